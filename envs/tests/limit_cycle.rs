//! `ciflow/LimitCycle-v0`: seeding, the expert, options and rendering.

use ciflow_envs::planar::PlanarEnv;
use ciflow_envs::rollout::expert_episode;
use ciflow_envs::tasks::limit_cycle::{
    self, CURLED_HELD_OUT_CONTEXTS, CURLED_TRAINING_CONTEXTS, HELD_OUT_CONTEXTS, LimitCycle,
    SUCCESS_DISTANCE, TRAINING_CONTEXTS,
};
use ciflow_envs::{Env, EnvError, ResetOptions};

fn options_with(key: &str, value: f64) -> ResetOptions {
    ResetOptions {
        extra: [(key.to_string(), value)].into(),
        ..ResetOptions::default()
    }
}

#[test]
fn same_seed_gives_identical_episodes_and_unseeded_resets_continue_the_rng() {
    let run = || {
        let mut env = limit_cycle::make().unwrap();
        let first = expert_episode(&mut env, Some(42), &ResetOptions::default()).unwrap();
        let second = expert_episode(&mut env, None, &ResetOptions::default()).unwrap();
        (first, second)
    };
    let (a, b) = (run(), run());
    assert_eq!(a, b);
    assert_ne!(a.0.observations[0], a.1.observations[0]);
}

#[test]
fn default_contexts_are_the_training_phases_and_held_out_ones_differ() {
    let mut env = limit_cycle::make().unwrap();
    for seed in 0..20 {
        let (obs, _) = env.reset(Some(seed), &ResetOptions::default()).unwrap();
        assert!(TRAINING_CONTEXTS.contains(&obs[4]));
        let (obs, _) = env
            .reset(Some(seed), &options_with("context_set", 1.0))
            .unwrap();
        assert!(HELD_OUT_CONTEXTS.contains(&obs[4]));
    }
}

#[test]
fn consecutive_seeds_demonstrate_every_phase_once_and_unseeded_resets_continue() {
    let mut env = limit_cycle::make().unwrap();
    let phase = |env: &mut PlanarEnv<LimitCycle>, seed, set: f64| {
        env.reset(seed, &options_with("context_set", set))
            .unwrap()
            .0[4]
    };
    for (set, phases) in [
        (0.0, &TRAINING_CONTEXTS[..]),
        (1.0, &HELD_OUT_CONTEXTS[..]),
        (3.0, &CURLED_TRAINING_CONTEXTS[..]),
        (4.0, &CURLED_HELD_OUT_CONTEXTS[..]),
    ] {
        let n = phases.len() as u64;
        for first in [0, 7, 1_000_003] {
            let seen: Vec<f64> = (first..first + n)
                .map(|seed| phase(&mut env, Some(seed), set))
                .collect();
            let mut sorted = seen.clone();
            sorted.sort_by(f64::total_cmp);
            assert_eq!(sorted, phases, "seeds {first}..: {seen:?}");
            // A seeded reset followed by unseeded ones walks the same schedule.
            let walked: Vec<f64> = std::iter::once(phase(&mut env, Some(first), set))
                .chain((1..n).map(|_| phase(&mut env, None, set)))
                .collect();
            assert_eq!(walked, seen);
        }
    }
}

#[test]
fn the_registered_reference_curve_is_the_closed_outline_of_the_phase() {
    let curve = ciflow_envs::registry::entry("limit-cycle")
        .unwrap()
        .reference_curve
        .expect("the limit cycle has an outline");
    for phase in [0.0, 0.5, 1.0, 1.5, 2.0] {
        let points = curve(&[phase]);
        assert!(points.len() > 100);
        assert_eq!(points.first(), points.last());
        let outline = ciflow_envs::vitruvian::Outline::new(phase);
        for p in &points {
            let error = outline.distance(&nalgebra::Vector2::new(p[0], p[1]));
            assert!(error < 1e-12, "{phase}: {p:?} is {error} off");
        }
        // Another phase's outline is another curve.
        let other = ciflow_envs::vitruvian::Outline::new(2.0 - phase);
        let farthest = points
            .iter()
            .map(|p| other.distance(&nalgebra::Vector2::new(p[0], p[1])))
            .fold(0.0, f64::max);
        assert!(phase == 1.0 || farthest > 0.05, "{phase}: {farthest}");
    }
}

#[test]
fn expert_converges_onto_the_outline_for_99_percent_of_uniform_phases() {
    let mut env = limit_cycle::make().unwrap();
    let uniform = options_with("context_set", 2.0);
    let episodes = 100;
    let successes = (0..episodes)
        .filter(|&seed| {
            let episode = expert_episode(&mut env, Some(seed), &uniform).unwrap();
            assert!(episode.truncations.last().copied().unwrap());
            // On the outline for the whole last 2 s, i.e. circulating on the limit cycle.
            let errors = &episode.infos["outline_error"];
            errors[errors.len() - 200..]
                .iter()
                .all(|e| *e < SUCCESS_DISTANCE)
        })
        .count();
    assert!(
        successes * 100 >= 99 * episodes as usize,
        "{successes}/{episodes}"
    );
}

