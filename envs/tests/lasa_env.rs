//! `ciflow/Lasa-v0`: shape selection, seeding, the expert on every shape, replaying the
//! dataset's demonstrations through the environment, the goal context.

use ciflow_envs::lasa;
use ciflow_envs::registry::{Kwargs, entry};
use ciflow_envs::rollout::expert_episode;
use ciflow_envs::tasks::lasa::{self as task, GOAL_TOLERANCE, SHAPES};
use ciflow_envs::{Env, EnvError, ResetOptions, make_with};

fn options(pairs: &[(&str, f64)]) -> ResetOptions {
    ResetOptions {
        extra: pairs.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
        ..ResetOptions::default()
    }
}

fn kwargs(pairs: &[(&str, f64)]) -> Kwargs {
    pairs
        .iter()
        .map(|(k, v)| (k.to_string(), (*v).into()))
        .collect()
}

/// The distance from `point` to the polyline through `path`.
fn distance_to_path(point: [f64; 2], path: &[[f64; 2]]) -> f64 {
    path.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let ab = [b[0] - a[0], b[1] - a[1]];
            let ap = [point[0] - a[0], point[1] - a[1]];
            let length2 = ab[0] * ab[0] + ab[1] * ab[1];
            let t = if length2 > 0.0 {
                ((ap[0] * ab[0] + ap[1] * ab[1]) / length2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (ap[0] - t * ab[0]).hypot(ap[1] - t * ab[1])
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn the_shape_list_is_the_dataset_s() {
    assert_eq!(lasa::shape_names().unwrap(), SHAPES);
}

#[test]
fn same_seed_gives_identical_episodes_and_unseeded_resets_continue_the_rng() {
    let noisy = options(&[("start_noise", 5.0)]);
    let run = || {
        let mut env = make_with("lasa", &kwargs(&[("shape", 24.0)])).unwrap();
        let first = expert_episode(env.as_mut(), Some(42), &noisy).unwrap();
        let second = expert_episode(env.as_mut(), None, &noisy).unwrap();
        (first, second)
    };
    let (a, b) = (run(), run());
    assert_eq!(a, b);
    assert_ne!(a.0.observations[0], a.1.observations[0]);
    assert!(a.0.infos["shape"].iter().all(|&s| s == 24.0));
}

#[test]
fn expert_follows_and_finishes_every_demonstration_of_every_shape() {
    let mut env = task::make(0).unwrap();
    let (mut episodes, mut successes, mut total_distance) = (0, 0, 0.0);
    for (shape, name) in SHAPES.iter().enumerate() {
        let data = lasa::load(name).unwrap();
        for (demo, recorded) in data.demos.iter().enumerate() {
            let reset = options(&[("shape", shape as f64), ("demo", demo as f64)]);
            let episode = expert_episode(&mut env, Some(0), &reset).unwrap();
            assert_eq!(&episode.observations[0][..2], &recorded.positions[0][..]);
            episodes += 1;
            if episode.terminations.last() == Some(&true) {
                successes += 1;
            }
            // The expert draws the demonstrated shape. One demonstration lies on average
            // 1–4 mm from the paths of the six others (10 mm for the Multi_Models).
            let mean_distance = episode
                .observations
                .iter()
                .map(|o| distance_to_path([o[0], o[1]], &recorded.positions))
                .sum::<f64>()
                / episode.observations.len() as f64;
            assert!(
                mean_distance < 4.0,
                "{name} #{demo}: {mean_distance} mm off"
            );
            total_distance += mean_distance;
        }
    }
    assert!(successes * 100 >= 99 * episodes, "{successes}/{episodes}");
    let mean = total_distance / episodes as f64;
    assert!(mean < 1.5, "{mean} mm from the demonstrations on average");
}

#[test]
fn expert_reaches_the_goal_from_random_starts_near_the_demonstrations() {
    let mut env = task::make(0).unwrap();
    let episodes = 120;
    let successes = (0..episodes)
        .filter(|&seed| {
            let reset = options(&[("shape", (seed % 30) as f64), ("start_noise", 8.0)]);
            let episode = expert_episode(&mut env, Some(seed), &reset).unwrap();
            let success = episode.infos["is_success"].last() == Some(&1.0);
            assert_eq!(success, episode.terminations.last() == Some(&true));
            success
        })
        .count();
    assert!(
        successes * 100 >= 99 * episodes as usize,
        "{successes}/{episodes}"
    );
}

/// Positions of `demo` at the times `k dt`, by linear interpolation.
fn resample(demo: &lasa::Demo, dt: f64) -> Vec<[f64; 2]> {
    let end = *demo.times.last().unwrap();
    let mut j = 0;
    (0..)
        .map(|k| k as f64 * dt)
        .take_while(|t| *t <= end)
        .map(|t| {
            while demo.times[j + 1] < t {
                j += 1;
            }
            let (t0, t1) = (demo.times[j], demo.times[j + 1]);
            let s = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
            let (a, b) = (demo.positions[j], demo.positions[j + 1]);
            [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])]
        })
        .collect()
}

#[test]
fn replaying_a_demonstration_s_accelerations_tracks_it_and_reaches_the_goal() {
    let mut env = task::make(0).unwrap();
    let dt = env.spec().control_dt;
    for (shape, name) in SHAPES.iter().enumerate() {
        let data = lasa::load(name).unwrap();
        let demo = &data.demos[shape % data.demos.len()];
        let p = resample(demo, dt);
        // From t_1 on, the acceleration held over [t_k, t_k+1] is the mean of the second
        // differences at t_k and t_k+1 (the interval's midpoint) and the initial velocity
        // the central difference at t_1: the double integrator then passes through the
        // samples up to O(dt²) terms that do not accumulate.
        let acceleration = |k: usize| {
            [0, 1].map(|axis| {
                (p[k + 2][axis] - p[k + 1][axis] - p[k][axis] + p[k - 1][axis]) / (2.0 * dt * dt)
            })
        };
        let initial_velocity = [0, 1].map(|axis| (p[2][axis] - p[0][axis]) / (2.0 * dt));
        let reset = ResetOptions {
            initial_position: Some(p[1].to_vec()),
            initial_velocity: Some(initial_velocity.to_vec()),
            ..options(&[("shape", shape as f64)])
        };
        env.reset(Some(0), &reset).unwrap();
        let mut worst: f64 = 0.0;
        let mut last = None;
        for k in 1..p.len() - 2 {
            let step = env.step(&acceleration(k)).unwrap();
            let [x, y] = p[k + 1];
            worst = worst.max((step.observation[0] - x).hypot(step.observation[1] - y));
            let done = step.terminated;
            last = Some(step);
            if done {
                break;
            }
        }
        let last = last.unwrap();
        let (distance, finished) = (last.info["distance_to_goal"], last.terminated);
        assert!(
            worst < 0.1,
            "{name}: replay {worst} mm off the demonstration"
        );
        assert!(finished, "{name}: ends {distance} mm from the goal");
    }
}

#[test]
fn the_goal_context_translates_the_shape_and_can_move_mid_episode() {
    let mut env = task::make(2).unwrap();
    let reference = env.reset(Some(0), &options(&[("demo", 1.0)])).unwrap().0;
    assert_eq!(&reference[4..], &[0.0, 0.0]);
    let goal = vec![6.0, -4.0];
    let moved = ResetOptions {
        context: Some(goal.clone()),
        ..options(&[("demo", 1.0)])
    };
    let episode = expert_episode(&mut env, Some(0), &moved).unwrap();
    assert!((episode.observations[0][0] - reference[0] - 6.0).abs() < 1e-12);
    assert!((episode.observations[0][1] - reference[1] + 4.0).abs() < 1e-12);
    let end = episode.observations.last().unwrap();
    assert!(episode.terminations.last() == Some(&true));
    assert!((end[0] - 6.0).hypot(end[1] + 4.0) < GOAL_TOLERANCE);
    // Moving the goal half-way: the expert ends at the new one.
    env.reset(Some(0), &options(&[("demo", 1.0)])).unwrap();
    let mut last = None;
    for k in 0..1500 {
        if k == 100 {
            env.set_context(&[-5.0, 5.0]).unwrap();
        }
        let step = env.step(&env.expert_action().unwrap()).unwrap();
        let done = step.terminated || step.truncated;
        last = Some(step);
        if done {
            break;
        }
    }
    let last = last.unwrap();
    assert!(last.terminated);
    assert!((last.observation[0] + 5.0).hypot(last.observation[1] - 5.0) < GOAL_TOLERANCE);
    assert!(matches!(
        env.set_context(&[20.0, 0.0]),
        Err(EnvError::OutOfBounds { .. })
    ));
}

#[test]
fn shapes_are_picked_by_index_or_name_and_bad_choices_are_typed_errors() {
    let lasa_entry = entry("ciflow/Lasa-v0").unwrap();
    assert_eq!(lasa_entry.value("shape", "Sshape").unwrap(), 24.0);
    assert_eq!(lasa_entry.value("shape", "7").unwrap(), 7.0);
    assert_eq!(task::shape_index("heee").unwrap(), 29);
    let mut by_name = task::make_named("Sshape").unwrap();
    let (_, info) = by_name.reset(Some(0), &ResetOptions::default()).unwrap();
    assert_eq!(info["shape"], 24.0);
    let invalid = |e: EnvError| matches!(e, EnvError::InvalidOption { .. });
    assert!(invalid(lasa_entry.value("shape", "Circle").unwrap_err()));
    assert!(invalid(lasa_entry.value("demo", "first").unwrap_err()));
    assert!(invalid(task::shape_index("Circle").unwrap_err()));
    assert!(invalid(task::make(30).err().unwrap()));
    for bad in [30.0, -1.0, 2.5, f64::NAN] {
        assert!(invalid(
            make_with("lasa", &kwargs(&[("shape", bad)])).err().unwrap()
        ));
    }
    assert!(invalid(
        make_with("lasa", &kwargs(&[("shapes", 1.0)]))
            .err()
            .unwrap()
    ));
    let mut env = task::make(0).unwrap();
    for bad in [
        options(&[("shape", 30.0)]),
        options(&[("demo", 7.0)]),
        options(&[("demo", -1.0)]),
        options(&[("start_noise", -1.0)]),
        options(&[("start_noise", f64::INFINITY)]),
        options(&[("obstacles", 1.0)]),
    ] {
        assert!(invalid(env.reset(Some(0), &bad).unwrap_err()));
    }
    // A failed reset ends the episode: stepping needs a new reset.
    assert!(matches!(
        env.step(&[0.0, 0.0]).unwrap_err(),
        EnvError::NeedsReset
    ));
}

#[test]
fn render_draws_the_demonstrations_and_the_trajectory() {
    let mut env = task::make(24).unwrap();
    env.reset(Some(0), &ResetOptions::default()).unwrap();
    let before = env.render(96, 96).unwrap();
    for _ in 0..100 {
        env.step(&env.expert_action().unwrap()).unwrap();
    }
    let after = env.render(96, 96).unwrap();
    let inked = |frame: &[u8]| frame.chunks(3).filter(|p| p != &[255, 255, 255]).count();
    assert!(inked(&before) > 200, "{} pixels drawn", inked(&before));
    assert!(inked(&after) > inked(&before));
}
