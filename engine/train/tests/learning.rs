//! Training recovers a known stable system (rollout error below a stated bound that the
//! untrained model fails), trained flows stay 100% stable far outside the data, and the
//! unconstrained behaviour-cloning baseline trained on the same data does not.

use ciflow_engine::flow::{
    BehaviourCloning, CheckpointConfig, CouplingKind, Goal, LatentKind, Policy,
};
use ciflow_evaluation::stability::{StabilityConfig, measure};
use ciflow_train::latent::LatentInit;
use ciflow_train::policy::FlowModel;
use ciflow_train::synthetic::Spiral;
use ciflow_train::trainer::{double_var_store, flow_config, save_checkpoint};
use ciflow_train::{BaselineTrainConfig, OptimConfig, TrainConfig, train_baseline, train_flow};

/// Stated bound: mean rollout error over held-out starts, relative to the data's box diagonal.
const MAX_RELATIVE_ROLLOUT_ERROR: f64 = 0.05;
const STEPS: usize = 80;
/// Demonstrations start in this sector only, so the far field away from it is free.
const SECTOR: f64 = std::f64::consts::FRAC_PI_2;

fn temp_dir(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("ciflow-learning-{name}-{}", std::process::id()))
}

fn train_config() -> TrainConfig {
    TrainConfig {
        coupling: CouplingKind::Spline {
            bins: 8,
            tail_bound: 4.0,
        },
        layers: 4,
        hidden: vec![32, 32],
        min_rate: 0.05,
        optim: OptimConfig {
            epochs: 200,
            batch_size: 128,
            learning_rate: 5e-3,
            patience: 60,
            ..OptimConfig::default()
        },
        ..TrainConfig::new("spiral", LatentKind::GoTo)
    }
}

/// Mean distance between the policy's noise-free rollouts and the true trajectories
/// from held-out starts, divided by the box diagonal.
fn rollout_error(policy: &Policy, spiral: &Spiral) -> f64 {
    let mut ws = policy.workspace();
    let diagonal = policy.config().bounds.state_diagonal();
    let (mut total, mut count) = (0.0, 0.0);
    for k in 0..7 {
        // Midway between the 8 demonstrations' start angles.
        let angle = (k as f64 + 0.5) / 7.0 * SECTOR;
        let truth = spiral.trajectory([1.5 * angle.cos(), 1.5 * angle.sin()], STEPS);
        let mut y = truth[0].clone();
        let mut next = vec![0.0; 2];
        for expected in &truth[1..] {
            policy.mean_next(&y, &[], &mut ws, &mut next).unwrap();
            std::mem::swap(&mut y, &mut next);
            total += ((y[0] - expected[0]).powi(2) + (y[1] - expected[1]).powi(2)).sqrt();
            count += 1.0;
        }
    }
    total / count / diagonal
}

#[test]
fn flow_learns_a_known_stable_system_and_stays_stable_while_bc_does_not() {
    let spiral = Spiral::default();
    let data = spiral.demonstrations(8, STEPS, 1.5, (0.0, SECTOR), 1);
    let config = train_config();

    // Untrained: the trainer's initial parameters, through the same checkpoint path.
    let untrained_dir = temp_dir("untrained");
    let vs = double_var_store();
    let flow = flow_config(&data, &config).unwrap();
    FlowModel::new(
        &vs.root(),
        &flow,
        LatentInit {
            sigma: 0.1,
            omega: 0.0,
            speed: 1.0,
        },
    );
    save_checkpoint(&untrained_dir, &CheckpointConfig::Flow(flow), &vs).unwrap();
    let untrained = Policy::load(&untrained_dir, Some("spiral")).unwrap();
    let untrained_error = rollout_error(&untrained, &spiral);

    let trained = train_flow(&data, &config, |_, _| {}).unwrap();
    let dir = temp_dir("trained");
    trained.save(&dir).unwrap();
    let policy = Policy::load(&dir, Some("spiral")).unwrap();
    let error = rollout_error(&policy, &spiral);
    let last = trained.history.last().unwrap();
    eprintln!(
        "rollout error: trained {error:.4}, untrained {untrained_error:.4}; validation NLL {:.3} after {} epochs",
        last.best_validation, last.epoch
    );
    assert!(
        error < MAX_RELATIVE_ROLLOUT_ERROR,
        "trained rollout error {error}"
    );
    assert!(
        untrained_error > MAX_RELATIVE_ROLLOUT_ERROR,
        "untrained rollout error {untrained_error}"
    );
    assert!(last.best_validation < trained.history[0].validation);

    let check = StabilityConfig {
        starts: 100,
        max_steps: 20_000,
        ..StabilityConfig::default()
    };
    for model in [&untrained, &policy] {
        let report = measure(model, &check, |_| {}).unwrap();
        assert_eq!(report.fraction, 1.0, "{report:?}");
    }

    let baseline = train_baseline(
        &data,
        &BaselineTrainConfig {
            hidden: vec![32, 32],
            optim: config.optim.clone(),
            ..BaselineTrainConfig::new(
                "spiral",
                Goal::State {
                    value: vec![0.0, 0.0],
                },
            )
        },
        |_| {},
    )
    .unwrap();
    let baseline_dir = temp_dir("baseline");
    baseline.save(&baseline_dir).unwrap();
    let bc = BehaviourCloning::load(&baseline_dir, Some("spiral")).unwrap();
    let report = measure(&bc, &check, |_| {}).unwrap();
    eprintln!("behaviour cloning stability: {report:?}");
    assert!(report.fraction < 1.0, "{report:?}");
    for d in [untrained_dir, dir, baseline_dir] {
        std::fs::remove_dir_all(d).unwrap();
    }
}
