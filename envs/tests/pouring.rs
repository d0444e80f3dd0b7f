//! `ciflow/Pouring-v0`: the expert pours without spilling, continuity, perturbations.

use ciflow_engine::sim::{Perturbation, PerturbationKind};
use ciflow_envs::arm::ArmEnv;
use ciflow_envs::env::PERTURBED_INFO;
use ciflow_envs::rollout::expert_episode;
use ciflow_envs::scene::{Body, Shape};
use ciflow_envs::tasks::pouring::{self, DEMO_PUSH_DURATION, PUSH_FORCE_OPTION, Pouring};
use ciflow_envs::{Env, EnvError, ResetOptions};

#[test]
fn expert_pours_into_the_pot_and_never_spills() {
    let mut env = pouring::make().unwrap();
    let episodes = 40;
    let mut successes = 0;
    for seed in 0..episodes {
        let episode = expert_episode(&mut env, Some(seed), &ResetOptions::default()).unwrap();
        assert!(
            episode.infos["spill"].iter().all(|&s| s == 0.0),
            "seed {seed} spilled"
        );
        assert!(episode.truncations.last().copied().unwrap());
        let tilts = &episode.infos["tilt"];
        let pouring = &episode.infos["is_success"];
        // Upright (no tilt beyond 0.3 rad) until the spout is over the pot.
        for ((tilt, over), distance) in tilts
            .iter()
            .zip(&episode.infos["over_pot"])
            .zip(&episode.infos["pour_distance"])
        {
            assert!(
                *tilt < 0.3 || *over == 1.0,
                "seed {seed}: tilt {tilt} at {distance} m"
            );
        }
        successes += usize::from(pouring[pouring.len() - 50..].iter().all(|&s| s == 1.0));
    }
    assert!(
        successes * 100 >= 99 * episodes as usize,
        "{successes}/{episodes}"
    );
}

/// A pushed demonstration flags one block of steps: it begins at the first step whose state
/// differs from the same seed's unpushed episode, and lasts as long as the push.
#[test]
fn pushed_demonstrations_flag_the_steps_the_push_acted_in() {
    let mut env = pouring::make().unwrap();
    let pushed = ResetOptions {
        extra: [(PUSH_FORCE_OPTION.to_string(), 40.0)].into(),
        ..ResetOptions::default()
    };
    for seed in 0..5 {
        let free = expert_episode(&mut env, Some(seed), &ResetOptions::default()).unwrap();
        let episode = expert_episode(&mut env, Some(seed), &pushed).unwrap();
        assert!(free.infos[PERTURBED_INFO].iter().all(|&f| f == 0.0));
        let flags = &episode.infos[PERTURBED_INFO];
        let first = flags
            .iter()
            .position(|&f| f == 1.0)
            .expect("a flagged step");
        let last = flags.iter().rposition(|&f| f == 1.0).unwrap();
        assert!(
            flags[first..=last].iter().all(|&f| f == 1.0),
            "seed {seed}: one block"
        );
        let diverged = (0..flags.len())
            .position(|t| episode.observations[t] != free.observations[t])
            .expect("the push moved the arm");
        assert_eq!(first, diverged, "seed {seed}");
        let seconds = (last - first + 1) as f64 * env.spec().control_dt;
        assert!(
            (seconds - DEMO_PUSH_DURATION).abs() <= env.spec().control_dt + 1e-9,
            "seed {seed}: flagged {seconds} s, pushed {DEMO_PUSH_DURATION} s"
        );
    }
}

#[test]
fn the_final_posture_varies_continuously_with_the_pot_pose() {
    let mut env = pouring::make().unwrap();
    let final_posture = |env: &mut ArmEnv<Pouring>, context: Vec<f64>| {
        let options = ResetOptions {
            context: Some(context),
            initial_position: Some(ciflow_engine::robot::PANDA_HOME.to_vec()),
            ..ResetOptions::default()
        };
        let episode = expert_episode(env, None, &options).unwrap();
        episode.observations.last().unwrap()[..7].to_vec()
    };
    let base = vec![0.5, 0.0, 0.05, 0.0, 0.0, 0.0];
    let reference = final_posture(&mut env, base.clone());
    for axis in 0..6 {
        let mut shifted = base.clone();
        shifted[axis] += 0.01;
        let posture = final_posture(&mut env, shifted);
        let change = reference
            .iter()
            .zip(&posture)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            change < 0.1,
            "a 0.01 change of context {axis} moved a joint by {change} rad"
        );
        assert!(change > 0.0);
    }
}

