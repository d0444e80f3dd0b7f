//! The point-mass environments' dynamics, perturbations and episode bookkeeping.

use ciflow_engine::sim::{Perturbation, PerturbationKind};
use ciflow_envs::tasks::obstacle_avoidance;
use ciflow_envs::{Env, EnvError, ResetOptions};

fn at_rest(x: [f64; 2]) -> ResetOptions {
    ResetOptions {
        initial_position: Some(x.to_vec()),
        initial_velocity: Some(vec![0.0, 0.0]),
        ..ResetOptions::default()
    }
}

#[test]
fn actions_are_accelerations() {
    let mut env = obstacle_avoidance::make(1).unwrap();
    env.reset(Some(0), &at_rest([-0.9, 0.0])).unwrap();
    let a = [2.0, -1.0];
    let mut observation = vec![];
    for _ in 0..10 {
        observation = env.step(&a).unwrap().observation;
    }
    // 0.1 s of constant acceleration: v = a t exactly.
    assert!((observation[2] - 0.2).abs() < 1e-12 && (observation[3] + 0.1).abs() < 1e-12);
}

#[test]
fn a_force_perturbation_changes_velocity_by_impulse_over_mass() {
    let mut env = obstacle_avoidance::make(1).unwrap();
    env.reset(Some(0), &at_rest([-0.9, 0.0])).unwrap();
    env.perturb(Perturbation {
        kind: PerturbationKind::LinkWrench {
            link: 0,
            force: [0.0, 3.0, 0.0],
            torque: [0.0; 3],
        },
        start: 0.05,
        duration: 0.1,
    })
    .unwrap();
    let mut observation = vec![];
    for _ in 0..30 {
        observation = env.step(&[0.0, 0.0]).unwrap().observation;
    }
    // Impulse 3 N × 0.1 s on 1 kg; the displacement is v·(t_end − t_mid) = 0.3 × 0.2.
    // The window's ends are compared in floating point, so it may cover one 1 ms physics
    // substep more or less: a tolerance of one substep's impulse, 3 mN·s.
    assert!(
        (observation[3] - 0.3).abs() <= 3.0e-3 + 1e-12,
        "vy = {}",
        observation[3]
    );
    assert!(
        (observation[1] - 0.06).abs() < 2e-3,
        "y = {}",
        observation[1]
    );
    assert_eq!(observation[2], 0.0);
}

#[test]
fn invalid_actions_and_calls_are_typed_errors() {
    let mut env = obstacle_avoidance::make(2).unwrap();
    assert!(matches!(
        env.step(&[0.0, 0.0]).unwrap_err(),
        EnvError::NeedsReset
    ));
    assert!(matches!(
        env.expert_action().unwrap_err(),
        EnvError::NeedsReset
    ));
    env.reset(Some(0), &ResetOptions::default()).unwrap();
    assert!(matches!(
        env.step(&[0.0]),
        Err(EnvError::WrongDimension { .. })
    ));
    assert!(matches!(
        env.step(&[f64::NAN, 0.0]),
        Err(EnvError::NotFinite { .. })
    ));
    assert!(matches!(
        env.step(&[1e3, 0.0]),
        Err(EnvError::OutOfBounds { .. })
    ));
    let bad_link = Perturbation {
        kind: PerturbationKind::LinkWrench {
            link: 3,
            force: [1.0, 0.0, 0.0],
            torque: [0.0; 3],
        },
        start: 0.0,
        duration: 1.0,
    };
    assert!(matches!(
        env.perturb(bad_link),
        Err(EnvError::InvalidPerturbation(_))
    ));
    assert!(matches!(
        env.set_context(&[0.0; 3]),
        Err(EnvError::WrongDimension { .. })
    ));
}

#[test]
fn stepping_after_the_end_needs_a_reset() {
    let mut env = obstacle_avoidance::make(1).unwrap();
    env.reset(Some(0), &ResetOptions::default()).unwrap();
    let mut steps = 0;
    loop {
        let step = env.step(&[0.0, 0.0]).unwrap();
        steps += 1;
        if step.terminated || step.truncated {
            assert!(step.truncated && !step.terminated);
            break;
        }
    }
    assert_eq!(steps, env.spec().max_episode_steps);
    assert!(matches!(
        env.step(&[0.0, 0.0]).unwrap_err(),
        EnvError::NeedsReset
    ));
}
