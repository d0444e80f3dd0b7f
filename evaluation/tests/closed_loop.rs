//! Closed-loop evaluation: the episodes `evaluate` reports are those a hand-written loop
//! of the actor produces, pushes displace the state by the requested distance through
//! the real dynamics, context switches hold, the log-likelihood is the per-transition
//! mean of `Policy::log_transition` with the earlier step's context, the field data
//! are the policy's velocity, rollouts and latent grid, and an episode's second half is
//! the mean speed and distance of its replayed states.

// The envs tests' obstacle-avoidance flow, shared rather than copied.
#[path = "../../envs/tests/common/mod.rs"]
mod common;

use ciflow_engine::sim::{Perturbation, PerturbationKind};
use ciflow_envs::actor::{Actor, DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::dataset::Episode;
use ciflow_envs::expert::limit_cycle::SPEED;
use ciflow_envs::tasks::limit_cycle;
use ciflow_envs::tasks::obstacle_avoidance::{self, SUCCESS_DISTANCE};
use ciflow_envs::{Env, ResetOptions};
use ciflow_evaluation::field::{FieldConfig, field};
use ciflow_evaluation::likelihood::log_likelihood;
use ciflow_evaluation::{
    Acting, ContextSwitch, Disturbance, EvaluationConfig, EvaluationError, PushConfig, evaluate,
    run_episodes, summarize,
};
use common::obstacle_flow;

fn config(episodes: usize, disturbance: Disturbance) -> EvaluationConfig {
    EvaluationConfig {
        episodes,
        seed: 40,
        velocity_gain: DEFAULT_VELOCITY_GAIN,
        reset_extra: Default::default(),
        disturbance,
        trajectories: 2,
    }
}

/// A 0.1 s push on the mass at 0.5 s, sized from 2 N up to `displacement` (m).
fn mass_push(displacement: f64) -> PushConfig {
    PushConfig {
        start: 0.5,
        duration: 0.1,
        displacement,
        initial_force: 2.0,
        ..PushConfig::default()
    }
}

/// The perturbation of `push` with the `force` its sizing settled on.
fn applied(push: &PushConfig, force: [f64; 3]) -> Perturbation {
    Perturbation {
        kind: PerturbationKind::LinkWrench {
            link: push.link,
            force,
            torque: [0.0; 3],
        },
        start: push.start,
        duration: push.duration,
    }
}

/// Positions of one episode of `acting` from `reset(seed)`, under `perturbation`, and the
/// last step's info, stepped by hand.
fn replay(
    acting: Acting,
    seed: u64,
    perturbation: Option<Perturbation>,
) -> (Vec<[f64; 2]>, ciflow_envs::Info) {
    let mut env = obstacle_avoidance::make(1).unwrap();
    let mut actor = match acting {
        Acting::Model(model) => Some(Actor::new(model, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap()),
        Acting::Expert => None,
    };
    let (mut observation, _) = env.reset(Some(seed), &ResetOptions::default()).unwrap();
    if let Some(p) = perturbation {
        env.perturb(p).unwrap();
    }
    let mut positions = vec![[observation[0], observation[1]]];
    let mut action = [0.0; 2];
    loop {
        match &mut actor {
            Some(actor) => actor.act(&observation, &mut action).unwrap(),
            None => action.copy_from_slice(&env.expert_action().unwrap()),
        }
        let step = env.step(&action).unwrap();
        observation = step.observation;
        positions.push([observation[0], observation[1]]);
        if step.terminated || step.truncated {
            return (positions, step.info);
        }
    }
}

#[test]
fn episodes_and_rates_are_those_of_the_closed_loop() {
    let model = Model::from(obstacle_flow(1));
    let mut env = obstacle_avoidance::make(1).unwrap();
    let report = evaluate(
        &mut env,
        Acting::Model(&model),
        &config(8, Disturbance::None),
        |_| {},
    )
    .unwrap();
    assert_eq!(report.episodes, 8);
    assert_eq!(report.distance_key.as_deref(), Some("distance_to_target"));
    assert_eq!(report.spill_rate, None, "Obstacle-v0 reports no spills");
    let successes = report.results.iter().filter(|r| r.success).count();
    let collisions = report
        .results
        .iter()
        .filter(|r| r.collision == Some(true))
        .count();
    assert_eq!(report.success_rate, successes as f64 / 8.0);
    assert_eq!(report.collision_rate, Some(collisions as f64 / 8.0));
    // A stable flow onto the target reaches it unless an obstacle is in the way.
    assert!(successes >= 5, "{successes} of 8 reached the target");
    for (i, result) in report.results.iter().enumerate() {
        let (positions, info) = replay(Acting::Model(&model), 40 + i as u64, None);
        assert_eq!(result.seed, 40 + i as u64);
        assert_eq!(result.start, positions[0], "the position at reset");
        assert_eq!(result.steps + 1, positions.len());
        assert_eq!(result.success, info["is_success"] == 1.0);
        assert_eq!(result.final_distance, Some(info["distance_to_target"]));
        if result.success {
            assert!(result.final_distance.unwrap() < SUCCESS_DISTANCE);
            assert_eq!(result.collision, Some(false));
        }
    }
    assert_eq!(report.trajectories.len(), 2);
    let trace = &report.trajectories[1];
    assert_eq!(trace.q.len(), trace.command.len() + 1);
    assert_eq!(
        trace.point, trace.q,
        "planar tasks track the position itself"
    );
    let example = report.example.as_ref().unwrap();
    assert_eq!(&example.trace, &report.trajectories[0]);
}

/// The second half of a limit-cycle episode (the expert's) is the mean speed `‖q̇‖` and
/// outline distance of the states a hand-written loop steps through from state `⌊n/2⌋`
/// on: the expert circulates at its speed, on the outline.
#[test]
fn the_second_half_is_the_mean_of_the_replayed_states() {
    let mut env = limit_cycle::make().unwrap();
    let report = evaluate(
        &mut env,
        Acting::Expert,
        &config(3, Disturbance::None),
        |_| {},
    )
    .unwrap();
    for (i, result) in report.results.iter().enumerate() {
        let (mut observation, info) = env
            .reset(Some(40 + i as u64), &ResetOptions::default())
            .unwrap();
        let mut speeds = vec![observation[2].hypot(observation[3])];
        let mut distances = vec![info["outline_error"]];
        loop {
            let step = env.step(&env.expert_action().unwrap()).unwrap();
            observation = step.observation;
            speeds.push(observation[2].hypot(observation[3]));
            distances.push(step.info["outline_error"]);
            if step.truncated {
                break;
            }
        }
        let half = speeds.len() / 2;
        let mean = |values: &[f64]| values.iter().sum::<f64>() / values.len() as f64;
        let second_half = result.second_half.as_ref().unwrap();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
        assert!(
            close(second_half.speed, mean(&speeds[half..])),
            "{second_half:?}"
        );
        assert!(close(
            second_half.distance.unwrap(),
            mean(&distances[half..])
        ));
        assert!(
            (second_half.speed - SPEED).abs() < 0.02 * SPEED,
            "{second_half:?}"
        );
        assert!(second_half.distance.unwrap() < 0.1 * limit_cycle::SUCCESS_DISTANCE);
    }
    let speeds = report.second_half_speed.as_ref().unwrap();
    assert_eq!(speeds.count, 3);
    assert!(report.second_half_distance.as_ref().unwrap().max < limit_cycle::SUCCESS_DISTANCE);
}

/// The expert, the reference of every experiment, runs through the same loop and
/// measures: its episodes are `expert_action` stepped by hand, pushes included.
#[test]
fn the_expert_is_evaluated_through_the_same_loop() {
    let mut env = obstacle_avoidance::make(1).unwrap();
    let push = mass_push(0.05);
    let free = evaluate(
        &mut env,
        Acting::Expert,
        &config(6, Disturbance::None),
        |_| {},
    )
    .unwrap();
    let pushed = evaluate(
        &mut env,
        Acting::Expert,
        &config(6, Disturbance::Push(push.clone())),
        |_| {},
    )
    .unwrap();
    assert_eq!(
        (free.model.as_str(), free.task.as_str()),
        ("expert", "obstacle-avoidance")
    );
    for (i, result) in free.results.iter().enumerate() {
        let (positions, info) = replay(Acting::Expert, 40 + i as u64, None);
        assert_eq!(result.steps + 1, positions.len());
        assert_eq!(result.success, info["is_success"] == 1.0);
        assert_eq!(result.final_distance, Some(info["distance_to_target"]));
    }
    let traced: Vec<[f64; 2]> = free.trajectories[0]
        .q
        .iter()
        .map(|q| [q[0], q[1]])
        .collect();
    assert_eq!(traced, replay(Acting::Expert, 40, None).0);
    assert_eq!(free.success_rate, 1.0, "the expert reaches every target");
    let outcome = pushed.results[0].push.as_ref().unwrap();
    let force = applied(&push, outcome.force);
    let traced: Vec<[f64; 2]> = pushed.trajectories[0]
        .q
        .iter()
        .map(|q| [q[0], q[1]])
        .collect();
    assert_eq!(traced, replay(Acting::Expert, 40, Some(force)).0);
    assert!(outcome.displacement >= 0.05);
}

#[test]
fn a_push_displaces_the_state_by_the_requested_distance() {
    let model = Model::from(obstacle_flow(2));
    let mut env = obstacle_avoidance::make(1).unwrap();
    let push = mass_push(0.08);
    let report = evaluate(
        &mut env,
        Acting::Model(&model),
        &config(3, Disturbance::Push(push.clone())),
        |_| {},
    )
    .unwrap();
    let summary = report.push.as_ref().unwrap();
    assert_eq!(summary.displaced_fraction, 1.0);
    assert!(summary.displacement.min >= 0.08);
    for result in &report.results {
        let outcome = result.push.as_ref().unwrap();
        assert!(
            outcome.attempts > 1,
            "2 N for 0.1 s cannot move 1 kg by 8 cm"
        );
        // Replayed by hand with the force found: the same displacement at equal times.
        let (free, _) = replay(Acting::Model(&model), result.seed, None);
        let pushed = applied(&push, outcome.force);
        let (moved, _) = replay(Acting::Model(&model), result.seed, Some(pushed));
        let first = (push.start / 0.01).round() as usize;
        let displacement = (first..moved.len())
            .map(|k| {
                let r = free[k.min(free.len() - 1)];
                ((moved[k][0] - r[0]).powi(2) + (moved[k][1] - r[1]).powi(2)).sqrt()
            })
            .fold(0.0, f64::max);
        assert!((displacement - outcome.displacement).abs() < 1e-9);
        assert!(displacement >= 0.08);
    }
    let example = report.example.as_ref().unwrap();
    assert!(
        example.reference.is_some(),
        "pushes keep the unpushed reference"
    );
}

#[test]
fn a_context_switch_moves_only_the_target_and_holds() {
    let model = Model::from(obstacle_flow(3));
    let mut env = obstacle_avoidance::make(1).unwrap();
    let switch = ContextSwitch {
        time: 0.5,
        tail: Some(2),
    };
    let report = evaluate(
        &mut env,
        Acting::Model(&model),
        &config(4, Disturbance::Context(switch)),
        |_| {},
    )
    .unwrap();
    for (result, trace) in report.results.iter().zip(&report.trajectories) {
        let new = result.switched_context.as_ref().unwrap();
        assert_eq!(new[..2], result.context[..2], "the obstacle stays");
        assert_ne!(new[2..], result.context[2..], "the target moves");
        let switched_at = trace
            .time
            .iter()
            .position(|t| *t >= 0.5 + 0.01 - 1e-9)
            .unwrap();
        assert!(
            trace.context[..switched_at]
                .iter()
                .all(|c| *c == result.context)
        );
        assert!(trace.context[switched_at..].iter().all(|c| c == new));
        if result.success {
            let last = trace.q.last().unwrap();
            let to_new = ((last[0] - new[2]).powi(2) + (last[1] - new[3]).powi(2)).sqrt();
            assert!(to_new < SUCCESS_DISTANCE, "success is at the new target");
        }
    }
}

/// The printed summary names the disturbance in words, not as a Rust value.
#[test]
fn disturbances_read_as_phrases() {
    let push = Disturbance::Push(PushConfig {
        link: 1,
        ..PushConfig::default()
    });
    assert_eq!(
        push.to_string(),
        "pushed on link 1 at 1 s for 0.2 s (to a displacement >= 0.05 m)"
    );
    let switch = |tail| Disturbance::Context(ContextSwitch { time: 1.5, tail }).to_string();
    assert_eq!(
        switch(Some(2)),
        "the last 2 context entries changed at 1.5 s"
    );
    assert_eq!(switch(None), "the context changed at 1.5 s");
    assert_eq!(Disturbance::None.to_string(), "undisturbed");
}

#[test]
fn bad_settings_are_typed_errors() {
    let model = Model::from(obstacle_flow(4));
    let mut env = obstacle_avoidance::make(1).unwrap();
    let none = evaluate(
        &mut env,
        Acting::Model(&model),
        &config(0, Disturbance::None),
        |_| {},
    );
    assert!(matches!(none, Err(EvaluationError::InvalidConfig(_))));
    let push = PushConfig {
        displacement: f64::NAN,
        ..PushConfig::default()
    };
    let bad = evaluate(
        &mut env,
        Acting::Model(&model),
        &config(1, Disturbance::Push(push)),
        |_| {},
    );
    assert!(matches!(bad, Err(EvaluationError::InvalidConfig(_))));
    let mut two = obstacle_avoidance::make(2).unwrap();
    let mismatch = evaluate(
        &mut two,
        Acting::Model(&model),
        &config(1, Disturbance::None),
        |_| {},
    );
    assert!(matches!(mismatch, Err(EvaluationError::Actor(_))));
}

#[test]
fn log_likelihood_is_the_mean_transition_density_with_the_earlier_context() {
    let policy = obstacle_flow(5);
    // Two episodes whose context changes every step, so the wrong one would show.
    let episodes: Vec<Episode> = (0..2)
        .map(|e| Episode {
            observations: (0..6)
                .map(|t| vec![0.1 * t as f64 - e as f64, 0.05 * t as f64, 0.0, 0.0])
                .collect(),
            contexts: (0..6)
                .map(|t| vec![0.0, 0.1 * t as f64, 0.7 + 0.01 * t as f64, -0.2])
                .collect(),
            ..Episode::default()
        })
        .collect();
    let ll = log_likelihood(&policy, &episodes).unwrap();
    let mut ws = policy.workspace();
    let (mut sum, mut later_context) = (0.0, 0.0);
    for e in &episodes {
        for t in 1..6 {
            let (prev, next) = (&e.observations[t - 1][..2], &e.observations[t][..2]);
            sum += policy
                .log_transition(prev, next, &e.contexts[t - 1], &mut ws)
                .unwrap();
            later_context += policy
                .log_transition(prev, next, &e.contexts[t], &mut ws)
                .unwrap();
        }
    }
    assert_eq!(ll.transitions, 10);
    assert!((ll.per_transition - sum / 10.0).abs() < 1e-9 * sum.abs().max(1.0));
    assert!((ll.per_transition - later_context / 10.0).abs() > 1e-6);
    let empty = log_likelihood(&policy, &[]);
    assert!(matches!(empty, Err(EvaluationError::InvalidConfig(_))));
}

#[test]
fn field_data_are_the_policy_velocity_rollouts_and_latent_grid() {
    let policy = obstacle_flow(6);
    let context = vec![0.0, 0.4, 0.7, -0.2];
    let config = FieldConfig {
        contexts: vec![context.clone()],
        window: Some([-1.0, 1.0, -0.8, 0.8]),
        resolution: 5,
        starts: Some(vec![[-0.9, 0.5]]),
        rollout_steps: 2000,
        latent_lines: 3,
    };
    let report = field(&policy, &config, &[]).unwrap();
    let f = &report.fields[0];
    let mut ws = policy.workspace();
    let mut v = [0.0; 2];
    policy
        .velocity(&[f.x[1], f.y[3]], &context, &mut ws, &mut v)
        .unwrap();
    assert_eq!([f.velocity_x[3][1], f.velocity_y[3][1]], v);
    let end = f.rollouts[0].last().unwrap();
    assert!(((end[0] - 0.7).powi(2) + (end[1] + 0.2).powi(2)).sqrt() < 1e-3);
    // The first lines hold z₀ fixed: mapped back, their points share z₀.
    let mut z = [0.0; 2];
    let line = &f.latent_grid[1];
    policy
        .latent_state(&line[0], &context, &mut ws, &mut z)
        .unwrap();
    let z0 = z[0];
    policy
        .latent_state(&line[60], &context, &mut ws, &mut z)
        .unwrap();
    assert!((z[0] - z0).abs() < 1e-8, "{} vs {z0}", z[0]);
    assert_eq!(f.latent_grid.len(), 6);
}

#[test]
fn batches_run_apart_add_up_to_the_report_of_one_run() {
    // Episode `i` depends only on its seed: batches in any order, on fresh environments,
    // summarise to the report of one run; a batch missing or repeated is refused.
    let model = Model::from(obstacle_flow(1));
    let acting = Acting::Model(&model);
    let config = config(5, Disturbance::Push(mass_push(0.03)));
    let mut env = obstacle_avoidance::make(1).unwrap();
    let whole = evaluate(&mut env, acting, &config, |_| {}).unwrap();
    let batch = |episodes: std::ops::Range<usize>| {
        let mut env = obstacle_avoidance::make(1).unwrap();
        run_episodes(&mut env, acting, &config, episodes, |_| {}).unwrap()
    };
    let (first, middle, last) = (batch(0..2), batch(2..3), batch(3..5));
    assert_eq!(
        first.trajectories.len(),
        2,
        "traces of the first two episodes"
    );
    assert!(first.example.is_some() && last.example.is_none());
    let spec = env.spec().clone();
    let merged = summarize(
        &spec,
        acting,
        &config,
        vec![last.clone(), first.clone(), middle.clone()],
    )
    .unwrap();
    assert_eq!(merged, whole);

    let mut appended = first.clone();
    appended.append(middle.clone());
    appended.append(last.clone());
    assert_eq!(
        summarize(&spec, acting, &config, vec![appended]).unwrap(),
        whole
    );

    for batches in [
        vec![first.clone(), last.clone()],
        vec![first.clone(), middle.clone(), middle.clone(), last.clone()],
        vec![first.clone(), middle.clone()],
    ] {
        let refused = summarize(&spec, acting, &config, batches);
        assert!(
            matches!(refused, Err(EvaluationError::InvalidConfig(_))),
            "{refused:?}"
        );
    }
    let beyond = run_episodes(&mut env, acting, &config, 4..6, |_| {});
    assert!(matches!(beyond, Err(EvaluationError::InvalidConfig(_))));
}