#[test]
fn a_push_on_the_hand_moves_the_arm_and_the_expert_recovers() {
    let mut env = pouring::make().unwrap();
    let options = ResetOptions {
        context: Some(vec![0.5, 0.0, 0.05, 0.0, 0.0, 0.0]),
        initial_position: Some(ciflow_engine::robot::PANDA_HOME.to_vec()),
        ..ResetOptions::default()
    };
    env.reset(None, &options).unwrap();
    // Free motion (q̈_des = 0) from rest under a lateral push on link 7: the joint
    // velocities follow q̈ = M⁻¹ Jᵀ f, so only a push makes the arm move.
    let mut quiet = env.step(&[0.0; 7]).unwrap().observation;
    assert!(quiet[7..14].iter().all(|v| v.abs() < 1e-6));
    env.perturb(Perturbation {
        kind: PerturbationKind::LinkWrench {
            link: 6,
            force: [0.0, 20.0, 0.0],
            torque: [0.0; 3],
        },
        start: 0.01,
        duration: 0.1,
    })
    .unwrap();
    for _ in 0..10 {
        quiet = env.step(&[0.0; 7]).unwrap().observation;
    }
    let joint_speed: f64 = quiet[7..14].iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!(
        joint_speed > 0.05,
        "the push moved the joints at {joint_speed} rad/s"
    );
    // The expert still pours without spilling after the push.
    let mut last = None;
    for _ in 0..500 {
        let action = env.expert_action().unwrap();
        let step = env.step(&action).unwrap();
        assert_eq!(step.info["spill"], 0.0);
        last = Some(step);
    }
    assert_eq!(last.unwrap().info["is_success"], 1.0);
}

/// The push, with the expert in control: for each of four horizontal directions,
/// the weakest 0.2 s push on the hand (in 10 N steps) that moves the cup's centre by 5 cm
/// from where it would have been spills nothing. The Panda's reflected rotor inertia
/// (`PANDA_ARMATURE`) makes the arm give way as a whole; without it the light wrist spins
/// and such pushes tip the cup past `SPILL_TILT`.
#[test]
fn the_weakest_push_that_displaces_the_cup_5_cm_spills_nothing() {
    let mut env = pouring::make().unwrap();
    let options = ResetOptions {
        context: Some(vec![0.5, 0.0, 0.05, 0.0, 0.0, 0.0]),
        initial_position: Some(ciflow_engine::robot::PANDA_HOME.to_vec()),
        ..ResetOptions::default()
    };
    // The cup's centre at each step, and whether the episode spilled.
    let run = |env: &mut ArmEnv<Pouring>, force: [f64; 3]| {
        env.reset(None, &options).unwrap();
        env.perturb(Perturbation {
            kind: PerturbationKind::LinkWrench {
                link: 6,
                force,
                torque: [0.0; 3],
            },
            start: 1.0,
            duration: 0.2,
        })
        .unwrap();
        let mut centres = vec![];
        for _ in 0..400 {
            let action = env.expert_action().unwrap();
            let step = env.step(&action).unwrap();
            let cup = env.cup().unwrap();
            centres.push((cup.bottom + cup.top) / 2.0);
            if step.terminated {
                return (centres, true);
            }
        }
        (centres, false)
    };
    let (calm, _) = run(&mut env, [0.0; 3]);
    for angle in [0.0, 0.5, 1.0, 1.5].map(|a: f64| a * std::f64::consts::PI) {
        let (force, spilled) = (1..=30)
            .map(|k| 10.0 * k as f64)
            .find_map(|force| {
                let (pushed, spilled) =
                    run(&mut env, [force * angle.cos(), force * angle.sin(), 0.0]);
                let displacement = pushed
                    .iter()
                    .zip(&calm)
                    .map(|(p, c)| (p - c).norm())
                    .fold(0.0, f64::max);
                (displacement >= 0.05).then_some((force, spilled))
            })
            .expect("a push of at most 300 N displaces the cup by 5 cm");
        assert!(!spilled, "the {force} N push at {angle} rad spilled");
    }
}

