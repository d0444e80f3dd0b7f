//! Shared set-up of the bridge's tests: an engine and clients on a private loopback port,
//! and `Fixture`, a tiny test-only task whose behaviour the tests know exactly (short
//! episodes for autoreset, a deliberate panic for crash containment).

#![allow(dead_code)]

use std::sync::Arc;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use ciflow_bridge::protocol::{
    BatchStepRequest, ErrorCode, ErrorReply, F64s, PROTOCOL_VERSION, encode, keys,
};
use ciflow_bridge::{
    BridgeError, Client, EngineServer, NetworkOptions, RemoteEnv, Role, ServerOptions, TaskFactory,
    query_all,
};
use ciflow_engine::flow::checkpoint;
use ciflow_engine::flow::{CheckpointConfig, CouplingKind, FlowConfig, LatentKind, Weights};
use ciflow_engine::sim::Perturbation;
use ciflow_envs::scene::{Body, Scene, Shape};
use ciflow_envs::{BoxSpace, Dtype, Env, EnvError, EnvSpec, Info, ResetOptions, StepOutcome};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub const FIXTURE_ID: &str = "test/Fixture-v0";
/// An action whose first element is this value makes the fixture panic.
pub const PANIC_ACTION: f64 = 12345.0;
pub const EPISODE_STEPS: u64 = 5;
/// The fixture's variant whose info key is [`LONG_INFO_KEY`].
pub const LONG_KEYED_FIXTURE_ID: &str = "test/LongKeyedFixture-v0";
/// An info key longer than a reply's estimate of 64 bytes per key.
pub const LONG_INFO_KEY: &str =
    "distance_from_the_context_in_metres_as_a_task_with_verbose_names_would_put_it";

/// A 1-D integrator `x ← x + a·dt` with context `c` (observation `[x, c]`), truncated
/// after [`EPISODE_STEPS`] steps; reward `-|x - c|`.
pub struct Fixture {
    spec: EnvSpec,
    rng: ChaCha8Rng,
    x: f64,
    context: f64,
    steps: u64,
    /// The key of the step's info value, `distance` unless made [`Fixture::long_keyed`].
    info_key: &'static str,
    pub perturbations: Vec<Perturbation>,
}

impl Fixture {
    pub fn new() -> Self {
        let unbounded = || BoxSpace::new(vec![-1e9], vec![1e9], Dtype::Float64);
        Self {
            spec: EnvSpec {
                id: FIXTURE_ID.into(),
                observation_space: BoxSpace::new(vec![-1e9, -1.0], vec![1e9, 1.0], Dtype::Float64),
                action_space: unbounded(),
                context_space: BoxSpace::new(vec![-1.0], vec![1.0], Dtype::Float64),
                control_dt: 0.1,
                physics_dt: 0.1,
                max_episode_steps: EPISODE_STEPS as u32,
            },
            rng: ChaCha8Rng::seed_from_u64(0),
            x: 0.0,
            context: 0.0,
            steps: 0,
            info_key: "distance",
            perturbations: Vec::new(),
        }
    }

    /// The fixture reporting its distance under [`LONG_INFO_KEY`].
    pub fn long_keyed() -> Self {
        let mut fixture = Self::new();
        fixture.spec.id = LONG_KEYED_FIXTURE_ID.into();
        fixture.info_key = LONG_INFO_KEY;
        fixture
    }

    fn observation(&self) -> Vec<f64> {
        vec![self.x, self.context]
    }
}

impl Env for Fixture {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(
        &mut self,
        seed: Option<u64>,
        options: &ResetOptions,
    ) -> Result<(Vec<f64>, Info), EnvError> {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        self.context = match &options.context {
            Some(c) => {
                self.spec.context_space.check("context", c)?;
                c[0]
            }
            None => self.rng.random_range(-1.0..1.0),
        };
        self.x = self.rng.random_range(-1.0..1.0);
        self.steps = 0;
        let mut info = Info::new();
        info.insert("reset".into(), 1.0);
        Ok((self.observation(), info))
    }

    fn step_into(
        &mut self,
        action: &[f64],
        observation: &mut [f64],
        info: &mut Info,
    ) -> Result<StepOutcome, EnvError> {
        self.spec.action_space.check("action", action)?;
        self.spec.check_observation_buffer(observation)?;
        assert!(action[0] != PANIC_ACTION, "fixture asked to panic");
        self.x += action[0] * self.spec.control_dt;
        self.steps += 1;
        info.clear();
        info.insert(self.info_key.into(), (self.x - self.context).abs());
        observation.copy_from_slice(&self.observation());
        Ok(StepOutcome {
            reward: -(self.x - self.context).abs(),
            terminated: false,
            truncated: self.steps >= EPISODE_STEPS,
        })
    }

    fn expert_action(&self) -> Result<Vec<f64>, EnvError> {
        Ok(vec![(self.context - self.x) / self.spec.control_dt])
    }

