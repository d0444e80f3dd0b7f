//! Measured stability: 100% for random (untrained) flows of every variant; and the check
//! can fail: it flags the same flows with their latent run backwards in time (a negative
//! control of the same class) and the unconstrained behaviour-cloning baseline.

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
fn the_check_flags_every_rollout_of_the_time_reversed_flows() {
    for (k, config) in variants().iter().enumerate() {
        let policy = random_policy(config, 1000 * k as u64).time_reversed();
        let report = measure(&policy, &check(), |_| {}).unwrap();
        assert_eq!(report.converged, 0, "variant {k}: {report:?}");
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