#[test]
fn invalid_inputs_are_typed_errors() {
    let mut env = pouring::make().unwrap();
    assert!(matches!(
        env.expert_action().unwrap_err(),
        EnvError::NeedsReset
    ));
    let context = |c: Vec<f64>| ResetOptions {
        context: Some(c),
        ..ResetOptions::default()
    };
    assert!(matches!(
        env.reset(None, &context(vec![0.5; 5])),
        Err(EnvError::WrongDimension { .. })
    ));
    assert!(matches!(
        env.reset(None, &context(vec![2.0, 0.0, 0.0, 0.0, 0.0, 0.0])),
        Err(EnvError::OutOfBounds { .. })
    ));
    let outside_limits = ResetOptions {
        initial_position: Some(vec![0.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0]),
        ..ResetOptions::default()
    };
    assert!(matches!(
        env.reset(None, &outside_limits),
        Err(EnvError::OutOfBounds { .. })
    ));
    env.reset(Some(0), &ResetOptions::default()).unwrap();
    assert!(matches!(
        env.step(&[100.0; 7]),
        Err(EnvError::OutOfBounds { .. })
    ));
    assert!(matches!(
        env.step(&[0.0; 6]),
        Err(EnvError::WrongDimension { .. })
    ));
    let frame = env.render(96, 96).unwrap();
    assert!(frame.chunks(3).filter(|p| p != &[255, 255, 255]).count() > 200);
    assert!(matches!(
        env.render(96, 0),
        Err(EnvError::InvalidOption { .. })
    ));
}

#[test]
fn render_shows_the_cup_held_by_the_hand_above_the_pot() {
    let mut env = pouring::make().unwrap();
    let (mut observation, _) = env.reset(Some(0), &ResetOptions::default()).unwrap();
    for step in 0..600 {
        if step % 200 == 0 {
            let scene = env.scene(&observation).unwrap();
            let index = |name: &str| {
                scene
                    .bodies
                    .iter()
                    .position(|b| b.name == name)
                    .unwrap_or_else(|| panic!("no body `{name}`"))
            };
            let picture = env.picture(240, 240).unwrap();
            let (cup, fingers) = (
                picture.pixels_of(index("cup")),
                picture.pixels_of(index("robot/fingers")),
            );
            assert!(!cup.is_empty() && !fingers.is_empty(), "step {step}");
            // The fingers touch the cup: no gap between hand and cup.
            let touching = cup.iter().any(|&(x, y)| {
                fingers
                    .iter()
                    .any(|&(u, v)| x.abs_diff(u) <= 1 && y.abs_diff(v) <= 1)
            });
            assert!(touching, "step {step}: the cup floats apart from the hand");
            // The pot is in frame, below the cup on screen.
            let lowest = |pixels: &[(u32, u32)]| pixels.iter().map(|p| p.1).max().unwrap();
            let pot = picture.pixels_of(index("pot"));
            assert!(lowest(&pot) > lowest(&cup), "step {step}");
            // Shading: the pot's pixels are not all one colour.
            let frame = env.render(240, 240).unwrap();
            let shades: std::collections::BTreeSet<_> = pot
                .iter()
                .map(|&(x, y)| {
                    let i = (y as usize * 240 + x as usize) * 3;
                    [frame[i], frame[i + 1], frame[i + 2]]
                })
                .collect();
            assert!(shades.len() > 5, "step {step}: {} shades", shades.len());
        }
        let action = env.expert_action().unwrap();
        observation = env.step(&action).unwrap().observation;
    }
}

/// The picture draws the cup's trail behind the scene's bodies, and none once
/// `record_trail(false)` turned it off (as an engine does for a batch).
#[test]
fn the_picture_draws_the_trail_unless_it_is_off() {
    let trail_pixels = |recording: bool| {
        let mut env = pouring::make().unwrap();
        env.record_trail(recording);
        let (observation, _) = env.reset(Some(0), &ResetOptions::default()).unwrap();
        let bodies = env.scene(&observation).unwrap().bodies.len();
        for _ in 0..300 {
            env.step(&env.expert_action().unwrap()).unwrap();
        }
        // The trail is the body after the scene's.
        env.picture(480, 480).unwrap().pixels_of(bodies).len()
    };
    let drawn = trail_pixels(true);
    assert!(drawn > 20, "{drawn} pixels");
    assert_eq!(trail_pixels(false), 0);
}

