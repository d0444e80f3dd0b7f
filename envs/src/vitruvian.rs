//! The "Vitruvian man" outlines of the limit-cycle task.
//!
//! Each outline is a star-shaped closed curve in polar form around the origin,
//!
//! `r(θ, c) = r₀ + Σₖ hₖ exp(κₖ (cos(θ − θₖ(c)) − 1))`,
//!
//! a circle (the torso) with von Mises bumps for the head, the two arms and the two legs.
//! Since `r > 0` everywhere the curve is simple and closed, so a stable limit cycle can
//! trace it. The phase context `c ∈ [0, 1]` moves the limbs smoothly: the arms rise from
//! slightly below horizontal (`c = 0`) to raised (`c = 1`), the legs spread apart.

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::Vector2;

/// Torso radius `r₀` in metres.
pub const TORSO_RADIUS: f64 = 0.3;

/// One limb: a von Mises bump `h exp(κ (cos(θ − θₖ) − 1))` on the torso circle.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Bump {
    /// Polar angle of the limb's tip, rad.
    angle: f64,
    /// Extra radius at the tip, m.
    height: f64,
    /// Concentration; the bump's angular half-width is about `1/√κ` rad.
    concentration: f64,
}

impl Bump {
    fn value(&self, theta: f64) -> f64 {
        self.height * (self.concentration * ((theta - self.angle).cos() - 1.0)).exp()
    }

    fn derivative(&self, theta: f64) -> f64 {
        -self.concentration * (theta - self.angle).sin() * self.value(theta)
    }
}

/// The outline for one phase context `c`.
#[derive(Clone, Debug, PartialEq)]
pub struct Outline {
    bumps: [Bump; 5],
}

impl Outline {
    /// The outline at phase `c`; `c` outside `[0, 1]` extrapolates the same formulas.
    pub fn new(c: f64) -> Self {
        // Arm elevation above horizontal and leg spread from vertical, rad.
        let arm = -0.1 + 0.7 * c;
        let leg = 0.25 + 0.35 * c;
        let arm_bump = |angle| Bump {
            angle,
            height: 0.55,
            concentration: 40.0,
        };
        let leg_bump = |angle| Bump {
            angle,
            height: 0.6,
            concentration: 30.0,
        };
        Self {
            bumps: [
                Bump {
                    angle: FRAC_PI_2,
                    height: 0.25,
                    concentration: 20.0,
                },
                arm_bump(arm),
                arm_bump(PI - arm),
                leg_bump(-FRAC_PI_2 - leg),
                leg_bump(-FRAC_PI_2 + leg),
            ],
        }
    }

    /// `r(θ)`, m.
    pub fn radius(&self, theta: f64) -> f64 {
        TORSO_RADIUS + self.bumps.iter().map(|b| b.value(theta)).sum::<f64>()
    }

    /// `∂r/∂θ`, m/rad.
    pub fn radius_derivative(&self, theta: f64) -> f64 {
        self.bumps.iter().map(|b| b.derivative(theta)).sum()
    }

    /// The point of the outline at polar angle `θ`.
    pub fn point(&self, theta: f64) -> Vector2<f64> {
        self.radius(theta) * Vector2::new(theta.cos(), theta.sin())
    }

    /// `n` points evenly spaced in `θ`, counter-clockwise from `θ = 0`.
    pub fn polyline(&self, n: usize) -> Vec<Vector2<f64>> {
        (0..n)
            .map(|i| self.point(2.0 * PI * i as f64 / n as f64))
            .collect()
    }

    /// Signed radial distance `ρ − r(θ)` of `x` from the outline (positive outside).
    pub fn radial_error(&self, x: &Vector2<f64>) -> f64 {
        x.norm() - self.radius(x.y.atan2(x.x))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radius_derivative_matches_finite_differences() {
        let outline = Outline::new(0.37);
        for i in 0..64 {
            let theta = -PI + 2.0 * PI * i as f64 / 64.0;
            let h = 1e-6;
            let numeric = (outline.radius(theta + h) - outline.radius(theta - h)) / (2.0 * h);
            assert!((numeric - outline.radius_derivative(theta)).abs() < 1e-5);
        }
    }

    #[test]
    fn outlines_are_star_shaped_and_vary_continuously_with_phase() {
        for i in 0..=20 {
            let c = i as f64 / 20.0;
            let (a, b) = (Outline::new(c), Outline::new(c + 1e-4));
            for j in 0..360 {
                let theta = (j as f64).to_radians();
                assert!(a.radius(theta) >= TORSO_RADIUS);
                assert!((a.radius(theta) - b.radius(theta)).abs() < 1e-3);
            }
        }
    }

    #[test]
    fn arms_rise_with_phase() {
        let arm_tip_height = |c: f64| {
            let outline = Outline::new(c);
            // The right arm is the farthest point in the right half-plane's upper part.
            (0..900)
                .map(|i| outline.point((i as f64 / 10.0 - 45.0).to_radians()))
                .max_by(|p, q| p.norm().total_cmp(&q.norm()))
                .unwrap()
                .y
        };
        assert!(arm_tip_height(1.0) > arm_tip_height(0.0) + 0.3);
    }
}
