//! Measured stability: 100% for random (untrained) flows of every variant, below 100% for
//! the unconstrained behaviour-cloning baseline — so the check can fail.

mod flow_common;

use ciflow_engine::flow::stability::{StabilityConfig, measure};
use ciflow_engine::flow::{BaselineConfig, BehaviourCloning, Goal, Normalisation, Weights};
use flow_common::*;

fn check() -> StabilityConfig {
    StabilityConfig {
        starts: 40,
        max_steps: 5_000,
        ..StabilityConfig::default()
    }
}

#[test]
fn random_flows_converge_from_starts_100x_outside_the_data() {
    for (k, config) in variants().iter().enumerate() {
        for seed in 0..2 {
            let policy = random_policy(config, 1000 * k as u64 + seed);
            let report = measure(&policy, &check(), |_| {}).unwrap();
            assert_eq!(report.fraction, 1.0, "variant {k} seed {seed}: {report:?}");
        }
    }
}

#[test]
fn random_behaviour_cloning_does_not_converge_everywhere() {
    let (d, m) = (2, 2);
    let config = BaselineConfig {
        task: "test".into(),
        state_dim: d,
        context_dim: m,
        dt: 0.05,
        hidden: vec![32, 32],
        goal: Goal::ContextIndices {
            indices: vec![0, 1],
        },
        normalisation: Normalisation::identity(d, m),
        bounds: flow_common::config(d, m, ciflow_engine::flow::LatentKind::GoTo, AFFINE).bounds,
    };
    let weights = Weights::random(&config.parameter_shapes(), 1.0, &mut rng(9));
    let baseline = BehaviourCloning::new(&config, weights).unwrap();
    let report = measure(&baseline, &check(), |_| {}).unwrap();
    assert!(report.fraction < 1.0, "{report:?}");
}
