//! Shared helpers of the envs integration tests: a random flow that acts in Obstacle-v0.
// Each test binary compiles this module and uses only some of it.
#![allow(dead_code)]

use ciflow_engine::flow::{CouplingKind, FlowConfig, LatentKind, Policy, Weights};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Configuration and weights of a random go-to flow for Obstacle-v0 with one obstacle:
/// state 2-D, context `[o_x, o_y, g_x, g_y]`, attractor on the target, contracting at
/// 2 /s at least so that it arrives within an episode. Small weights keep `f` near the
/// identity, so its paths run nearly straight to the target. `seed` draws the weights.
pub fn obstacle_flow_checkpoint(seed: u64) -> (FlowConfig, Weights) {
    let mut config = FlowConfig::new(
        "obstacle-avoidance",
        2,
        4,
        LatentKind::GoTo,
        CouplingKind::AFFINE,
        4,
        vec![16, 16],
    );
    config.min_rate = 2.0;
    config.goal_context_indices = Some(vec![2, 3]);
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.1,
        &mut ChaCha8Rng::seed_from_u64(seed),
    );
    (config, weights)
}

/// The policy of [`obstacle_flow_checkpoint`]`(seed)`.
pub fn obstacle_flow(seed: u64) -> Policy {
    let (config, weights) = obstacle_flow_checkpoint(seed);
    Policy::new(&config, weights).expect("valid random flow")
}
