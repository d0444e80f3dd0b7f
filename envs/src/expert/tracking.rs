//! Second-order tracking of a first-order dynamical system.
//!
//! The planar experts are first-order systems `ẋ = f(x)` (a velocity field); the
//! environments are double integrators `ẍ = a`. The expert's action makes the velocity
//! track the field,
//!
//! `a = k_v (f(x) − ẋ) + (∂f/∂x) ẋ`,
//!
//! the feedback term pulling `ẋ` onto `f(x)` and the feed-forward term `(∂f/∂x) ẋ`
//! (the acceleration of a particle that follows the field exactly) removing the lag.

use nalgebra::{Matrix2, Vector2};

/// A first-order dynamical system `ẋ = f(x)` in the plane.
pub trait VelocityField {
    /// The desired velocity `f(x)`.
    fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64>;

    /// The Jacobian `∂f/∂x`, by central differences unless a field knows better.
    fn jacobian(&self, x: &Vector2<f64>) -> Matrix2<f64> {
        const H: f64 = 1e-5;
        let mut jacobian = Matrix2::zeros();
        for axis in 0..2 {
            let step = Vector2::ith(axis, H);
            let column = (self.velocity(&(x + step)) - self.velocity(&(x - step))) / (2.0 * H);
            jacobian.set_column(axis, &column);
        }
        jacobian
    }
}

/// The tracking acceleration `a = k_v (f(x) − ẋ) + (∂f/∂x) ẋ`.
pub fn tracking_acceleration(
    field: &(impl VelocityField + ?Sized),
    x: &Vector2<f64>,
    xd: &Vector2<f64>,
    velocity_gain: f64,
) -> Vector2<f64> {
    velocity_gain * (field.velocity(x) - xd) + field.jacobian(x) * xd
}

/// Smoothly caps a speed: `v ↦ v · s_max tanh(|v| / s_max) / |v|`, which is the identity
/// for slow velocities and never exceeds `s_max`.
pub fn saturate(v: Vector2<f64>, max_speed: f64) -> Vector2<f64> {
    let speed = v.norm();
    if speed < 1e-12 {
        return v;
    }
    v * (max_speed * (speed / max_speed).tanh() / speed)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Linear(Matrix2<f64>);
    impl VelocityField for Linear {
        fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
            self.0 * x
        }
    }

    #[test]
    fn finite_difference_jacobian_matches_a_linear_field() {
        let a = Matrix2::new(-1.0, 2.0, -0.5, -3.0);
        let jacobian = Linear(a).jacobian(&Vector2::new(0.3, -0.7));
        assert!((jacobian - a).norm() < 1e-8);
    }

    #[test]
    fn tracking_a_field_exactly_needs_only_the_feed_forward_term() {
        let a = Matrix2::new(-1.0, 2.0, -0.5, -3.0);
        let x = Vector2::new(0.3, -0.7);
        let xd = a * x;
        let acceleration = tracking_acceleration(&Linear(a), &x, &xd, 10.0);
        assert!((acceleration - a * xd).norm() < 1e-8);
    }

    #[test]
    fn saturation_caps_speed_and_keeps_direction() {
        let v = Vector2::new(30.0, 40.0);
        let capped = saturate(v, 2.0);
        assert!(capped.norm() <= 2.0 && capped.norm() > 1.99);
        assert!((capped.normalize() - v.normalize()).norm() < 1e-12);
        assert!((saturate(Vector2::new(1e-3, 0.0), 2.0).x - 1e-3).abs() < 1e-9);
    }
}
