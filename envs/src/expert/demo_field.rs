//! The LASA expert: a velocity field regressed on demonstrations, with a guaranteed pull
//! toward the goal where the demonstrations say nothing.
//!
//! With the demonstrations' positions `xᵢ` and velocities `vᵢ` relative to the goal `g`,
//! `u = x − g`, and Gaussian weights `wᵢ(u) = exp(−‖u − xᵢ‖² / 2σ²)`, the field is
//!
//! `f(x) = a(u) + (1 − γ(u)) s(u) (f_tube(u) − a(u))`, where
//!
//! - `f_tube(u) = Σ wᵢ (vᵢ + k_c (xᵢ − u)) / Σ wᵢ` is Nadaraya–Watson regression of the
//!   demonstrated velocities plus a pull of gain `k_c` onto the local mean of the
//!   demonstrations, which makes the demonstrated paths attracting tubes;
//! - `a(u) = −k_a u` is a linear attractor to the goal;
//! - `s(u) = W / (W + ε)`, `W = Σ wᵢ`, is the regression's confidence: 1 near the
//!   demonstrations, 0 far from them, with `ε = exp(−d_c² / 2σ²)` so that a single
//!   demonstrated point at distance `d_c` gives `s = ½`;
//! - `γ(u) = exp(−‖u‖² / 2ρ²)` hands over to the attractor within `ρ` of the goal, so
//!   that `f(g) = 0` exactly and the goal is exponentially stable.
//!
//! The Jacobian is analytic: with weighted covariances `Cov_w`,
//! `∂f_tube/∂u = (Cov_w(v, x) + k_c Cov_w(x, x)) / σ² − k_c I` and
//! `∂s/∂u = −s (1 − s) (u − x̄)ᵀ / σ²`, where `x̄ = Σ wᵢ xᵢ / W`.

use std::sync::Arc;

use nalgebra::{Matrix2, Vector2};

use crate::expert::tracking::VelocityField;

/// Kernel bandwidth `σ`, mm.
pub const BANDWIDTH: f64 = 3.0;
/// Gain `k_c` of the pull onto the demonstrated paths, 1/s.
pub const PATH_GAIN: f64 = 4.0;
/// Gain `k_a` of the linear attractor, 1/s.
pub const ATTRACTOR_GAIN: f64 = 2.0;
/// Radius `ρ` of the hand-over to the attractor around the goal, mm.
pub const GOAL_RADIUS: f64 = 2.0;
/// Distance `d_c` from a lone demonstrated point at which the confidence is ½, mm.
pub const CONFIDENCE_DISTANCE: f64 = 3.0 * BANDWIDTH;
/// Arc length between the demonstration samples kept as kernel centres, mm.
pub const CENTRE_SPACING: f64 = BANDWIDTH / 3.0;

/// One demonstrated state, relative to the goal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub position: Vector2<f64>,
    pub velocity: Vector2<f64>,
}

/// The demonstration field (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct DemoField {
    /// Shared by the fields cloned from one (environments of one shape): only the goal
    /// differs between them.
    centres: Arc<[Sample]>,
    /// The goal `g`, where all demonstrations end.
    pub goal: Vector2<f64>,
}

/// Weighted moments of the kernel centres at one point.
struct Moments {
    /// `ln W`.
    log_weight: f64,
    mean_position: Vector2<f64>,
    mean_velocity: Vector2<f64>,
    cov_position: Matrix2<f64>,
    /// `Cov_w(v, x)`.
    cov_velocity_position: Matrix2<f64>,
}

impl DemoField {
    /// The field of `demos` (each a time-ordered path ending at the goal, relative to it),
    /// keeping samples [`CENTRE_SPACING`] apart along each path. `None` without samples.
    pub fn new(demos: &[Vec<Sample>]) -> Option<Self> {
        let mut centres = Vec::new();
        for demo in demos {
            let mut last: Option<Vector2<f64>> = None;
            for (i, sample) in demo.iter().enumerate() {
                let far_enough =
                    last.is_none_or(|p| (sample.position - p).norm() >= CENTRE_SPACING);
                if far_enough || i + 1 == demo.len() {
                    centres.push(*sample);
                    last = Some(sample.position);
                }
            }
        }
        (!centres.is_empty()).then_some(Self {
            centres: centres.into(),
            goal: Vector2::zeros(),
        })
    }

    /// The kernel centres kept from the demonstrations.
    pub fn centres(&self) -> &[Sample] {
        &self.centres
    }

