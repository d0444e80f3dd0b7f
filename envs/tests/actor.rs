//! A checkpoint acting in an environment: the actor's action is the flow's desired
//! acceleration for `[q, q̇, c]` (the baseline's, through the same law) clipped to
//! the action space, shapes are checked, and the saturated closed loop reaches the
//! attractor, the target in the context.

mod common;

use ciflow_engine::flow::sampled_control::limit_overshoot;
use ciflow_engine::flow::{
    BaselineConfig, BehaviourCloning, CouplingKind, FlowConfig, Goal, JointRange, LatentKind,
    Policy, Weights,
};
use ciflow_engine::robot::panda_limits;
use ciflow_envs::actor::{Actor, ActorError, DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::tasks::{limit_cycle, obstacle_avoidance, pouring};
use ciflow_envs::{Env, ResetOptions};
use common::{obstacle_flow, obstacle_flow_checkpoint};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn action_is_the_clipped_flow_acceleration() {
    let model = Model::from(obstacle_flow(1));
    let env = obstacle_avoidance::make(1).unwrap();
    let mut actor = Actor::new(&model, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    let observation = [-0.8, 0.3, 0.1, -0.2, 0.0, 0.1, 0.7, -0.2];
    let mut action = [0.0; 2];
    actor.act(&observation, &mut action).unwrap();

    let Model::Flow(policy) = &model else {
        unreachable!()
    };
    let (mut expected, mut velocity) = ([0.0; 2], [0.0; 2]);
    policy
        .acceleration(
            &observation[..2],
            &observation[2..4],
            &observation[4..],
            DEFAULT_VELOCITY_GAIN,
            &mut policy.workspace(),
            &mut expected,
            &mut velocity,
        )
        .unwrap();
    let bound = &env.spec().action_space;
    for i in 0..2 {
        assert_eq!(action[i], expected[i].clamp(bound.low[i], bound.high[i]));
    }
    assert!(
        action.iter().any(|a| a.abs() < 20.0),
        "some action is inside the bounds"
    );
    assert_eq!(actor.desired_velocity(), &velocity);
}

/// The baseline acts through the flow's law, `q̈ = (∂v/∂q) q̇ + K_v (v − q̇)` on its
/// finite-difference velocity `v = (ŷ_{k+1} − q) / dt`, with the same overshoot guard.
/// The actor takes `(∂v/∂q) q̇` as a central difference along `q̇`; here the whole
/// Jacobian is built column by column and multiplied out.
#[test]
fn baseline_acts_through_the_flows_law_on_its_finite_difference_velocity() {
    let (flow, _) = obstacle_flow_checkpoint(5);
    let config = BaselineConfig {
        task: flow.task,
        task_kwargs: Default::default(),
        state_dim: 2,
        context_dim: 4,
        dt: flow.dt,
        hidden: vec![8],
        goal: Goal::ContextIndices {
            indices: vec![2, 3],
        },
        normalisation: flow.normalisation,
        bounds: flow.bounds,
    };
    // Weights large enough that the field bends: the feed-forward term matters.
    let weights = Weights::random(
        &config.parameter_shapes(),
        1.0,
        &mut ChaCha8Rng::seed_from_u64(5),
    );
    let baseline = BehaviourCloning::new(&config, weights).unwrap();
    let model = Model::from(baseline.clone());
    let env = obstacle_avoidance::make(1).unwrap();
    let mut actor = Actor::new(&model, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    let (q, context) = ([-0.8, 0.3], [0.0, 0.1, 0.7, -0.2]);
    let mut ws = baseline.workspace();
    let mut velocity_at = |q: &[f64]| {
        let mut next = [0.0; 2];
        baseline.mean_next(q, &context, &mut ws, &mut next).unwrap();
        [0, 1].map(|i| (next[i] - q[i]) / config.dt)
    };
    let velocity = velocity_at(&q);
    // Moving nearly as the field asks: the feed-forward term is most of the command.
    let qd = [velocity[0] + 0.002, velocity[1] - 0.004];
    let observation: Vec<f64> = [&q[..], &qd, &context].concat();
    let mut action = [0.0; 2];
    actor.act(&observation, &mut action).unwrap();
    assert_eq!(actor.desired_velocity(), &velocity);
    let step = 1e-6;
    let mut feed_forward = [0.0; 2];
    for j in 0..2 {
        let (mut plus, mut minus) = ([q[0], q[1]], [q[0], q[1]]);
        plus[j] += step;
        minus[j] -= step;
        let (v_plus, v_minus) = (velocity_at(&plus), velocity_at(&minus));
        for i in 0..2 {
            feed_forward[i] += (v_plus[i] - v_minus[i]) / (2.0 * step) * qd[j];
        }
    }
    let mut expected =
        [0, 1].map(|i| feed_forward[i] + DEFAULT_VELOCITY_GAIN * (velocity[i] - qd[i]));
    limit_overshoot(
        &qd,
        &velocity,
        DEFAULT_VELOCITY_GAIN,
        env.spec().control_dt,
        &mut expected,
    );
    let bound = &env.spec().action_space;
    for i in 0..2 {
        let expected = expected[i].clamp(bound.low[i], bound.high[i]);
        assert!(
            (action[i] - expected).abs() <= 1e-6 * (1.0 + expected.abs()),
            "{action:?} against {expected}"
        );
    }
    let size = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!(
        size(&feed_forward) > 0.5 * size(&action),
        "the feed-forward term is too small to be told apart: {feed_forward:?} in {action:?}"
    );
}

#[test]
fn shapes_and_gain_are_checked() {
    let model = Model::from(obstacle_flow(2));
    let two_obstacles = obstacle_avoidance::make(2).unwrap();
    assert!(matches!(
        Actor::new(&model, two_obstacles.spec(), DEFAULT_VELOCITY_GAIN),
        Err(ActorError::Mismatch { .. })
    ));
    let cycle = limit_cycle::make().unwrap();
    assert!(Actor::new(&model, cycle.spec(), DEFAULT_VELOCITY_GAIN).is_err());
    let env = obstacle_avoidance::make(1).unwrap();
    assert!(matches!(
        Actor::new(&model, env.spec(), f64::NAN),
        Err(ActorError::VelocityGain(_))
    ));
    let mut actor = Actor::new(&model, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    let mut action = [0.0; 2];
    assert!(matches!(
        actor.act(&[0.0; 7], &mut action),
        Err(ActorError::ObservationDim {
            expected: 8,
            found: 7
        })
    ));
    assert!(matches!(
        actor.act(&[0.0; 8], &mut [0.0; 3]),
        Err(ActorError::ActionDim { .. })
    ));
    assert!(actor.act(&[f64::NAN; 8], &mut action).is_err());
}

#[test]
fn closed_loop_reaches_the_target_in_the_context() {
    let model = Model::from(obstacle_flow(3));
    let mut env = obstacle_avoidance::make(1).unwrap();
    // The obstacle sits far below the straight path from the start to the target.
    let target = [0.8, 0.1];
    let options = ResetOptions {
        context: Some(vec![0.0, -0.7, target[0], target[1]]),
        initial_position: Some(vec![-0.8, 0.2]),
        ..ResetOptions::default()
    };
    let (mut observation, _) = env.reset(Some(0), &options).unwrap();
    let mut actor = Actor::new(&model, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    let mut action = [0.0; 2];
    let mut closest = f64::INFINITY;
    for _ in 0..env.spec().max_episode_steps {
        actor.act(&observation, &mut action).unwrap();
        let step = env.step(&action).unwrap();
        observation = step.observation;
        closest = closest.min(step.info["distance_to_target"]);
        assert_eq!(
            step.info["collision"], 0.0,
            "the path must not reach the obstacle"
        );
        if step.terminated || step.truncated {
            break;
        }
    }
    assert!(closest < 0.02, "closest approach to the target {closest} m");
}

#[test]
fn a_checkpoint_in_memory_loads_like_its_directory() {
    use ciflow_engine::flow::checkpoint::{self, CONFIG_FILE, WEIGHTS_FILE};
    use ciflow_engine::flow::{CheckpointConfig, FlowError};

    let (config, weights) = obstacle_flow_checkpoint(4);
    let dir = std::env::temp_dir().join(format!("ciflow-actor-bytes-{}", std::process::id()));
    checkpoint::write(&dir, &CheckpointConfig::Flow(config.clone()), &weights).unwrap();
    let config_json = std::fs::read_to_string(dir.join(CONFIG_FILE)).unwrap();
    let bytes = std::fs::read(dir.join(WEIGHTS_FILE)).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();

    let from_bytes = Model::from_bytes(&config_json, &bytes, Some("obstacle-avoidance")).unwrap();
    let direct = Model::from(Policy::new(&config, weights).unwrap());
    let env = obstacle_avoidance::make(1).unwrap();
    let observation = [-0.8, 0.3, 0.1, -0.2, 0.0, 0.1, 0.7, -0.2];
    let (mut a, mut b) = ([0.0; 2], [0.0; 2]);
    // An actor shares its model's weights and outlives the model it was built from.
    let mut actor = Actor::new(&from_bytes, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    drop(from_bytes);
    actor.act(&observation, &mut a).unwrap();
    Actor::new(&direct, env.spec(), DEFAULT_VELOCITY_GAIN)
        .unwrap()
        .act(&observation, &mut b)
        .unwrap();
    assert_eq!(a, b);

    assert!(matches!(
        Model::from_bytes(&config_json, &bytes, Some("pouring")),
        Err(FlowError::TaskMismatch { .. })
    ));
    assert!(matches!(
        Model::from_bytes("{not json", &bytes, None),
        Err(FlowError::ConfigText(_))
    ));
    assert!(matches!(
        Model::from_bytes(&config_json, &bytes[..bytes.len() / 2], None),
        Err(FlowError::SafeTensors(_))
    ));
}

/// Under a joint range, an actor that drove a joint at its limit follows its own latent
/// state on the next observation of the episode (`EndStopHold`); `reset` starts the next
/// episode memoryless, as a fresh actor does.
#[test]
fn an_actor_keeps_its_end_stop_hold_until_reset() {
    let mut config = FlowConfig::new(
        "pouring",
        7,
        6,
        LatentKind::GoTo,
        CouplingKind::AFFINE,
        4,
        vec![16, 16],
    );
    let limits = panda_limits();
    config.joint_range = Some(JointRange::from_limits(&limits));
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.1,
        &mut ChaCha8Rng::seed_from_u64(7),
    );
    let policy = Policy::new(&config, weights).unwrap();
    let env = pouring::make().unwrap();
    let context: Vec<f64> = {
        let space = &env.spec().context_space;
        space
            .low
            .iter()
            .zip(&space.high)
            .map(|(a, b)| 0.5 * (a + b))
            .collect()
    };
    let middle: Vec<f64> = (0..7)
        .map(|i| 0.5 * (limits.q_min[i] + limits.q_max[i]))
        .collect();
    let observation = |q: &[f64]| [q, &[0.0; 7], &context].concat();
    // A joint 1 mrad off the limit the field there drives it at, the others anywhere.
    let mut ws = policy.workspace();
    let mut velocity = [0.0; 7];
    let mut r = ChaCha8Rng::seed_from_u64(8);
    let at_a_limit = (0..1000)
        .find_map(|k| {
            let (i, upper) = (k % 7, k % 2 == 0);
            let mut q: Vec<f64> = (0..7)
                .map(|j| r.random_range(limits.q_min[j]..limits.q_max[j]))
                .collect();
            q[i] = match upper {
                true => limits.q_max[i] - 1e-3,
                false => limits.q_min[i] + 1e-3,
            };
            policy
                .velocity(&q, &context, &mut ws, &mut velocity)
                .unwrap();
            ((velocity[i] > 0.0) == upper).then_some(q)
        })
        .expect("the field drives some joint at one of its limits");

    let model = Model::from(policy);
    let new_actor = || Actor::new(&model, env.spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    let act = |actor: &mut Actor, q: &[f64]| {
        let mut action = [0.0; 7];
        actor.act(&observation(q), &mut action).unwrap();
        action
    };
    let fresh = act(&mut new_actor(), &middle);
    let mut actor = new_actor();
    act(&mut actor, &at_a_limit);
    let held = act(&mut actor, &middle);
    assert_ne!(
        held, fresh,
        "the hold did not carry over to the next observation"
    );
    actor.reset();
    assert_eq!(act(&mut actor, &middle), fresh);
}
