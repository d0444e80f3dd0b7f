//! What the radial contractions are for: with an otherwise identity network the latent
//! paths are straight lines to the target, and the contraction about an obstacle centre
//! bends nearly all of those that would cross the obstacle around it — while every path
//! still converges to the target.

mod flow_common;

use ciflow_engine::flow::{ContractionConfig, Policy, Tensor, Weights};
use ciflow_engine::math::distance;
use flow_common::*;

const BODY_RADIUS: f64 = 0.1;
const TARGET: [f64; 2] = [0.8, 0.0];

/// `f(z, c) = P_c⁻¹(z + a(c))` about one centre at the origin (context
/// `[o₁, o₂, g]`, the second centre far away), each of six layers with `strength`: a
/// layer pulls by at most `α / K` about each of the `K = 2` centres.
fn policy(strength: Option<f64>) -> Policy {
    let mut config = contracted(AFFINE);
    let contraction = config.contractions.as_mut().unwrap();
    contraction.radius = 0.16;
    contraction.exponent = 2;
    contraction.layers = 6;
    if strength.is_none() {
        config.contractions = None;
    }
    // All-zero network weights: identity mixing and couplings, latent `A = −ε I`.
    let mut weights = Weights::random(&config.parameter_shapes(), 0.0, &mut rng(0));
    if let Some(strength) = strength {
        for l in 0..config.contractions.unwrap().layers {
            let [name, _] = ContractionConfig::parameter_names(l);
            weights.insert(
                name,
                Tensor {
                    shape: vec![1],
                    data: vec![strength],
                },
            );
        }
    }
    Policy::new(&config, weights).unwrap()
}

/// Starts `(−0.8, y₀)` whose noise-free paths enter the body, and the largest final
/// distance to the target.
fn collisions(policy: &Policy) -> (usize, f64) {
    let context = [0.0, 0.0, 5.0, 5.0, TARGET[0], TARGET[1]];
    let mut ws = policy.workspace();
    let (mut hits, mut worst) = (0, 0.0f64);
    for i in 0..61 {
        let mut y = vec![-0.8, -0.3 + 0.01 * i as f64];
        let mut next = vec![0.0; 2];
        let mut entered = false;
        for _ in 0..3000 {
            policy.mean_next(&y, &context, &mut ws, &mut next).unwrap();
            std::mem::swap(&mut y, &mut next);
            entered |= y[0].hypot(y[1]) < BODY_RADIUS;
        }
        hits += usize::from(entered);
        worst = worst.max(distance(&y, &TARGET));
    }
    (hits, worst)
}

#[test]
fn a_contraction_bends_the_straight_latent_paths_around_the_obstacle() {
    let (straight, straight_worst) = collisions(&policy(None));
    // Lines from x = −0.8 to the target cross the body for |y₀| < 0.2.
    assert!(
        (38..=42).contains(&straight),
        "{straight} straight paths collide"
    );
    let (bent, bent_worst) = collisions(&policy(Some(4.0)));
    assert!(bent <= 3, "{bent} of 61 contracted paths still collide");
    for worst in [straight_worst, bent_worst] {
        assert!(worst < 1e-3, "a path ends {worst} from the target");
    }
}
