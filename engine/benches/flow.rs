//! One policy action at the pouring size (d = 7, context 6, 10 coupling layers): the
//! affine network as `ciflow train --task pouring` builds it (2×32 hidden,
//! `envs/src/recipes.rs`), the same with the default 2×64 (`affine-64`, pouring's before),
//! the default spline flow (2×64) and the spline flow the pouring recipe builds
//! (`spline-32`: `ciflow train --task pouring --coupling spline`, 2×32). The action a
//! robot gets is `Policy::acceleration`, `flow/acceleration/*`: the desired acceleration
//! `q̈_des` and velocity `v_des` of the second-order controller that every environment,
//! served policy and evaluation runs (`envs::actor::Actor`).
//! `flow/act/*` is the first-order step (`Policy::act`: inverse, latent step, forward
//! and the Jacobian-vector product of the desired velocity), the figure the tch eager
//! comparison prints beside it (`cargo bench -p ciflow-train --bench flow_tch`). The
//! affine network also with the Panda's joint range as its last layer
//! (`--joint-range true`).
//!
//! Also both at the obstacle-avoidance size (d = 2, 3 obstacles + target, 6 spline
//! layers) with and without the radial contractions about the obstacles, side by side:
//! their cost is the 15 layers' iterative inverses in the forward pass (the layer count
//! `ciflow train` gives 3 obstacles, 5 per obstacle: `envs/src/recipes.rs`).

use std::hint::black_box;

use ciflow_engine::flow::{
    AFFINE_SCALE_BOUND, ContextSet, ContractionConfig, CouplingKind, FlowConfig, JointRange,
    LatentKind, Policy, SetEncoderConfig, Weights,
};
use ciflow_engine::robot::panda_limits;
use criterion::{Criterion, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const SPLINE: CouplingKind = CouplingKind::Spline {
    bins: 8,
    tail_bound: 4.0,
};

fn random_policy(config: &FlowConfig) -> Policy {
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.5,
        &mut ChaCha8Rng::seed_from_u64(0),
    );
    Policy::new(config, weights).expect("valid policy")
}

/// Hidden widths of the pouring recipe's conditioners, and of the default flow's.
const POURING_HIDDEN: [usize; 2] = [32, 32];
const DEFAULT_HIDDEN: [usize; 2] = [64, 64];

fn pouring_policy(coupling: CouplingKind, hidden: [usize; 2], joint_range: bool) -> Policy {
    let mut config = FlowConfig::new(
        "pouring",
        7,
        6,
        LatentKind::GoTo,
        coupling,
        10,
        hidden.to_vec(),
    );
    config.joint_range = joint_range.then(|| JointRange::from_limits(&panda_limits()));
    random_policy(&config)
}

/// The obstacle-avoidance architecture of `ciflow train` (3 obstacles).
fn obstacle_policy(contracted: bool) -> Policy {
    let mut config = FlowConfig::new(
        "obstacle-avoidance",
        2,
        8,
        LatentKind::GoTo,
        SPLINE,
        6,
        vec![64, 64],
    );
    let obstacles = ContextSet {
        start: 0,
        count: 3,
        size: 2,
    };
    config.goal_context_indices = Some(vec![6, 7]);
    config.context_sets = vec![obstacles];
    config.set_encoder = Some(SetEncoderConfig::default());
    config.contractions = contracted.then_some(ContractionConfig {
        centres: obstacles,
        layers: 15,
        exponent: 2,
        radius: 0.16,
    });
    random_policy(&config)
}

fn bench(c: &mut Criterion) {
    let y = [0.1, -0.3, 0.2, -1.5, 0.05, 1.2, 0.4];
    let context = [0.5, 0.2, 0.3, 0.0, 0.1, -0.2];
    let affine = CouplingKind::AFFINE;
    // The pouring recipe's couplings (`envs/src/recipes.rs`).
    let tapered = CouplingKind::Affine {
        scale_bound: AFFINE_SCALE_BOUND,
        taper_radius: Some(8.0),
    };
    for (name, coupling, hidden, joint_range) in [
        ("affine", affine.clone(), POURING_HIDDEN, false),
        ("affine-tapered", tapered, POURING_HIDDEN, false),
        ("affine-joint-range", affine.clone(), POURING_HIDDEN, true),
        ("affine-64", affine, DEFAULT_HIDDEN, false),
        ("spline", SPLINE, DEFAULT_HIDDEN, false),
        ("spline-32", SPLINE, POURING_HIDDEN, false),
    ] {
        let policy = pouring_policy(coupling, hidden, joint_range);
        bench_actions(c, name, &policy, &y, &context);
    }
}

fn bench_obstacle(c: &mut Criterion) {
    let y = [-0.5, 0.1];
    let context = [-0.2, 0.3, 0.1, -0.4, 0.3, 0.5, 0.8, 0.0];
    for (name, contracted) in [("plain", false), ("contracted", true)] {
        let policy = obstacle_policy(contracted);
        bench_actions(c, &format!("obstacle-3/{name}"), &policy, &y, &context);
    }
}

/// `Policy::acceleration` at `(q = y, q̇, c)` and `Policy::act` at `(y, c)`.
fn bench_actions(c: &mut Criterion, name: &str, policy: &Policy, y: &[f64], context: &[f64]) {
    let mut ws = policy.workspace();
    let qd: Vec<f64> = (0..y.len()).map(|i| 0.02 * (i as f64 - 2.0)).collect();
    let (mut next, mut velocity) = (vec![0.0; y.len()], vec![0.0; y.len()]);
    c.bench_function(&format!("flow/acceleration/{name}"), |b| {
        b.iter(|| {
            policy
                .acceleration(
                    black_box(y),
                    &qd,
                    black_box(context),
                    5.0,
                    &mut ws,
                    &mut next,
                    &mut velocity,
                )
                .unwrap();
            black_box(&next);
        })
    });
    c.bench_function(&format!("flow/act/{name}"), |b| {
        b.iter(|| {
            policy
                .act(
                    black_box(y),
                    black_box(context),
                    &mut ws,
                    &mut next,
                    &mut velocity,
                )
                .unwrap();
            black_box(&next);
        })
    });
}

criterion_group!(benches, bench, bench_obstacle);
criterion_main!(benches);
