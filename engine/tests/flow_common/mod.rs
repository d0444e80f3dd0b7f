//! Shared helpers of the flow integration tests: random architectures and weights.
#![allow(dead_code)]

use ciflow_engine::flow::{
    ContextSet, ContractionConfig, CouplingKind, FlowConfig, JointRange, LatentKind, LocalConfig,
    Policy, SetEncoderConfig, Weights,
};
use ciflow_engine::nn::scalar::Dual;
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub const AFFINE: CouplingKind = CouplingKind::AFFINE;
/// Affine couplings fading beyond a radius the tests' states straddle.
pub const TAPERED: CouplingKind = CouplingKind::Affine {
    scale_bound: 2.0,
    taper_radius: Some(1.5),
};
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
        for latent in [
            LatentKind::GoTo,
            LatentKind::SaturatedGoTo,
            LatentKind::LimitCycle,
        ] {
            out.push(config(2, 0, latent, coupling.clone()));
            out.push(config(3, 2, latent, coupling.clone()));
            out.push(config(5, 3, latent, coupling.clone()));
        }
        for latent in [LatentKind::GoTo, LatentKind::SaturatedGoTo] {
            let mut goal = config(2, 3, latent, coupling.clone());
            goal.goal_context_indices = Some(vec![2, 0]);
            out.push(goal);
        }
        out.push(contracted(coupling.clone()));
    }
    // Non-trivial normalisation.
    let mut scaled = config(3, 1, LatentKind::GoTo, SPLINE);
    scaled.normalisation.state_mean = vec![0.3, -1.0, 2.0];
    scaled.normalisation.state_std = vec![0.5, 2.0, 0.1];
    scaled.normalisation.context_mean = vec![1.0];
    scaled.normalisation.context_std = vec![3.0];
    out.push(scaled);
    // Sets seen through the encoder, with and without local features (appended, so the
    // variants above keep their seeds).
    for coupling in [AFFINE, SPLINE] {
        out.push(obstacle_set(coupling.clone()));
        let mut summary_only = obstacle_set(coupling);
        if let Some(encoder) = &mut summary_only.set_encoder {
            encoder.local = None;
        }
        out.push(summary_only);
    }
    // Tapered affine couplings (appended, as above).
    for latent in [
        LatentKind::GoTo,
        LatentKind::SaturatedGoTo,
        LatentKind::LimitCycle,
    ] {
        out.push(config(3, 2, latent, TAPERED));
    }
    let mut goal = config(2, 3, LatentKind::SaturatedGoTo, TAPERED);
    goal.goal_context_indices = Some(vec![2, 0]);
    out.push(goal);
    out
}

/// [`variants`] and, after them, the ones with a robot's joint range as the last layer.
/// Apart: random weights at full scale send some of their far latent states where `tanh`
/// rounds to ±1 (a checked rollout then crawls along a limit), so the rollout checks
/// exercise the range with tamer weights of their own.
pub fn all_variants() -> Vec<FlowConfig> {
    let mut out = variants();
    for coupling in [AFFINE, SPLINE] {
        out.push(ranged(
            config(3, 2, LatentKind::GoTo, coupling.clone()),
            UNBOUNDED,
        ));
        let mut goal = config(2, 3, LatentKind::SaturatedGoTo, coupling);
        goal.goal_context_indices = Some(vec![2, 0]);
        out.push(ranged(goal, UNBOUNDED));
    }
    out
}

/// A speed or acceleration bound no random test field comes near: the command unscaled.
pub const UNBOUNDED: f64 = 1e12;

/// `config` with joint ranges (asymmetric about 0, wider than the ±50 the tests draw
/// states from) as its last layer, commands bounded by `speed_max` per joint and the
/// acceleration [`UNBOUNDED`]. The network's output is scaled by 0.005 so that random
/// weights, whose outputs reach the hundreds, keep it where `tanh` is invertible in `f64`
/// (`|u| < 13`, `R`'s input), attractor and far latent states included.
pub fn ranged(mut config: FlowConfig, speed_max: f64) -> FlowConfig {
    let d = config.state_dim;
    config.normalisation.state_std = vec![0.005; d];
    config.joint_range = Some(JointRange {
        position_min: (0..d).map(|i| -55.0 - 5.0 * i as f64).collect(),
        position_max: (0..d).map(|i| 55.0 + 7.0 * i as f64).collect(),
        speed_max: vec![speed_max; d],
        acceleration_max: vec![UNBOUNDED; d],
    });
    config
}

