//! One full policy action at the pouring size (d = 7, context 6, 10 coupling layers of
//! 2×64 hidden): inverse, latent step, forward and the Jacobian-vector product of the
//! desired velocity (`Policy::act`), plus the second-order `Policy::acceleration`.
//! Target: `act` < 20 µs. The tch eager figure is printed beside it by
//! `cargo bench -p ciflow-train --bench flow_tch`.

use std::hint::black_box;

use ciflow_engine::flow::{CouplingKind, FlowConfig, LatentKind, Policy, Weights};
use criterion::{Criterion, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn pouring_policy(coupling: CouplingKind) -> Policy {
    let config = FlowConfig::new(
        "pouring",
        7,
        6,
        LatentKind::GoTo,
        coupling,
        10,
        vec![64, 64],
    );
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.5,
        &mut ChaCha8Rng::seed_from_u64(0),
    );
    Policy::new(&config, weights).expect("valid policy")
}

fn bench(c: &mut Criterion) {
    let y = [0.1, -0.3, 0.2, -1.5, 0.05, 1.2, 0.4];
    let qd = [0.01, 0.02, -0.03, 0.0, 0.1, -0.05, 0.02];
    let context = [0.5, 0.2, 0.3, 0.0, 0.1, -0.2];
    for (name, coupling) in [
        ("affine", CouplingKind::Affine { scale_bound: 2.0 }),
        (
            "spline",
            CouplingKind::Spline {
                bins: 8,
                tail_bound: 4.0,
            },
        ),
    ] {
        let policy = pouring_policy(coupling);
        let mut ws = policy.workspace();
        let (mut next, mut velocity, mut acceleration) = ([0.0; 7], [0.0; 7], [0.0; 7]);
        c.bench_function(&format!("flow/act/{name}"), |b| {
            b.iter(|| {
                policy
                    .act(
                        black_box(&y),
                        black_box(&context),
                        &mut ws,
                        &mut next,
                        &mut velocity,
                    )
                    .unwrap();
                black_box(&next);
            })
        });
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

criterion_group!(benches, bench);
criterion_main!(benches);
