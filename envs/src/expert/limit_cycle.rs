//! The limit-cycle expert: a velocity field whose stable limit cycle is an [`Outline`].
//!
//! In polar coordinates `(ρ, θ)` around the outline's centre the field is
//!
//! `θ̇ = V / √(r² + r′²)`,  `ρ̇ = r′(θ) θ̇ − k_r (ρ − r(θ))`,
//!
//! so on the outline (`ρ = r`) the point moves counter-clockwise along it at the constant
//! speed `V`, and off it the radial error decays as `e^{−k_r t}`. The field is smooth
//! everywhere except at the centre `ρ = 0`.

use nalgebra::Vector2;

use crate::expert::tracking::VelocityField;
use crate::vitruvian::Outline;

/// Speed along the outline `V`, m/s.
pub const SPEED: f64 = 0.8;
/// Radial convergence rate `k_r`, 1/s.
pub const RADIAL_GAIN: f64 = 3.0;

/// The velocity field of the limit cycle for one outline.
#[derive(Clone, Debug)]
pub struct LimitCycleField {
    pub outline: Outline,
}

impl VelocityField for LimitCycleField {
    fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
        let rho = x.norm();
        let theta = x.y.atan2(x.x);
        let (r, dr) = (
            self.outline.radius(theta),
            self.outline.radius_derivative(theta),
        );
        let theta_dot = SPEED / (r * r + dr * dr).sqrt();
        let rho_dot = dr * theta_dot - RADIAL_GAIN * (rho - r);
        let radial = Vector2::new(theta.cos(), theta.sin());
        let tangential = Vector2::new(-theta.sin(), theta.cos());
        rho_dot * radial + rho * theta_dot * tangential
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_the_outline_the_field_is_tangent_with_the_cruise_speed() {
        let field = LimitCycleField {
            outline: Outline::new(0.5),
        };
        for i in 0..72 {
            let theta = (i as f64 * 5.0).to_radians();
            let x = field.outline.point(theta);
            let v = field.velocity(&x);
            assert!((v.norm() - SPEED).abs() < 1e-9);
            let h = 1e-6;
            let tangent =
                (field.outline.point(theta + h) - field.outline.point(theta - h)).normalize();
            assert!((v.normalize() - tangent).norm() < 1e-5);
        }
    }

    #[test]
    fn radial_error_decays_along_the_flow() {
        let field = LimitCycleField {
            outline: Outline::new(0.2),
        };
        let mut x = Vector2::new(1.5, -1.2);
        let dt = 1e-3;
        for _ in 0..8000 {
            x += dt * field.velocity(&x);
        }
        assert!(field.outline.radial_error(&x).abs() < 1e-3);
    }
}