#[test]
fn the_scene_of_an_observation_needs_no_reset_and_refuses_bad_observations() {
    let mut env = pouring::make().unwrap();
    let (observation, _) = env.reset(Some(3), &ResetOptions::default()).unwrap();
    let fresh = pouring::make().unwrap();
    assert_eq!(
        fresh.scene(&observation).unwrap(),
        env.scene(&observation).unwrap()
    );
    assert!(matches!(
        fresh.scene(&observation[1..]),
        Err(EnvError::WrongDimension { .. })
    ));
    let mut broken = observation.clone();
    broken[2] = f64::NAN;
    assert!(matches!(
        fresh.scene(&broken),
        Err(EnvError::NotFinite { .. })
    ));
    // The pot stands where the context puts it.
    let mut moved = observation.clone();
    let n = moved.len();
    moved[n - 6] += 0.05;
    let pot_x = |observation: &[f64]| match fresh.scene(observation).unwrap().body("pot") {
        Some(Body {
            shape: Shape::Cylinder { pose, .. },
            ..
        }) => pose.translation.x,
        other => panic!("{other:?}"),
    };
    assert!((pot_x(&moved) - pot_x(&observation) - 0.05).abs() < 1e-12);
}

fn options(pairs: &[(&str, f64)]) -> ResetOptions {
    ResetOptions {
        extra: pairs.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
        ..ResetOptions::default()
    }
}

#[test]
fn start_spread_sets_how_far_starts_lie_from_home() {
    let mut env = pouring::make().unwrap();
    let spread_of = |env: &mut ArmEnv<Pouring>, spread: f64| {
        (0..20)
            .map(|seed| {
                let (observation, _) = env
                    .reset(Some(seed), &options(&[("start_spread", spread)]))
                    .unwrap();
                observation[..7]
                    .iter()
                    .zip(ciflow_engine::robot::PANDA_HOME)
                    .map(|(q, home)| (q - home).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max)
    };
    assert_eq!(spread_of(&mut env, 0.0), 0.0);
    let wide = spread_of(&mut env, 0.25);
    assert!(wide > 0.2 && wide <= 0.25, "{wide}");
    for bad in [-0.1, 0.31, f64::NAN] {
        let error = env
            .reset(Some(0), &options(&[("start_spread", bad)]))
            .unwrap_err();
        assert!(
            matches!(error, EnvError::InvalidOption { .. }),
            "{bad}: {error}"
        );
    }
}

#[test]
fn push_force_pushes_each_episode_once_reproducibly() {
    let mut env = pouring::make().unwrap();
    let pushed = options(&[("push_force", 60.0)]);
    let spout_x = |episode: &ciflow_envs::dataset::Episode| episode.infos["spout_x"].clone();
    let calm = expert_episode(&mut env, Some(3), &ResetOptions::default()).unwrap();
    let first = expert_episode(&mut env, Some(3), &pushed).unwrap();
    let again = expert_episode(&mut env, Some(3), &pushed).unwrap();
    assert_eq!(
        spout_x(&first),
        spout_x(&again),
        "the push depends on the seed only"
    );
    // Same start and context, so the runs agree until the push and differ after it.
    assert_eq!(first.observations[0], calm.observations[0]);
    let differ = first
        .observations
        .iter()
        .zip(&calm.observations)
        .position(|(a, b)| a != b)
        .expect("the push changed the motion");
    let time = differ as f64 * 0.01;
    assert!((0.3..=3.2).contains(&time), "first change at {time} s");
    for bad in [-1.0, f64::INFINITY] {
        let error = env
            .reset(Some(0), &options(&[("push_force", bad)]))
            .unwrap_err();
        assert!(
            matches!(error, EnvError::InvalidOption { .. }),
            "{bad}: {error}"
        );
    }
}
