//! One full policy action at the pouring size (d = 7, context 6, 10 coupling layers of
//! 2×64 hidden): inverse, latent step, forward and the Jacobian-vector product of the
//! desired velocity (`Policy::act`), plus the second-order `Policy::acceleration`.
//! Target: `act` < 20 µs. The tch eager figure is printed beside it by
//! `cargo bench -p ciflow-train --bench flow_tch`. The affine network also with the
//! Panda's joint range as its last layer (`--joint-range true`).
//!
//! Also `act` at the obstacle-avoidance size (d = 2, 3 obstacles + target, 6 spline
//! layers) with and without the radial contractions about the obstacles, side by side:
//! their cost is the eight layers' iterative inverses in the forward pass (the layer count
//! `ciflow train` gives obstacle avoidance).

use std::hint::black_box;

use ciflow_engine::flow::{
    ContextSet, ContractionConfig, CouplingKind, FlowConfig, JointRange, LatentKind, Policy,
    SetEncoderConfig, Weights,
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

fn pouring_policy(coupling: CouplingKind, joint_range: bool) -> Policy {
    let mut config = FlowConfig::new(
        "pouring",
        7,
        6,
        LatentKind::GoTo,
        coupling,
        10,
        vec![64, 64],
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
        layers: 8,
        exponent: 2,
        radius: 0.16,
    });
    random_policy(&config)
}

fn bench(c: &mut Criterion) {
    let y = [0.1, -0.3, 0.2, -1.5, 0.05, 1.2, 0.4];
    let qd = [0.01, 0.02, -0.03, 0.0, 0.1, -0.05, 0.02];
    let context = [0.5, 0.2, 0.3, 0.0, 0.1, -0.2];
    let affine = CouplingKind::Affine { scale_bound: 2.0 };
    for (name, coupling, joint_range) in [
        ("affine", affine.clone(), false),
        ("affine-joint-range", affine, true),
        ("spline", SPLINE, false),
    ] {
        let policy = pouring_policy(coupling, joint_range);
        bench_act(c, &format!("flow/act/{name}"), &policy, &y, &context);
        let mut ws = policy.workspace();
        let (mut velocity, mut acceleration) = ([0.0; 7], [0.0; 7]);
        c.bench_function(&format!("flow/acceleration/{name}"), |b| {
            b.iter(|| {
                policy
                    .acceleration(
                        black_box(&y),
                        &qd,
                        &context,
                        5.0,
                        &mut ws,
                        &mut acceleration,
                        &mut velocity,
                    )
                    .unwrap();
                black_box(&acceleration);
            })
        });
    }
}

fn bench_obstacle(c: &mut Criterion) {
    let y = [-0.5, 0.1];
    let context = [-0.2, 0.3, 0.1, -0.4, 0.3, 0.5, 0.8, 0.0];
    for (name, contracted) in [("plain", false), ("contracted", true)] {
        let policy = obstacle_policy(contracted);
        bench_act(
            c,
            &format!("flow/act/obstacle-3/{name}"),
            &policy,
            &y,
            &context,
        );
    }
}

/// `Policy::act` at `(y, c)`.
fn bench_act(c: &mut Criterion, name: &str, policy: &Policy, y: &[f64], context: &[f64]) {
    let mut ws = policy.workspace();
    let (mut next, mut velocity) = (vec![0.0; y.len()], vec![0.0; y.len()]);
    c.bench_function(name, |b| {
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
