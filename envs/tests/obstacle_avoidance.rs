//! `ciflow/Obstacle-v0`: the expert, contexts, options.

use ciflow_envs::rollout::expert_episode;
use ciflow_envs::tasks::obstacle_avoidance::{self, OBSTACLE_RADIUS};
use ciflow_envs::{Env, EnvError, ResetOptions, make_with};

#[test]
fn context_dimension_follows_the_obstacle_count() {
    for (obstacles, dim) in [(1, 4), (2, 6), (3, 8)] {
        let kwargs = [("obstacles".to_string(), (obstacles as f64).into())].into();
        let env = make_with("obstacle-avoidance", &kwargs).unwrap();
        assert_eq!(env.spec().context_space.dim(), dim);
        assert_eq!(env.spec().observation_space.dim(), 4 + dim);
    }
    for bad in [0.0, 4.0, 1.5] {
        let kwargs = [("obstacles".to_string(), bad.into())].into();
        assert!(matches!(
            make_with("obstacle-avoidance", &kwargs),
            Err(EnvError::InvalidOption { .. })
        ));
    }
}

#[test]
fn expert_never_collides_and_reaches_the_target_for_99_percent_of_contexts() {
    for obstacles in 1..=3 {
        let mut env = obstacle_avoidance::make(obstacles).unwrap();
        let episodes = 150;
        let mut successes = 0;
        for seed in 0..episodes {
            let episode = expert_episode(&mut env, Some(seed), &ResetOptions::default()).unwrap();
            // Clearance from every obstacle body along the whole path.
            for (observation, context) in episode.observations.iter().zip(&episode.contexts) {
                for centre in context[..context.len() - 2].chunks(2) {
                    let d = (observation[0] - centre[0]).hypot(observation[1] - centre[1]);
                    assert!(d > OBSTACLE_RADIUS, "seed {seed}: {d} m from an obstacle");
                }
            }
            assert!(episode.infos["collision"].iter().all(|&c| c == 0.0));
            successes += usize::from(*episode.infos["is_success"].last().unwrap() == 1.0);
        }
        assert!(
            successes * 100 >= 99 * episodes as usize,
            "{obstacles}: {successes}/{episodes}"
        );
    }
}

#[test]
fn demonstrations_vary_continuously_with_the_context() {
    let mut env = obstacle_avoidance::make(3).unwrap();
    let (first, _) = env.reset(Some(5), &ResetOptions::default()).unwrap();
    let context = first[4..].to_vec();
    let run = |env: &mut dyn ciflow_envs::Env, shift: f64| {
        let mut c = context.clone();
        c[0] += shift;
        let options = ResetOptions {
            context: Some(c),
            initial_position: Some(first[..2].to_vec()),
            ..ResetOptions::default()
        };
        expert_episode(env, None, &options).unwrap()
    };
    let base = run(&mut env, 0.0);
    let near = run(&mut env, 1e-4);
    let gap = base
        .observations
        .iter()
        .zip(&near.observations)
        .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
        .fold(0.0, f64::max);
    assert!(
        gap < 1e-2,
        "a 0.1 mm obstacle shift moved the path by {gap} m"
    );
}

#[test]
fn invalid_contexts_and_options_are_typed_errors() {
    let mut env = obstacle_avoidance::make(2).unwrap();
    let with_context = |c: Vec<f64>| ResetOptions {
        context: Some(c),
        ..ResetOptions::default()
    };
    // Overlapping obstacles, then a target inside an obstacle's safety disc.
    let overlapping = with_context(vec![0.0, 0.0, 0.1, 0.0, 0.8, 0.0]);
    assert!(matches!(
        env.reset(None, &overlapping),
        Err(EnvError::OutOfBounds { .. })
    ));
    let target_inside = with_context(vec![0.0, 0.0, 0.45, 0.0, 0.55, 0.0]);
    assert!(matches!(
        env.reset(None, &target_inside),
        Err(EnvError::OutOfBounds { .. })
    ));
    let change_count = ResetOptions {
        extra: [("obstacles".to_string(), 3.0)].into(),
        ..ResetOptions::default()
    };
    assert!(matches!(
        env.reset(None, &change_count),
        Err(EnvError::InvalidOption { .. })
    ));
    let start_in_obstacle = ResetOptions {
        context: Some(vec![0.0, 0.0, 0.0, 0.5, 0.8, 0.0]),
        initial_position: Some(vec![0.01, 0.0]),
        ..ResetOptions::default()
    };
    assert!(matches!(
        env.reset(None, &start_in_obstacle),
        Err(EnvError::OutOfBounds { .. })
    ));
}