    /// Weighted moments at `u`, with weights shifted by the nearest centre's so that
    /// points far from every demonstration do not underflow.
    fn moments(&self, u: &Vector2<f64>) -> Moments {
        let scale = 1.0 / (2.0 * BANDWIDTH * BANDWIDTH);
        let nearest = self
            .centres
            .iter()
            .map(|c| (c.position - u).norm_squared())
            .fold(f64::INFINITY, f64::min);
        let (mut total, mut sum_x, mut sum_v) = (0.0, Vector2::zeros(), Vector2::zeros());
        let (mut sum_xx, mut sum_vx) = (Matrix2::zeros(), Matrix2::zeros());
        for c in self.centres.iter() {
            let excess = ((c.position - u).norm_squared() - nearest) * scale;
            // Below e^-40 of the nearest centre's weight: nothing a double would keep.
            if excess > 40.0 {
                continue;
            }
            let w = (-excess).exp();
            total += w;
            sum_x += w * c.position;
            sum_v += w * c.velocity;
            sum_xx += w * c.position * c.position.transpose();
            sum_vx += w * c.velocity * c.position.transpose();
        }
        let (mean_position, mean_velocity) = (sum_x / total, sum_v / total);
        Moments {
            log_weight: total.ln() - nearest * scale,
            mean_position,
            mean_velocity,
            cov_position: sum_xx / total - mean_position * mean_position.transpose(),
            cov_velocity_position: sum_vx / total - mean_velocity * mean_position.transpose(),
        }
    }

    /// `f` and `∂f/∂x` at `x`.
    pub fn velocity_and_jacobian(&self, x: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let u = x - self.goal;
        let m = self.moments(&u);
        let sigma2 = BANDWIDTH * BANDWIDTH;
        let identity = Matrix2::identity();
        let tube = m.mean_velocity + PATH_GAIN * (m.mean_position - u);
        let tube_jacobian =
            (m.cov_velocity_position + PATH_GAIN * m.cov_position) / sigma2 - PATH_GAIN * identity;
        let log_epsilon = -CONFIDENCE_DISTANCE * CONFIDENCE_DISTANCE / (2.0 * sigma2);
        let confidence = 1.0 / (1.0 + (log_epsilon - m.log_weight).exp());
        let confidence_gradient = -confidence * (1.0 - confidence) * (u - m.mean_position) / sigma2;
        let handover = (-u.norm_squared() / (2.0 * GOAL_RADIUS * GOAL_RADIUS)).exp();
        let handover_gradient = -handover * u / (GOAL_RADIUS * GOAL_RADIUS);
        let attractor = -ATTRACTOR_GAIN * u;
        let blend = (1.0 - handover) * confidence;
        let blend_gradient =
            (1.0 - handover) * confidence_gradient - confidence * handover_gradient;
        let difference = tube - attractor;
        let velocity = attractor + blend * difference;
        let jacobian = -ATTRACTOR_GAIN * identity
            + blend * (tube_jacobian + ATTRACTOR_GAIN * identity)
            + difference * blend_gradient.transpose();
        (velocity, jacobian)
    }
}

impl VelocityField for DemoField {
    fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
        self.velocity_and_jacobian(x).0
    }

    fn jacobian(&self, x: &Vector2<f64>) -> Matrix2<f64> {
        self.velocity_and_jacobian(x).1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two arcs into the goal from different sides, sampled at 1 kHz.
    fn arcs() -> DemoField {
        let arc = |radius: f64, sign: f64| -> Vec<Sample> {
            (0..=1000)
                .map(|i| {
                    // Half a turn of a circle through the origin, slowing into it.
                    let s = i as f64 / 1000.0;
                    let phase = std::f64::consts::PI * (1.0 - (1.0 - s).powi(2));
                    let rate = std::f64::consts::PI * 2.0 * (1.0 - s);
                    let position = radius * Vector2::new(phase.cos() + 1.0, sign * phase.sin());
                    let velocity = radius * rate * Vector2::new(-phase.sin(), sign * phase.cos());
                    Sample { position, velocity }
                })
                .collect()
        };
        DemoField::new(&[arc(20.0, 1.0), arc(20.0, -1.0)]).unwrap()
    }

    #[test]
    fn analytic_jacobian_matches_finite_differences() {
        struct Numeric<'a>(&'a DemoField);
        impl VelocityField for Numeric<'_> {
            fn velocity(&self, x: &Vector2<f64>) -> Vector2<f64> {
                self.0.velocity(x)
            }
        }
        let mut field = arcs();
        field.goal = Vector2::new(1.0, -2.0);
        for x in [
            Vector2::new(10.0, 15.0),
            Vector2::new(30.0, -18.0),
            Vector2::new(2.0, -1.0),
            Vector2::new(-25.0, 40.0),
            Vector2::new(1.5, -2.5),
        ] {
            let (analytic, numeric) = (field.jacobian(&x), Numeric(&field).jacobian(&x));
            assert!(
                (analytic - numeric).norm() < 1e-5 * (1.0 + numeric.norm()),
                "at {x}: {analytic} vs {numeric}"
            );
        }
    }

    #[test]
    fn the_goal_is_an_equilibrium_and_far_points_head_to_it() {
        let field = arcs();
        assert_eq!(field.velocity(&Vector2::zeros()), Vector2::zeros());
        let far = Vector2::new(400.0, -300.0);
        let v = field.velocity(&far);
        assert!((v + ATTRACTOR_GAIN * far).norm() < 1e-9 * far.norm());
    }

    #[test]
    fn on_a_demonstration_the_field_follows_it() {
        let field = arcs();
        let demo = &field.centres()[field.centres().len() / 4];
        let v = field.velocity(&demo.position);
        let angle = v.angle(&demo.velocity);
        assert!(angle < 0.15, "off by {angle} rad");
    }
}