/// The curled outlines, which no polar radius describes: the expert still ends every
/// episode on the curve, by the Euclidean distance to it.
#[test]
fn expert_converges_onto_every_curled_outline() {
    let mut env = limit_cycle::make().unwrap();
    for (set, contexts) in [
        (3.0, &CURLED_TRAINING_CONTEXTS[..]),
        (4.0, &CURLED_HELD_OUT_CONTEXTS[..]),
    ] {
        for seed in 0..contexts.len() as u64 {
            let episode =
                expert_episode(&mut env, Some(seed), &options_with("context_set", set)).unwrap();
            let errors = &episode.infos["outline_error"];
            let worst = errors[errors.len() - 200..]
                .iter()
                .fold(0.0, |a: f64, &e| a.max(e));
            assert!(
                worst < SUCCESS_DISTANCE,
                "context {}: {worst} m",
                episode.contexts[0][0]
            );
        }
    }
}

#[test]
fn expert_circulates_counter_clockwise_around_the_figure() {
    let mut env = limit_cycle::make().unwrap();
    let episode = expert_episode(&mut env, Some(3), &ResetOptions::default()).unwrap();
    // Accumulated polar angle over the episode: 10 s at 0.8 m/s on a ~5 m outline.
    let angle: f64 = episode
        .observations
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0][1].atan2(w[0][0]), w[1][1].atan2(w[1][0]));
            (b - a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
                - std::f64::consts::PI
        })
        .sum();
    assert!(angle > 2.0 * std::f64::consts::PI, "turned {angle} rad");
}

#[test]
fn changing_the_context_mid_episode_moves_the_target_outline() {
    let mut env = limit_cycle::make().unwrap();
    let options = ResetOptions {
        context: Some(vec![0.0]),
        ..ResetOptions::default()
    };
    env.reset(Some(1), &options).unwrap();
    for _ in 0..600 {
        let a = env.expert_action().unwrap();
        env.step(&a).unwrap();
    }
    env.set_context(&[1.0]).unwrap();
    let mut last = None;
    for _ in 0..390 {
        let a = env.expert_action().unwrap();
        last = Some(env.step(&a).unwrap());
    }
    let last = last.unwrap();
    assert_eq!(last.observation[4], 1.0);
    assert!(last.info["outline_error"] < SUCCESS_DISTANCE);
}

#[test]
fn invalid_options_are_typed_errors() {
    let mut env = limit_cycle::make().unwrap();
    let mut err = |options: ResetOptions| env_reset_error(&mut env, options);
    assert!(matches!(
        err(options_with("context_set", 7.0)),
        EnvError::InvalidOption { .. }
    ));
    assert!(matches!(
        err(options_with("shape", 1.0)),
        EnvError::InvalidOption { .. }
    ));
    let context = |c: Vec<f64>| ResetOptions {
        context: Some(c),
        ..ResetOptions::default()
    };
    assert!(matches!(
        err(context(vec![2.5])),
        EnvError::OutOfBounds { .. }
    ));
    assert!(matches!(
        err(context(vec![f64::NAN])),
        EnvError::NotFinite { .. }
    ));
    assert!(matches!(
        err(context(vec![0.1, 0.2])),
        EnvError::WrongDimension { .. }
    ));
    let start = ResetOptions {
        initial_position: Some(vec![0.5]),
        ..ResetOptions::default()
    };
    assert!(matches!(err(start), EnvError::WrongDimension { .. }));
}

fn env_reset_error(env: &mut dyn Env, options: ResetOptions) -> EnvError {
    env.reset(Some(0), &options).unwrap_err()
}

#[test]
fn render_draws_the_outline_and_the_trajectory() {
    let mut env = limit_cycle::make().unwrap();
    let blank = env.render(64, 48).unwrap();
    assert_eq!(blank.len(), 64 * 48 * 3);
    assert!(blank.iter().all(|&v| v == 255));
    env.reset(Some(0), &ResetOptions::default()).unwrap();
    for _ in 0..50 {
        let a = env.expert_action().unwrap();
        env.step(&a).unwrap();
    }
    let frame = env.render(64, 48).unwrap();
    let inked = frame.chunks(3).filter(|p| p != &[255, 255, 255]).count();
    assert!(inked > 100, "{inked} pixels drawn");
    assert!(matches!(
        env.render(0, 10),
        Err(EnvError::InvalidOption { .. })
    ));
}
