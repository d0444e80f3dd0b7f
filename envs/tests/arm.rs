//! The environment the arm tasks share (`envs/src/arm.rs`), on both of them: pouring
//! (the Panda) and reach (the Panda by default); and how a batch of them splits its reset
//! options.

use ciflow_envs::env::PERTURBED_INFO;
use ciflow_envs::{Env, EnvError, ResetOptions};

fn arm_tasks() -> Vec<Box<dyn Env>> {
    ["ciflow/Pouring-v0", "ciflow/Reach-v0"]
        .into_iter()
        .map(|id| ciflow_envs::make(id).unwrap())
        .collect()
}

#[test]
fn a_failed_reset_leaves_no_episode_to_step() {
    for mut env in arm_tasks() {
        let id = env.spec().id.clone();
        env.reset(Some(0), &ResetOptions::default()).unwrap();
        let hold = vec![0.0; env.spec().action_space.dim()];
        env.step(&hold).unwrap();
        let outside = ResetOptions {
            context: Some(vec![1e3; env.spec().context_space.dim()]),
            ..ResetOptions::default()
        };
        assert!(
            matches!(env.reset(None, &outside), Err(EnvError::OutOfBounds { .. })),
            "{id}"
        );
        assert!(
            matches!(env.step(&hold), Err(EnvError::NeedsReset)),
            "{id}: stepped the episode a failed reset left behind"
        );
        env.reset(None, &ResetOptions::default()).unwrap();
        env.step(&hold).unwrap();
    }
}

#[test]
fn info_has_the_same_keys_at_reset_and_at_every_step_ending_with_perturbed_and_time() {
    for mut env in arm_tasks() {
        let (_, reset_info) = env.reset(Some(1), &ResetOptions::default()).unwrap();
        let keys: Vec<String> = reset_info.iter().map(|(k, _)| k.to_string()).collect();
        assert_eq!(keys[keys.len() - 2..], [PERTURBED_INFO, "time"], "{keys:?}");
        assert_eq!(reset_info.get("time"), Some(&0.0));
        for step in 1..=3 {
            let action = env.expert_action().unwrap();
            let info = env.step(&action).unwrap().info;
            let step_keys: Vec<String> = info.iter().map(|(k, _)| k.to_string()).collect();
            assert_eq!(step_keys, keys);
            let time = info.get("time").copied().unwrap();
            assert!((time - 0.01 * step as f64).abs() < 1e-12, "time {time}");
        }
    }
}

/// `ResetOptions::rows` on an arm's layout (7 positions, a 6-D context): the rows of a
/// batch of 3 go to their environments, a value for all stays one, and any other length
/// is refused by `check_rows`, naming both lengths a batch takes.
#[test]
fn reset_options_give_each_environment_of_a_batch_its_row() {
    let env = ciflow_envs::make("ciflow/Pouring-v0").unwrap();
    let spec = env.spec();
    assert_eq!(spec.position_dim(), 7);
    let numbers = |range: std::ops::Range<usize>| range.map(|k| k as f64).collect::<Vec<_>>();
    let options = ResetOptions {
        context: Some(numbers(0..18)),
        initial_position: Some(numbers(100..121)),
        initial_velocity: Some(vec![0.5; 7]),
        ..ResetOptions::default()
    };
    assert!(options.has_rows(3, spec));
    let second = options.rows(3, 1..2, spec);
    assert_eq!(second.context, Some(numbers(6..12)));
    assert_eq!(second.initial_position, Some(numbers(107..114)));
    assert_eq!(second.initial_velocity, Some(vec![0.5; 7]));
    let last_two = options.rows(3, 1..3, spec);
    assert_eq!(last_two.context, Some(numbers(6..18)));
    assert!(last_two.has_rows(2, spec));

    let shared = ResetOptions {
        context: Some(numbers(0..6)),
        initial_position: Some(numbers(0..7)),
        ..ResetOptions::default()
    };
    assert!(!shared.has_rows(3, spec));
    assert_eq!(shared.rows(3, 2..3, spec), shared);
    let odd = ResetOptions {
        context: Some(numbers(0..12)),
        ..ResetOptions::default()
    };
    assert!(!odd.has_rows(3, spec));
    assert_eq!(odd.rows(3, 0..1, spec).context, Some(numbers(0..12)));

    options.check_rows(3, spec).unwrap();
    shared.check_rows(3, spec).unwrap();
    let refused = odd.check_rows(3, spec).unwrap_err().to_string();
    assert!(
        refused.starts_with("context has 12 numbers")
            && refused.contains("takes 6 (")
            && refused.contains("or 18 ("),
        "{refused}"
    );
    let short_velocity = ResetOptions {
        initial_velocity: Some(numbers(0..14)),
        ..ResetOptions::default()
    };
    assert!(short_velocity.check_rows(3, spec).is_err());
    assert!(short_velocity.check_rows(2, spec).is_ok(), "two rows of 7");
    assert!(
        odd.check_rows(1, spec).is_ok(),
        "one environment refuses it itself"
    );
}