    fn set_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
        self.spec.context_space.check("context", context)?;
        self.context = context[0];
        Ok(())
    }

    fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError> {
        self.perturbations.push(perturbation);
        Ok(())
    }

    fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, EnvError> {
        let shade = ((self.x.tanh() + 1.0) * 127.0) as u8;
        Ok(vec![shade; (width * height * 3) as usize])
    }

    /// The fixture keeps no trail.
    fn record_trail(&mut self, _recording: bool) {}

    /// A ball at `x` on the line.
    fn scene(&self, observation: &[f64]) -> Result<Scene, EnvError> {
        let (state, _) = self.spec.split_observation(observation)?;
        let ball = Shape::sphere([state[0], 0.0, 0.0].into(), 0.1);
        Ok(Scene {
            bodies: vec![Body::new("ball", ball, [0, 0, 0])],
        })
    }
}

pub fn fixture_task() -> TaskFactory {
    TaskFactory {
        id: FIXTURE_ID.into(),
        name: "fixture".into(),
        make: Arc::new(|_| Ok(Box::new(Fixture::new()) as Box<dyn Env>)),
    }
}

pub fn long_keyed_fixture_task() -> TaskFactory {
    TaskFactory {
        id: LONG_KEYED_FIXTURE_ID.into(),
        name: "long-keyed-fixture".into(),
        make: Arc::new(|_| Ok(Box::new(Fixture::long_keyed()) as Box<dyn Env>)),
    }
}

pub fn endpoint(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}

/// An engine serving the fixture (and the registered tasks) on `port`.
pub fn start_engine(port: u16) -> EngineServer {
    let mut options = ServerOptions::default();
    options.tasks.push(fixture_task());
    options.name = Some(format!("test-{port}"));
    EngineServer::open(
        &NetworkOptions::endpoint(Role::Engine, &endpoint(port)),
        options,
    )
    .expect("engine starts")
}

pub fn connect(port: u16) -> Client {
    Client::open(&NetworkOptions::endpoint(Role::Client, &endpoint(port))).expect("client connects")
}

/// Polls `condition` for up to `seconds`.
pub fn eventually(seconds: f64, mut condition: impl FnMut() -> bool) -> bool {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs_f64(seconds);
    while std::time::Instant::now() < deadline {
        if condition() {
            return true;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    condition()
}

pub fn no_kwargs() -> ciflow_bridge::Kwargs {
    BTreeMap::new()
}

/// The code of a typed engine error; panics on any other error.
pub fn remote_code(error: BridgeError) -> ErrorCode {
    match error {
        BridgeError::Remote(reply) => reply.code,
        other => panic!("expected a typed engine error, got {other}"),
    }
}

/// Sends raw bytes to `key` and returns its one reply (payload or typed error).
pub fn raw_query(
    session: &zenoh::Session,
    key: &str,
    payload: Vec<u8>,
) -> Result<Vec<u8>, ErrorReply> {
    let mut replies = query_all(session, key, payload, Duration::from_secs(15)).unwrap();
    assert_eq!(replies.len(), 1, "exactly one reply to {key}");
    replies.pop().unwrap()
}

/// The key and payload of a `step_batch` request for `env`'s environments, to send by
/// hand.
pub fn step_batch_request(
    env: &RemoteEnv,
    actions: &[f64],
    known_contexts: Option<u64>,
) -> (String, Vec<u8>) {
    let key = keys::session(
        env.engine(),
        keys::ANONYMOUS,
        env.session_id(),
        "step_batch",
    );
    let request = encode(&BatchStepRequest {
        v: PROTOCOL_VERSION,
        token: serde_bytes::ByteBuf::from(env.token()),
        actions: F64s(actions.to_vec()),
        known_contexts,
    });
    (key, request)
}

/// A random one-obstacle go-to flow checkpoint in a fresh directory.
pub fn write_checkpoint(tag: &str) -> PathBuf {
    let mut config = FlowConfig::new(
        "obstacle-avoidance",
        2,
        4,
        LatentKind::GoTo,
        CouplingKind::AFFINE,
        4,
        vec![16, 16],
    );
    config.goal_context_indices = Some(vec![2, 3]);
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.1,
        &mut ChaCha8Rng::seed_from_u64(5),
    );
    let dir = std::env::temp_dir().join(format!("ciflow-{tag}-{}", std::process::id()));
    checkpoint::write(&dir, &CheckpointConfig::Flow(config), &weights).unwrap();
    dir
}

/// The construction arguments of [`write_checkpoint`]'s task.
pub fn one_obstacle() -> ciflow_bridge::Kwargs {
    BTreeMap::from([("obstacles".to_owned(), 1.0.into())])
}

/// This process's mappings of Zenoh's shared-memory segments: each mapping's address
/// range and its segment's file (a segment read by several sessions is mapped once per
/// session).
#[cfg(target_os = "linux")]
pub fn shared_memory_mappings() -> Vec<(std::ops::Range<usize>, String)> {
    let maps = std::fs::read_to_string("/proc/self/maps").expect("/proc/self/maps");
    maps.lines()
        .filter(|line| line.contains("/dev/shm/") && line.ends_with(".zenoh"))
        .map(|line| {
            let range = line.split_whitespace().next().expect("address range");
            let path = line.split_whitespace().last().expect("segment file");
            let (start, end) = range.split_once('-').expect("start-end");
            let address = |hex: &str| usize::from_str_radix(hex, 16).expect("hex address");
            (address(start)..address(end), path.to_owned())
        })
        .collect()
}