/// Go-to in the plane among two context points `[o₁, o₂, g]` (a set, seen through the
/// set encoder and the couplings' local features) with the target `g`, as obstacle
/// avoidance is.
pub fn obstacle_set(coupling: CouplingKind) -> FlowConfig {
    let mut config = config(2, 6, LatentKind::GoTo, coupling);
    config.goal_context_indices = Some(vec![4, 5]);
    config.context_sets = vec![CENTRES];
    config.set_encoder = Some(SetEncoderConfig {
        hidden: vec![8],
        width: 4,
        local: Some(LocalConfig {
            hidden: vec![6],
            width: 3,
        }),
    });
    config
}

/// The two context points of [`obstacle_set`].
pub const CENTRES: ContextSet = ContextSet {
    start: 0,
    count: 2,
    size: 2,
};

/// [`obstacle_set`], contracted about the two context points.
pub fn contracted(coupling: CouplingKind) -> FlowConfig {
    let mut config = obstacle_set(coupling);
    config.contractions = Some(ContractionConfig {
        centres: CENTRES,
        layers: 2,
        exponent: 2,
        radius: 0.3,
    });
    config
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

/// The joint box of [`narrow`], a little over a radian wide or less.
pub const NARROW_MIN: [f64; 3] = [-0.8, -0.3, -1.2];
pub const NARROW_MAX: [f64; 3] = [0.6, 0.9, -0.2];

/// A go-to flow in 3-D with narrow joint ranges: random weights map much of the latent
/// space outside them. Its output is scaled by 0.1, so that they keep `R`'s input where
/// `tanh` is invertible in `f64` (`|u| < 13`).
pub fn narrow(coupling: CouplingKind, speed_max: f64, acceleration_max: f64) -> FlowConfig {
    let mut config = config(3, 2, LatentKind::GoTo, coupling);
    config.normalisation.state_std = vec![0.1; 3];
    config.joint_range = Some(JointRange {
        position_min: NARROW_MIN.to_vec(),
        position_max: NARROW_MAX.to_vec(),
        speed_max: vec![speed_max; 3],
        acceleration_max: vec![acceleration_max; 3],
    });
    config
}

/// Weights `N(0, 0.3²)`: far from the identity, not so steep that `R`'s input leaves
/// `tanh`'s invertible part.
pub fn tame_weights(config: &FlowConfig, seed: u64) -> Weights {
    Weights::random(&config.parameter_shapes(), 0.3, &mut rng(seed))
}

/// Exact Jacobian of `z ↦ f(z, c)` from dual numbers, one column per seeded direction:
/// a path independent of the log-determinant, which sums the transforms' own
/// log-derivative formulas. (Central differences carry ~1e-7 of rounding noise, which the
/// nearly singular Jacobians of the scaled variant amplify past the tolerance.)
pub fn dual_jacobian(policy: &ciflow_engine::flow::Policy, z: &[f64], c: &[f64]) -> DMatrix<f64> {
    let flow = policy.network();
    let mut conditioning = flow.conditioning();
    flow.condition(c, &mut conditioning, &mut flow.scratch())
        .unwrap();
    let mut scratch = flow.scratch();
    let d = z.len();
    let mut jacobian = DMatrix::zeros(d, d);
    let mut y = vec![Dual::new(0.0, 0.0); d];
    for j in 0..d {
        let seeded: Vec<Dual<f64>> = (0..d)
            .map(|i| Dual::new(z[i], if i == j { 1.0 } else { 0.0 }))
            .collect();
        flow.forward(&seeded, &conditioning, &mut scratch, &mut y);
        for i in 0..d {
            jacobian[(i, j)] = y[i].du;
        }
    }
    jacobian
}
