//! The obstacle-avoidance expert: a linear attractor deflected by modulation matrices.
//!
//! Khansari-Zadeh & Billard, "A dynamical system approach to realtime obstacle
//! avoidance", Autonomous Robots 32 (2012). The nominal system
//! `f(x) = sat(−k (x − g))` is reshaped around each circular obstacle `i` by
//!
//! `M_i(x) = E_i D_i E_iᵀ`, `E_i = [n_i  t_i]`, `D_i = diag(1 − Γ_i^{−1/ρ}, 1 + Γ_i^{−1/ρ})`,
//! `Γ_i(x) = (‖x − o_i‖ / R_i)²`,
//!
//! with `n_i` the outward normal, `t_i` the tangent and `ρ ≥ 1` the reactivity (their
//! Eq. 17): a larger `ρ` starts the deflection farther out, so the motion turns gradually
//! instead of running at the obstacle and wrapping around its boundary at the last moment.
//! On the boundary (`Γ = 1`) the normal component vanishes for every `ρ`, so trajectories
//! cannot enter; far away `M_i → I`. With
//! several obstacles each `1/Γ_i` is weighted by (their Eq. 20)
//!
//! `ω_i = Π_{j≠i} (Γ_j − 1) / ((Γ_i − 1) + (Γ_j − 1))`,
//!
//! which tends to 1 for the obstacle whose boundary is reached and to 0 for the others,
//! so the product `ẋ = M_1(x) ⋯ M_K(x) f(x)` keeps every boundary impenetrable. The field
//! is continuous in the state and in the context (obstacle positions and target), so the
//! demonstrations vary continuously with both — there is no planner that picks a side.

use nalgebra::{Matrix2, Vector2};

use crate::expert::tracking::{VelocityField, saturate};

/// Convergence rate of the nominal linear system `k`, 1/s.
pub const ATTRACTOR_GAIN: f64 = 2.0;
/// Speed cap of the nominal system, m/s.
pub const MAX_SPEED: f64 = 0.6;
/// Smallest `Γ` used in `D`, so that `1/Γ` stays bounded deep inside a boundary.
const MIN_GAMMA: f64 = 0.25;
/// Smallest `Γ − 1` used in the weights.
const MIN_MARGIN: f64 = 1e-9;

/// A disc the expert keeps out of: `o` and the radius `R` of its safety boundary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    pub center: Vector2<f64>,
    pub radius: f64,
}

impl Disc {
    /// `Γ(x) = (‖x − o‖ / R)²`: below 1 inside, 1 on the boundary.
    pub fn gamma(&self, x: &Vector2<f64>) -> f64 {
        (x - self.center).norm_squared() / (self.radius * self.radius)
    }

    /// The modulation matrix `M(x) = E D Eᵀ` with `Γ^{−1/ρ}` weighted by `weight` (`ω`).
    pub fn modulation(&self, x: &Vector2<f64>, weight: f64, reactivity: f64) -> Matrix2<f64> {
        let offset = x - self.center;
        let distance = offset.norm();
        if distance < 1e-12 {
            return Matrix2::identity();
        }
        let normal = offset / distance;
        let tangent = Vector2::new(-normal.y, normal.x);
        let inverse_gamma = weight / self.gamma(x).max(MIN_GAMMA).powf(1.0 / reactivity);
        (1.0 - inverse_gamma) * normal * normal.transpose()
            + (1.0 + inverse_gamma) * tangent * tangent.transpose()
    }
}

/// `ẋ = M_1(x) ⋯ M_K(x) sat(−k (x − g))`.
#[derive(Clone, Debug, PartialEq)]
pub struct ModulatedField {
    pub target: Vector2<f64>,
    pub obstacles: Vec<Disc>,
    /// `ρ ≥ 1`: how far out the obstacles deflect the motion (1: the least).
    pub reactivity: f64,
}

impl VelocityField for ModulatedField {
    fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
        let nominal = saturate(-ATTRACTOR_GAIN * (x - self.target), MAX_SPEED);
        // `Γ − 1`, kept positive so that the weights stay defined inside a boundary.
        let margins: Vec<f64> = self
            .obstacles
            .iter()
            .map(|disc| (disc.gamma(x) - 1.0).max(MIN_MARGIN))
            .collect();
        let weight = |i: usize| -> f64 {
            (0..margins.len())
                .filter(|&j| j != i)
                .map(|j| margins[j] / (margins[i] + margins[j]))
                .product()
        };
        self.obstacles
            .iter()
            .enumerate()
            .rev()
            .fold(nominal, |v, (i, disc)| {
                disc.modulation(x, weight(i), self.reactivity) * v
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_the_boundary_the_velocity_is_tangent() {
        let disc = Disc {
            center: Vector2::new(0.1, -0.2),
            radius: 0.3,
        };
        for reactivity in [1.0, 3.0] {
            let field = ModulatedField {
                target: Vector2::new(2.0, 0.5),
                obstacles: vec![disc],
                reactivity,
            };
            for i in 0..36 {
                let angle = (i as f64 * 10.0).to_radians();
                let normal = Vector2::new(angle.cos(), angle.sin());
                let v = field.velocity(&(disc.center + disc.radius * normal));
                assert!(v.dot(&normal).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn between_two_close_obstacles_both_boundaries_stay_impenetrable() {
        let discs = [Vector2::new(0.0, 0.0), Vector2::new(0.0, 0.37)].map(|center| Disc {
            center,
            radius: 0.16,
        });
        for reactivity in [1.0, 3.0] {
            let field = ModulatedField {
                target: Vector2::new(1.0, 0.3),
                obstacles: discs.to_vec(),
                reactivity,
            };
            for disc in &discs {
                for i in 0..72 {
                    let angle = (i as f64 * 5.0).to_radians();
                    let normal = Vector2::new(angle.cos(), angle.sin());
                    let v = field.velocity(&(disc.center + disc.radius * normal));
                    assert!(v.dot(&normal) > -1e-6, "{}", v.dot(&normal));
                }
            }
        }
    }

    #[test]
    fn far_from_obstacles_the_field_is_the_nominal_attractor() {
        let field = ModulatedField {
            target: Vector2::zeros(),
            obstacles: vec![Disc {
                center: Vector2::new(100.0, 0.0),
                radius: 0.1,
            }],
            reactivity: 1.0,
        };
        let x = Vector2::new(0.005, -0.002);
        assert!((field.velocity(&x) + ATTRACTOR_GAIN * x).norm() < 1e-5);
    }

    #[test]
    fn a_larger_reactivity_turns_earlier() {
        let disc = Disc {
            center: Vector2::zeros(),
            radius: 0.16,
        };
        // Two radii in front of the obstacle, heading at it slightly off-centre.
        let x = Vector2::new(-0.32, 0.01);
        let turn = |reactivity| {
            let field = ModulatedField {
                target: Vector2::new(1.0, 0.0),
                obstacles: vec![disc],
                reactivity,
            };
            let v = field.velocity(&x);
            v.y.atan2(v.x)
        };
        assert!(
            turn(3.0) > 2.0 * turn(1.0),
            "{} vs {}",
            turn(3.0),
            turn(1.0)
        );
    }
}
