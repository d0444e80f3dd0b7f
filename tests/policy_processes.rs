//! Trained policies served by `ciflow serve --policy` in its own process: `act` answers
//! what the in-process actor computes, a published checkpoint replaces the policy without
//! a restart (bad publications are ignored), and a policy-driven session recovers from a
//! push while client steps are refused as `busy`.

mod common;
#[path = "../envs/tests/common/mod.rs"]
mod envs_common;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use ciflow_bridge::protocol::{
    ByteBuf, CheckpointMsg, ErrorCode, PROTOCOL_VERSION, PerturbationKindMsg, PerturbationMsg,
    Telemetry, encode, keys,
};
use ciflow_bridge::zenoh::Wait;
use ciflow_bridge::{
    CheckpointPublisher, CheckpointSigner, Client, NetworkOptions, RemoteEnv, Role,
};
use ciflow_engine::flow::checkpoint::{self, CONFIG_FILE, WEIGHTS_FILE};
use ciflow_engine::flow::{CheckpointConfig, CouplingKind, FlowConfig, LatentKind, Weights};
use ciflow_envs::ResetOptions;
use ciflow_envs::actor::{Actor, DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::tasks::obstacle_avoidance;
use common::{Scratch, ciflow, code, connect, endpoint, line_with, refused, serve, spawn_ciflow};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const OBSTACLE: &str = "ciflow/Obstacle-v0";

/// Writes [`envs_common::obstacle_flow_checkpoint`]`(seed)` (the envs tests' random flow
/// for Obstacle-v0 with one obstacle) as a checkpoint directory.
fn write_flow(dir: &Path, seed: u64) {
    let (config, weights) = envs_common::obstacle_flow_checkpoint(seed);
    checkpoint::write(dir, &CheckpointConfig::Flow(config), &weights).unwrap();
}

/// Actions of the checkpoint in `dir` for `observations`, computed in this process.
fn local_actions(dir: &Path, observations: &[f64]) -> Vec<f64> {
    let model = Model::load(dir, None).unwrap();
    let env = obstacle_avoidance::make(1).unwrap();
    let mut actor =
        Actor::new(&model, ciflow_envs::Env::spec(&env), DEFAULT_VELOCITY_GAIN).unwrap();
    let mut actions = vec![0.0; observations.len() / 8 * 2];
    for (o, a) in observations.chunks(8).zip(actions.chunks_mut(2)) {
        actor.act(o, a).unwrap();
    }
    actions
}

const OBSERVATIONS: [f64; 24] = [
    -0.8, 0.3, 0.1, -0.2, 0.0, 0.1, 0.7, -0.2, //
    -0.5, -0.4, 0.0, 0.0, 0.2, 0.3, 0.9, 0.4, //
    0.6, 0.1, -0.3, 0.2, -0.3, -0.5, 0.8, 0.0,
];

#[test]
fn served_policy_acts_like_the_in_process_actor_and_bad_checkpoints_are_refused() {
    let scratch = Scratch::new("policy-act");
    let dir = scratch.join("a");
    write_flow(&dir, 1);
    let dir_arg = format!("avoid={}", dir.display());
    let _server = serve(
        27531,
        "policy-act",
        &["--policy", &dir_arg, "--policy-kwarg", "obstacles=1"],
    );
    let client = connect(27531);
    let info = client.engine_info("policy-act").unwrap();
    let listed = info
        .policies
        .iter()
        .find(|p| p.name == "avoid")
        .expect("the tasks reply lists the policy");
    assert_eq!(
        (
            listed.task.as_str(),
            listed.observation_dim,
            listed.action_dim
        ),
        (OBSTACLE, 8, 2)
    );

    let remote = client.act("policy-act", "avoid", &OBSERVATIONS).unwrap();
    assert_eq!(remote, local_actions(&dir, &OBSERVATIONS));
    assert!(
        remote.iter().any(|a| a.abs() > 1e-3),
        "actions are not all zero"
    );

    assert_eq!(
        code(
            client
                .act("policy-act", "avoid", &OBSERVATIONS[..7])
                .unwrap_err()
        ),
        ErrorCode::WrongDimension
    );
    assert_eq!(
        code(
            client
                .act("policy-act", "nobody", &OBSERVATIONS)
                .unwrap_err()
        ),
        ErrorCode::UnknownPolicy
    );

    // Start-up errors: a missing checkpoint, and one that does not fit the task's
    // default construction arguments (three obstacles).
    let endpoint = endpoint(27532);
    for (checkpoint, expected) in [
        (scratch.arg("missing"), CONFIG_FILE),
        (dir.display().to_string(), "cannot act"),
    ] {
        let args = ["serve", "--listen", &endpoint, "--policy", &checkpoint];
        let output = ciflow(&args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{args:?} must fail");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
    // Policy arguments without a policy to apply them to.
    refused(
        &[
            "serve",
            "--listen",
            &endpoint,
            "--policy-kwarg",
            "obstacles=1",
        ],
        "--policy",
    );
}

/// Actions of the checkpoint in `dir` on its own data's observations (8-D, as an
/// obstacle flow with one obstacle has them), computed in this process.
fn own_data_actions(dir: &Path, observations: &[f64]) -> Vec<f64> {
    let model = Model::load(dir, None).unwrap();
    let mut actor = Actor::new(&model, &model.own_data_spec(), DEFAULT_VELOCITY_GAIN).unwrap();
    let mut actions = vec![0.0; observations.len() / 8 * 2];
    for (o, a) in observations.chunks(8).zip(actions.chunks_mut(2)) {
        actor.act(o, a).unwrap();
    }
    actions
}

/// A checkpoint whose shapes fit no task's default (one obstacle, where the task's default
/// has three, standing in for one trained on data from elsewhere) is refused by `--policy`
/// with the way out named, and served by `--own-data-policy` on its own observations:
/// `act` answers what the in-process actor computes on them, unclipped.
#[test]
fn a_checkpoint_on_its_own_data_is_served_without_a_task() {
    let scratch = Scratch::new("policy-own-data");
    let dir = scratch.join("mine");
    write_flow(&dir, 2);
    let refusal = refused(
        &[
            "serve",
            "--listen",
            &endpoint(27537),
            "--policy",
            &dir.display().to_string(),
        ],
        "cannot act",
    );
    assert!(refusal.contains("--own-data-policy"), "{refusal}");

    let dir_arg = format!("mine={}", dir.display());
    let _server = serve(27536, "policy-own-data", &["--own-data-policy", &dir_arg]);
    let client = connect(27536);
    let info = client.engine_info("policy-own-data").unwrap();
    let listed = info.policies.iter().find(|p| p.name == "mine").unwrap();
    assert_eq!(
        (
            listed.task.as_str(),
            listed.observation_dim,
            listed.action_dim
        ),
        (ciflow_envs::actor::OWN_DATA_TASK, 8, 2)
    );
    // Far from the demonstrations, where the task would clip the action to its bounds.
    let far: Vec<f64> = OBSERVATIONS.iter().map(|o| 40.0 * o).collect();
    let remote = client.act("policy-own-data", "mine", &far).unwrap();
    assert_eq!(remote, own_data_actions(&dir, &far));
    let bound = obstacle_avoidance::make(1).unwrap();
    let high = &ciflow_envs::Env::spec(&bound).action_space.high;
    assert!(
        remote
            .iter()
            .zip(high.iter().cycle())
            .any(|(a, h)| a.abs() > *h),
        "unclipped: some action exceeds the task's bound {high:?}: {remote:?}"
    );
}

/// A policy served on its own data takes the next checkpoint trained on that data, which
/// fits no task (a publication `--policy` would refuse), and acts with it on its own
/// observations, unclipped; a checkpoint on data of other shapes is refused and said so.
#[test]
fn a_policy_on_its_own_data_is_replaced_by_the_next_checkpoint_on_that_data() {
    let scratch = Scratch::new("policy-own-hot");
    let (a, b, wider) = (scratch.join("a"), scratch.join("b"), scratch.join("wider"));
    write_flow(&a, 2);
    write_flow(&b, 3);
    // A 3-D state: 10 observations and 3 actions where the served policy has 8 and 2.
    let config = FlowConfig::new(
        "obstacle-avoidance",
        3,
        4,
        LatentKind::GoTo,
        CouplingKind::AFFINE,
        4,
        vec![16, 16],
    );
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.1,
        &mut ChaCha8Rng::seed_from_u64(4),
    );
    checkpoint::write(&wider, &CheckpointConfig::Flow(config), &weights).unwrap();

    let engine = "policy-own-hot";
    let a_arg = format!("mine={}", a.display());
    let (mut server, lines) = spawn_ciflow(&[
        "serve",
        "--listen",
        &endpoint(27538),
        "--name",
        engine,
        "--own-data-policy",
        &a_arg,
    ]);
    line_with(&lines, "ready", Duration::from_secs(20));
    let client = connect(27538);
    let far: Vec<f64> = OBSERVATIONS.iter().map(|o| 40.0 * o).collect();
    let (actions_a, actions_b) = (own_data_actions(&a, &far), own_data_actions(&b, &far));
    assert_ne!(actions_a, actions_b);
    assert_eq!(client.act(engine, "mine", &far).unwrap(), actions_a);

    let publisher = CheckpointPublisher::open(
        &NetworkOptions::endpoint(Role::Client, &endpoint(27538)),
        "mine",
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    publisher.publish(&b, 5, -1.5).unwrap();
    wait_for_epoch(&client, engine, "mine", 5);
    assert_eq!(client.act(engine, "mine", &far).unwrap(), actions_b);
    let listed = client.engine_info(engine).unwrap().policies;
    assert_eq!(
        (listed[0].task.as_str(), listed[0].observation_dim),
        (ciflow_envs::actor::OWN_DATA_TASK, 8)
    );

    // Other shapes are refused; the publication after them is taken.
    publisher.publish(&wider, 6, -1.0).unwrap();
    publisher.publish(&a, 7, -2.0).unwrap();
    wait_for_epoch(&client, engine, "mine", 7);
    assert_eq!(client.act(engine, "mine", &far).unwrap(), actions_a);
    let _ = server.0.kill();
    let _ = server.0.wait();
    let log = server.stderr();
    assert!(
        log.contains("acts on 8 observations with 2 actions, the checkpoint on 10 with 3"),
        "{log}"
    );
}

/// Waits until the engine lists policy `name` with `epoch`.
fn wait_for_epoch(client: &Client, engine: &str, name: &str, epoch: u64) {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let info = client.engine_info(engine).unwrap();
        if info
            .policies
            .iter()
            .any(|p| p.name == name && p.epoch == Some(epoch))
        {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "epoch {epoch} never loaded: {info:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn published_checkpoints_replace_the_policy_without_restart_and_bad_ones_are_ignored() {
    let scratch = Scratch::new("policy-hot");
    let (a, b) = (scratch.join("a"), scratch.join("b"));
    write_flow(&a, 1);
    write_flow(&b, 2);
    let (actions_a, actions_b) = (
        local_actions(&a, &OBSERVATIONS),
        local_actions(&b, &OBSERVATIONS),
    );
    assert_ne!(actions_a, actions_b);
    let a_arg = format!("avoid={}", a.display());
    let _server = serve(
        27533,
        "policy-hot",
        &["--policy", &a_arg, "--policy-kwarg", "obstacles=1"],
    );
    let client = connect(27533);
    assert_eq!(
        client.act("policy-hot", "avoid", &OBSERVATIONS).unwrap(),
        actions_a
    );

    let publisher = CheckpointPublisher::open(
        &NetworkOptions::endpoint(Role::Client, &endpoint(27533)),
        "avoid",
    )
    .unwrap();
    // The engine's subscription must have reached the publisher's session first.
    std::thread::sleep(Duration::from_millis(300));
    publisher.publish(&b, 7, -1.25).unwrap();
    wait_for_epoch(&client, "policy-hot", "avoid", 7);
    assert_eq!(
        client.act("policy-hot", "avoid", &OBSERVATIONS).unwrap(),
        actions_b
    );
    let info = client.engine_info("policy-hot").unwrap();
    assert_eq!(info.policies[0].validation_nll, Some(-1.25));

    // Garbage, truncated weights and a task the policy does not act in: all ignored.
    let zenoh = client.zenoh_session();
    let key = keys::policy_checkpoint("avoid");
    zenoh.put(&key, b"garbage".to_vec()).wait().unwrap();
    let message = |config: String, weights: Vec<u8>| CheckpointMsg {
        v: PROTOCOL_VERSION,
        name: "avoid".into(),
        task: "obstacle-avoidance".into(),
        config,
        weights: ByteBuf::from(weights),
        epoch: 8,
        validation_nll: 0.0,
        kwargs: BTreeMap::new(),
        signature: None,
    };
    let config = std::fs::read_to_string(a.join(CONFIG_FILE)).unwrap();
    let weights = std::fs::read(a.join(WEIGHTS_FILE)).unwrap();
    let truncated = message(config.clone(), weights[..weights.len() / 2].to_vec());
    zenoh.put(&key, encode(&truncated)).wait().unwrap();
    let three_obstacles = CheckpointMsg {
        kwargs: BTreeMap::from([("obstacles".to_owned(), 3.0.into())]),
        ..message(config, weights)
    };
    zenoh.put(&key, encode(&three_obstacles)).wait().unwrap();

    // The engine still serves B, and still takes good publications after the bad ones.
    publisher.publish(&a, 9, -2.0).unwrap();
    wait_for_epoch(&client, "policy-hot", "avoid", 9);
    assert_eq!(
        client.act("policy-hot", "avoid", &OBSERVATIONS).unwrap(),
        actions_a
    );
}

/// The tests' throwaway trainer key pair (`bridge/tests/keys`).
fn test_key(file: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("bridge/tests/keys")
        .join(file)
        .to_string_lossy()
        .into_owned()
}

#[test]
fn an_engine_with_a_trusted_key_refuses_unsigned_checkpoints_and_says_so_once() {
    let scratch = Scratch::new("policy-signed");
    let (a, b) = (scratch.join("a"), scratch.join("b"));
    write_flow(&a, 1);
    write_flow(&b, 2);
    let a_arg = format!("avoid={}", a.display());
    let (trusted, engine) = ("--trusted-key", "policy-signed");
    let (mut server, lines) = spawn_ciflow(&[
        "serve",
        "--listen",
        &endpoint(27534),
        "--name",
        engine,
        "--policy",
        &a_arg,
        "--policy-kwarg",
        "obstacles=1",
        trusted,
        &test_key("trainer.pub.pem"),
    ]);
    line_with(&lines, "ready", Duration::from_secs(20));
    let client = connect(27534);
    let network = NetworkOptions::endpoint(Role::Client, &endpoint(27534));
    let rogue = CheckpointPublisher::open(&network, "avoid").unwrap();
    let signer = CheckpointSigner::from_pem_file(Path::new(&test_key("trainer.pem"))).unwrap();
    let trainer = CheckpointPublisher::open(&network, "avoid")
        .unwrap()
        .with_signer(Some(signer));
    std::thread::sleep(Duration::from_millis(300));
    for epoch in 2..7 {
        rogue.publish(&b, epoch, 0.0).unwrap();
    }
    trainer.publish(&b, 7, -1.0).unwrap();
    wait_for_epoch(&client, engine, "avoid", 7);

    let _ = server.0.kill();
    let _ = server.0.wait();
    let log = server.stderr();
    let refusals = log.matches("not signed").count();
    assert_eq!(
        refusals, 1,
        "five unsigned publications, one report:\n{log}"
    );
}

/// Target and obstacle well below the straight path from the start to the target.
const TARGET: [f64; 2] = [0.8, 0.1];

fn reset_for_run(env: &RemoteEnv) {
    let options = ResetOptions {
        context: Some(vec![0.0, -0.7, TARGET[0], TARGET[1]]),
        initial_position: Some(vec![-0.8, 0.2]),
        ..ResetOptions::default()
    };
    env.reset(Some(0), Some(options)).unwrap();
}

/// Telemetry samples of one run, by step, until the sample that ends it.
fn record_run(env: &RemoteEnv, telemetry: &ciflow_bridge::TelemetryStream) -> Vec<Telemetry> {
    let mut samples = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "the run never ended");
        let Some(sample) = telemetry.recv_timeout(Duration::from_secs(5)).unwrap() else {
            panic!("telemetry stopped before the run ended");
        };
        let over = !sample.running;
        samples.push(sample);
        if over {
            // A stopped or finished run no longer refuses client requests.
            assert_ne!(
                env.step(&[0.0, 0.0]).map_err(code).err(),
                Some(ErrorCode::Busy)
            );
            return samples;
        }
    }
}

#[test]
fn policy_driven_session_recovers_from_a_push_and_refuses_client_steps() {
    let scratch = Scratch::new("policy-run");
    let dir = scratch.join("a");
    write_flow(&dir, 1);
    let dir_arg = format!("avoid={}", dir.display());
    let _server = serve(
        27535,
        "policy-run",
        &[
            "--policy",
            &dir_arg,
            "--policy-kwarg",
            "obstacles=1",
            "--telemetry-hz",
            "5000",
        ],
    );
    let client = connect(27535);
    let kwargs = BTreeMap::from([("obstacles".to_owned(), 1.0.into())]);
    let env = client.make("policy-run", OBSTACLE, 1, &kwargs).unwrap();
    let telemetry = env.control().telemetry().unwrap();
    std::thread::sleep(Duration::from_millis(300));

    // `run` needs a reset first; then the unperturbed reference run at 4× real time.
    assert_eq!(
        code(env.control().run(0, "avoid", 4.0, None).unwrap_err()),
        ErrorCode::NeedsReset
    );
    reset_for_run(&env);
    while telemetry
        .recv_timeout(Duration::from_millis(200))
        .unwrap()
        .is_some()
    {}
    env.control().run(0, "avoid", 4.0, None).unwrap();
    assert_eq!(code(env.step(&[0.0, 0.0]).unwrap_err()), ErrorCode::Busy);
    assert_eq!(code(env.reset(None, None).unwrap_err()), ErrorCode::Busy);
    let reference = record_run(&env, &telemetry);

    // The same start with a 0.2 s push of 10 N along +y at t = 0.5 s.
    reset_for_run(&env);
    while telemetry
        .recv_timeout(Duration::from_millis(200))
        .unwrap()
        .is_some()
    {}
    env.control()
        .perturb(
            0,
            PerturbationMsg {
                kind: PerturbationKindMsg::JointTorque {
                    torque: vec![0.0, 10.0],
                },
                start: Some(0.5),
                duration: 0.2,
            },
        )
        .unwrap();
    env.control().run(0, "avoid", 4.0, None).unwrap();
    let pushed = record_run(&env, &telemetry);

    for run in [&reference, &pushed] {
        let last = run.last().unwrap();
        assert!(last.episode_done, "the run ends with the episode");
        let distance =
            ((last.state.0[0] - TARGET[0]).powi(2) + (last.state.0[1] - TARGET[1]).powi(2)).sqrt();
        assert!(distance < 0.02, "final distance to the target {distance} m");
        assert!(
            run.len() > 50,
            "telemetry during the run: {} samples",
            run.len()
        );
    }
    // During and right after the push the state departs from the reference.
    let by_step: BTreeMap<u64, &Telemetry> = reference.iter().map(|s| (s.step, s)).collect();
    let departure = pushed
        .iter()
        .filter(|s| (0.55..=0.9).contains(&s.time))
        .filter_map(|s| {
            by_step
                .get(&s.step)
                .map(|r| (s.state.0[3] - r.state.0[3]).abs())
        })
        .fold(0.0, f64::max);
    assert!(
        departure > 0.3,
        "the push changes the y-velocity by {departure} m/s"
    );

    // `stop` ends a run early and hands stepping back to the client.
    reset_for_run(&env);
    env.control().run(0, "avoid", 1.0, None).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    env.control().stop().unwrap();
    env.reset(None, None).unwrap();
    env.step(&[0.0, 0.0]).unwrap();
}
