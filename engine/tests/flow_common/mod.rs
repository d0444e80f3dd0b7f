//! Shared helpers of the flow integration tests: random architectures and weights.
#![allow(dead_code)]

use ciflow_engine::flow::{CouplingKind, FlowConfig, LatentKind, Policy, Weights};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub const AFFINE: CouplingKind = CouplingKind::Affine { scale_bound: 2.0 };
pub const SPLINE: CouplingKind = CouplingKind::Spline {
    bins: 8,
    tail_bound: 3.0,
};

pub fn config(d: usize, m: usize, latent: LatentKind, coupling: CouplingKind) -> FlowConfig {
    let mut config = FlowConfig::new("test", d, m, latent, coupling, 4, vec![16, 16]);
    config.dt = 0.05;
    config.min_rate = 0.5;
    config
}

/// Every architecture variant the tests sweep.
pub fn variants() -> Vec<FlowConfig> {
    let mut out = Vec::new();
    for coupling in [AFFINE, SPLINE] {
        for latent in [LatentKind::GoTo, LatentKind::LimitCycle] {
            out.push(config(2, 0, latent, coupling.clone()));
            out.push(config(3, 2, latent, coupling.clone()));
            out.push(config(5, 3, latent, coupling.clone()));
        }
        let mut goal = config(2, 3, LatentKind::GoTo, coupling.clone());
        goal.goal_context_indices = Some(vec![2, 0]);
        out.push(goal);
    }
    // Non-trivial normalisation.
    let mut scaled = config(3, 1, LatentKind::GoTo, SPLINE);
    scaled.normalisation.state_mean = vec![0.3, -1.0, 2.0];
    scaled.normalisation.state_std = vec![0.5, 2.0, 0.1];
    scaled.normalisation.context_mean = vec![1.0];
    scaled.normalisation.context_std = vec![3.0];
    out.push(scaled);
    out
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub fn random_weights(config: &FlowConfig, seed: u64) -> Weights {
    Weights::random(&config.parameter_shapes(), 1.0, &mut rng(seed))
}

pub fn random_policy(config: &FlowConfig, seed: u64) -> Policy {
    Policy::new(config, random_weights(config, seed)).expect("valid random policy")
}

pub fn uniform(rng: &mut ChaCha8Rng, n: usize, half_width: f64) -> Vec<f64> {
    use rand::RngExt;
    (0..n)
        .map(|_| rng.random_range(-half_width..=half_width))
        .collect()
}

pub fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
