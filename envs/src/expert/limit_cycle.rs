//! The limit-cycle expert: a velocity field whose stable limit cycle is an [`Outline`].
//!
//! In polar coordinates `(ρ, θ)` around the outline's centre the field is
//!
//! `θ̇ = V / √(r² + r′²)`,  `ρ̇ = r′(θ) θ̇ − k_r (ρ − r(θ))`,
//!
//! so on the outline (`ρ = r`) the point moves counter-clockwise along it at the constant
//! speed `V`, and off it the radial error decays as `e^{−k_r t}`. The field is smooth
//! everywhere except at the centre `ρ = 0`.
//!
//! A curled outline (`c > 1`) is the image of the star-shaped one under the curl `T`;
//! its field is the star field carried through `T`, `∂T/∂y · v★(y)` at `y = T⁻¹(x)`,
//! rescaled to the star field's speed `|v★(y)|`: its orbits are those of the star field
//! mapped by `T`, so its limit cycle is the curled outline, traced at the speed `V`.

use std::sync::Arc;

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
    pub outline: Arc<Outline>,
}

impl VelocityField for LimitCycleField {
    fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
        let y = self.outline.uncurled(x);
        let star = self.star_velocity(&y);
        let carried = self.outline.curl_tangent(&y, &star);
        // At the star field's speed: the curl stretches far points' motion (by `2κρ²`),
        // faster than a mass with bounded acceleration follows; a positive rescaling
        // keeps every orbit and the limit cycle.
        carried * (star.norm() / carried.norm().max(f64::MIN_POSITIVE))
    }
}

impl LimitCycleField {
    /// `v★(x)`: the field of the star-shaped figure before the curl.
    fn star_velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
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
            outline: Outline::shared(0.5),
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
    fn the_distance_to_the_outline_decays_along_the_flow() {
        for c in [0.2, 2.0] {
            let field = LimitCycleField {
                outline: Outline::shared(c),
            };
            let mut x = Vector2::new(1.5, -1.2);
            let dt = 1e-3;
            for _ in 0..8000 {
                x += dt * field.velocity(&x);
            }
            assert!(field.outline.distance(&x) < 1e-3, "c = {c}");
        }
    }

    #[test]
    fn on_a_curled_outline_the_field_is_tangent() {
        let field = LimitCycleField {
            outline: Outline::shared(1.7),
        };
        for i in 0..72 {
            let theta = (i as f64 * 5.0).to_radians();
            let x = field.outline.point(theta);
            let h = 1e-6;
            let tangent =
                (field.outline.point(theta + h) - field.outline.point(theta - h)).normalize();
            let v = field.velocity(&x);
            assert!((v.normalize() - tangent).norm() < 1e-5);
            assert!((v.norm() - SPEED).abs() < 1e-9);
        }
    }
}
