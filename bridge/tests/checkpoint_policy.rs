//! A checkpoint served as a policy: concurrent callers get the in-process actor's
//! actions, and publications that do not fit are refused with typed errors.

mod common;

use std::sync::Arc;

use ciflow_bridge::protocol::{ByteBuf, CheckpointMsg, PROTOCOL_VERSION};
use ciflow_bridge::{CheckpointPolicy, Kwargs, Policy, PolicyLoadError, TaskFactory};
use ciflow_engine::flow::FlowError;
use ciflow_engine::flow::checkpoint::{CONFIG_FILE, WEIGHTS_FILE};
use ciflow_envs::actor::{Actor, DEFAULT_VELOCITY_GAIN, Model, OWN_DATA_TASK};
use ciflow_envs::tasks::obstacle_avoidance;
use common::{one_obstacle, write_checkpoint};

#[test]
fn concurrent_callers_get_the_actors_actions() {
    let dir = write_checkpoint("policy-threads");
    let tasks = TaskFactory::registry();
    let policy = Arc::new(CheckpointPolicy::load(None, &dir, &tasks, &one_obstacle()).unwrap());
    let info = policy.info();
    assert_eq!(
        info.name, "obstacle-avoidance",
        "the name defaults to the task"
    );
    assert_eq!((info.observation_dim, info.action_dim), (8, 2));

    let model = Model::load(&dir, None).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let env = obstacle_avoidance::make(1).unwrap();
    let mut actor =
        Actor::new(&model, ciflow_envs::Env::spec(&env), DEFAULT_VELOCITY_GAIN).unwrap();
    let observations: Vec<[f64; 8]> = (0..64)
        .map(|i| {
            let s = i as f64 / 64.0;
            [
                -0.9 + s,
                0.5 - s,
                0.2 * s,
                -0.1,
                0.0,
                -0.6,
                0.8,
                0.2 - s * 0.4,
            ]
        })
        .collect();
    let expected: Vec<[f64; 2]> = observations
        .iter()
        .map(|o| {
            let mut a = [0.0; 2];
            actor.act(o, &mut a).unwrap();
            a
        })
        .collect();
    std::thread::scope(|scope| {
        for _ in 0..4 {
            let (policy, observations, expected) = (&policy, &observations, &expected);
            scope.spawn(move || {
                for _ in 0..20 {
                    for (o, e) in observations.iter().zip(expected) {
                        assert_eq!(policy.act(o).unwrap(), e.to_vec());
                    }
                }
            });
        }
    });
    assert!(
        policy.act(&[0.0; 7]).is_err(),
        "wrong dimension is an error"
    );
}

#[test]
fn publications_that_do_not_fit_are_refused() {
    let dir = write_checkpoint("policy-refused");
    let config = std::fs::read_to_string(dir.join(CONFIG_FILE)).unwrap();
    let weights = std::fs::read(dir.join(WEIGHTS_FILE)).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let tasks = TaskFactory::registry();
    let message = CheckpointMsg {
        v: PROTOCOL_VERSION,
        name: "avoid".into(),
        task: "obstacle-avoidance".into(),
        config,
        weights: ByteBuf::from(weights),
        epoch: 3,
        validation_nll: -1.0,
        kwargs: one_obstacle(),
        signature: None,
    };
    let loaded = CheckpointPolicy::from_message("avoid", &message, &tasks, &Kwargs::new()).unwrap();
    assert_eq!(loaded.info().epoch, Some(3));
    assert_eq!(loaded.task_kwargs(), one_obstacle());

    let refused = |message: &CheckpointMsg, kwargs: &Kwargs| {
        CheckpointPolicy::from_message("avoid", message, &tasks, kwargs)
            .err()
            .expect("refused")
    };
    assert!(matches!(
        CheckpointPolicy::from_message("other", &message, &tasks, &Kwargs::new()),
        Err(PolicyLoadError::NameMismatch { .. })
    ));
    // The task may be named by its Gymnasium id, as `PolicyInfo.task` names it.
    let by_id = CheckpointMsg {
        task: obstacle_avoidance::ID.into(),
        ..message.clone()
    };
    assert!(CheckpointPolicy::from_message("avoid", &by_id, &tasks, &Kwargs::new()).is_ok());
    let claims_pouring = CheckpointMsg {
        task: "pouring".into(),
        ..message.clone()
    };
    assert!(matches!(
        refused(&claims_pouring, &Kwargs::new()),
        PolicyLoadError::TaskMismatch { .. }
    ));
    // Three obstacles (the task's default) give an 8-D context: the shapes do not fit.
    let default_task = CheckpointMsg {
        kwargs: Kwargs::new(),
        ..message.clone()
    };
    assert!(matches!(
        refused(&default_task, &Kwargs::new()),
        PolicyLoadError::Shape(_)
    ));
    // ...unless the replaced policy's arguments apply.
    assert!(
        CheckpointPolicy::from_message("avoid", &default_task, &tasks, &one_obstacle()).is_ok()
    );
    // On its own data it needs no task, with the same checks of name and task.
    let own = CheckpointPolicy::from_message_on_own_data("avoid", &default_task, &tasks).unwrap();
    let info = own.info();
    assert_eq!(
        (info.task.as_str(), info.observation_dim, info.epoch),
        (OWN_DATA_TASK, 8, Some(3))
    );
    assert!(matches!(
        CheckpointPolicy::from_message_on_own_data("other", &default_task, &tasks),
        Err(PolicyLoadError::NameMismatch { .. })
    ));
    assert!(matches!(
        CheckpointPolicy::from_message_on_own_data("avoid", &claims_pouring, &tasks),
        Err(PolicyLoadError::TaskMismatch { .. })
    ));
    let truncated = CheckpointMsg {
        weights: ByteBuf::from(message.weights[..100].to_vec()),
        ..message.clone()
    };
    assert!(matches!(
        refused(&truncated, &Kwargs::new()),
        PolicyLoadError::Checkpoint(FlowError::SafeTensors(_))
    ));
    let only_cycles: Vec<TaskFactory> = tasks
        .into_iter()
        .filter(|t| t.name == "limit-cycle")
        .collect();
    assert!(matches!(
        CheckpointPolicy::from_message("avoid", &message, &only_cycles, &Kwargs::new()),
        Err(PolicyLoadError::UnknownTask { .. })
    ));
    assert!(matches!(
        CheckpointPolicy::load(None, &dir, &only_cycles, &Kwargs::new()),
        Err(PolicyLoadError::Checkpoint(FlowError::Io { .. }))
    ));
}
