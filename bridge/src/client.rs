//! The Rust client: discovers engines, opens sessions and drives them. The Python
//! extension wraps it; the integration tests and benchmarks use it directly.
//!
//! Blocking API: each call is one Zenoh query (`step` through a pre-declared querier),
//! waiting for its one reply; [`crate::vector`] sends one to each of several sessions
//! before it waits for any.

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use ciflow_envs::registry::Kwargs;
use ciflow_envs::{EnvSpec, Info, ResetOptions};
use ciflow_evaluation::stability::{Ending, StabilityConfig};
use ciflow_evaluation::stability_check::Subject;
use ciflow_evaluation::{EpisodeBatch, EvaluationConfig};
use serde::Serialize;
use serde::de::DeserializeOwned;
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::handlers::FifoChannelHandler;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber;
use zenoh::query::{ConsolidationMode, Querier, QueryTarget};
use zenoh::sample::Sample;

use crate::config::{NetworkOptions, Role};
use crate::control::{SessionAddress, SessionControl, TelemetryStream};
use crate::error::{BridgeError, check_name};
use crate::limits::{Limits, Usage};
use crate::protocol::keys::{self, SessionOp};
use crate::protocol::{
    AckReply, ActRequest, ActionReply, BatchResetReply, BatchSeeds, BatchStepReplyView,
    BatchStepRequest, ContextUpdateView, DescribeReply, DescribeRequest, EvaluateReply,
    EvaluateRequest, F64Slice, F64s, FrameHeader, LimitsReply, LimitsRequest, MakeReply,
    MakeRequest, PROTOCOL_VERSION, PolicyInfo, RenderReply, RenderRequest, ResetReply,
    ResetRequest, StabilityReply, StabilityRequest, StepReply, StepRequest, TaskInfo, TasksReply,
    TasksRequest, decode_reply, encode, write_le_bytes,
};
use crate::query::{Pending, decode_ok, query, retry_unanswered, send_query};

/// Default wait for a reply.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(10);

/// An engine found by [`Client::discover`].
#[derive(Clone, Debug, PartialEq)]
pub struct EngineInfo {
    pub name: String,
    pub tasks: Vec<TaskInfo>,
    pub policies: Vec<PolicyInfo>,
}

impl EngineInfo {
    /// Whether the engine serves `task` (Gymnasium id or short name).
    pub fn serves(&self, task: &str) -> bool {
        self.tasks.iter().any(|t| t.is_named(task))
    }
}

impl From<TasksReply> for EngineInfo {
    fn from(reply: TasksReply) -> Self {
        Self {
            name: reply.engine,
            tasks: reply.tasks,
            policies: reply.policies,
        }
    }
}

/// A process's identity towards engines: a Zenoh session and a liveliness token under
/// which its sessions live (they are closed when the token goes away).
pub struct Client {
    zsession: zenoh::Session,
    /// Who this process is; the `<identity>` chunk of the keys of its sessions.
    identity: String,
    /// `<identity>/<instance>`, which owns this process's sessions.
    name: String,
    timeout: Duration,
    _token: LivelinessToken,
}

impl Client {
    /// Connects to Zenoh as a client (default: to [`crate::DEFAULT_ENDPOINT`]). Fails
    /// fast with [`BridgeError::NoEngine`]-like advice when nothing listens there.
    pub fn open(network: &NetworkOptions) -> Result<Self, BridgeError> {
        let zsession = network.open(
            Role::Client,
            "join Zenoh",
            "is an engine or router running there? Start one with `ciflow serve`",
        )?;
        let identity = network.identity.as_deref().unwrap_or(keys::ANONYMOUS);
        Self::with_identity(zsession, identity)
    }

    /// Uses an open Zenoh session (e.g. the one of an engine in the same process), as
    /// [`keys::ANONYMOUS`].
    pub fn with_session(zsession: zenoh::Session) -> Result<Self, BridgeError> {
        Self::with_identity(zsession, keys::ANONYMOUS)
    }

    /// Uses an open Zenoh session as `identity` (see [`NetworkOptions::identity`]).
    pub fn with_identity(zsession: zenoh::Session, identity: &str) -> Result<Self, BridgeError> {
        check_name("identity", identity)?;
        let name = keys::client(identity, &format!("c{:016x}", rand::random::<u64>()));
        let token = zsession
            .liveliness()
            .declare_token(keys::client_alive(&name))
            .wait()
            .map_err(BridgeError::zenoh(
                "declaring the client's liveliness token",
            ))?;
        Ok(Self {
            zsession,
            identity: identity.to_owned(),
            name,
            timeout: DEFAULT_TIMEOUT,
            _token: token,
        })
    }

    /// `<identity>/<instance>`: the name under which this process's sessions are owned.
    pub fn id(&self) -> &str {
        &self.name
    }

    /// Who this process is: the `<identity>` chunk of its sessions' keys.
    pub fn identity(&self) -> &str {
        &self.identity
    }

    /// The `<instance>` chunk of [`Client::id`].
    pub fn instance(&self) -> &str {
        self.name
            .split_once('/')
            .map_or("", |(_, instance)| instance)
    }

    pub fn zenoh_session(&self) -> &zenoh::Session {
        &self.zsession
    }

    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// Every engine reachable now, with its tasks and policies.
    pub fn discover(&self) -> Result<Vec<EngineInfo>, BridgeError> {
        let payload = ZBytes::from(encode(&TasksRequest {
            v: PROTOCOL_VERSION,
        }));
        let mut engines = retry_unanswered(self.timeout, || {
            let sent = Instant::now();
            let replies = self
                .zsession
                .get(keys::ALL_ENGINES_TASKS)
                .payload(payload.clone())
                .consolidation(ConsolidationMode::None)
                .target(QueryTarget::All)
                .timeout(self.timeout)
                .wait()
                .map_err(BridgeError::zenoh("asking the engines for their tasks"))?;
            Ok(replies
                .iter()
                .filter_map(|reply| {
                    decode_ok::<TasksReply>(keys::ALL_ENGINES_TASKS, &reply, sent).ok()
                })
                .map(EngineInfo::from)
                .collect::<Vec<_>>())
        })?;
        engines.sort_by(|a, b| a.name.cmp(&b.name));
        engines.dedup_by(|a, b| a.name == b.name);
        Ok(engines)
    }

    /// The name of the first reachable engine, in name order, that serves `task` (any
    /// engine for `None`); `None` when no engine does.
    pub fn first_engine_serving(&self, task: Option<&str>) -> Result<Option<String>, BridgeError> {
        Ok(self
            .discover()?
            .into_iter()
            .find(|engine| task.is_none_or(|task| engine.serves(task)))
            .map(|engine| engine.name))
    }

    /// Tasks and policies of one engine.
    pub fn engine_info(&self, engine: &str) -> Result<EngineInfo, BridgeError> {
        check_name("engine name", engine)?;
        let reply: TasksReply = self.call(
            &keys::tasks(engine),
            &TasksRequest {
                v: PROTOCOL_VERSION,
            },
        )?;
        Ok(reply.into())
    }

    /// The controls of a session another process made, from its id and token; `engine`
    /// names the engine that holds it, or [`ANY_ENGINE`](crate::ANY_ENGINE) for whichever
    /// does. Nothing is sent until a control is used; the session stays its owner's.
    pub fn attach(
        &self,
        engine: &str,
        session: &str,
        token: &[u8],
    ) -> Result<SessionControl, BridgeError> {
        SessionControl::new(
            self.zsession.clone(),
            SessionAddress::new(engine, &self.identity, session),
            token,
            self.timeout,
        )
    }

    /// What a session is — its task, construction arguments and size — from the engine,
    /// the owner's identity and the session id (as a telemetry key names them); needs no
    /// token.
    pub fn describe(
        &self,
        engine: &str,
        identity: &str,
        session: &str,
    ) -> Result<DescribeReply, BridgeError> {
        self.call(
            &keys::session(engine, identity, session, SessionOp::Describe.as_str()),
            &DescribeRequest {
                v: PROTOCOL_VERSION,
            },
        )
    }

    /// The telemetry of every session on `engine` ([`ANY_ENGINE`](crate::ANY_ENGINE): on
    /// every engine) that this identity may read, each sample with where it came from.
    pub fn watch(&self, engine: &str) -> Result<TelemetryStream, BridgeError> {
        TelemetryStream::subscribe(
            &self.zsession,
            &keys::session(engine, "*", "*", "telemetry"),
        )
    }

    /// Opens a session of `num_envs` environments of `task` on `engine`, built with the
    /// task's construction arguments `kwargs`.
    pub fn make(
        &self,
        engine: &str,
        task: &str,
        num_envs: u32,
        kwargs: &Kwargs,
    ) -> Result<RemoteEnv, BridgeError> {
        let reply: MakeReply = self.call(
            &keys::make(engine, &self.identity),
            &MakeRequest {
                v: PROTOCOL_VERSION,
                instance: self.instance().to_owned(),
                task: task.to_owned(),
                num_envs,
                kwargs: kwargs.clone(),
                deadline_ms: Some(self.deadline_ms()),
            },
        )?;
        let address = SessionAddress::new(engine, &self.identity, &reply.session);
        RemoteEnv::new(self.zsession.clone(), address, reply, self.timeout)
    }

    /// Asks policy `policy` of `engine` for the actions of `n` observations (row-major).
    pub fn act(
        &self,
        engine: &str,
        policy: &str,
        observations: &[f64],
    ) -> Result<Vec<f64>, BridgeError> {
        let reply: ActionReply = self.call(
            &keys::policy_act(engine, policy),
            &ActRequest {
                v: PROTOCOL_VERSION,
                observations: F64s(observations.to_vec()),
                deadline_ms: Some(self.deadline_ms()),
            },
        )?;
        Ok(reply.action.0)
    }

    /// Has checkpoint policy `policy` of `engine` run the closed-loop episodes `episodes`
    /// of the evaluation `config` in its task (see [`crate::spread`] for a whole
    /// evaluation over many engines).
    pub fn evaluate(
        &self,
        engine: &str,
        policy: &str,
        config: &EvaluationConfig,
        episodes: Range<usize>,
    ) -> Result<EpisodeBatch, BridgeError> {
        let reply: EvaluateReply = self.call(
            &keys::policy_evaluate(engine, policy),
            &EvaluateRequest {
                v: PROTOCOL_VERSION,
                config: config.clone(),
                first: episodes.start as u64,
                count: episodes.len() as u64,
                deadline_ms: Some(self.deadline_ms()),
            },
        )?;
        Ok(reply.batch)
    }

    /// Has checkpoint policy `policy` of `engine` run the observation-space rollouts
    /// `trials` of the stability check `config` of `subject` (the checkpoint's model or its
    /// negative control), and returns their endings in order.
    pub fn stability(
        &self,
        engine: &str,
        policy: &str,
        subject: Subject,
        config: &StabilityConfig,
        trials: Range<usize>,
    ) -> Result<Vec<Ending>, BridgeError> {
        let reply: StabilityReply = self.call(
            &keys::policy_stability(engine, policy),
            &StabilityRequest {
                v: PROTOCOL_VERSION,
                subject,
                config: config.clone(),
                first: trials.start as u64,
                count: trials.len() as u64,
                deadline_ms: Some(self.deadline_ms()),
            },
        )?;
        if reply.endings.len() != trials.len() {
            return Err(BridgeError::InvalidArgument(format!(
                "engine `{engine}` returned {} endings for {} rollouts",
                reply.endings.len(),
                trials.len()
            )));
        }
        Ok(reply.endings)
    }

    /// The deadline the requests that build or compute in bulk carry: nine tenths of this
    /// client's timeout, so that the engine stops working before nobody waits for the
    /// answer, and its refusal still arrives.
    fn deadline_ms(&self) -> u32 {
        u32::try_from(self.timeout.as_millis() * 9 / 10).unwrap_or(u32::MAX)
    }

    /// `engine`'s bounds, and what this client holds of them.
    pub fn limits(&self, engine: &str) -> Result<(Limits, Usage), BridgeError> {
        let reply: LimitsReply = self.call(
            &keys::limits(engine, &self.identity),
            &LimitsRequest {
                v: PROTOCOL_VERSION,
                instance: Some(self.instance().to_owned()),
            },
        )?;
        Ok((reply.limits, reply.usage.unwrap_or_default()))
    }

    fn call<R: DeserializeOwned>(
        &self,
        key: &str,
        request: &impl Serialize,
    ) -> Result<R, BridgeError> {
        query(&self.zsession, key, encode(request), self.timeout)
    }
}

/// Result of [`RemoteEnv::step`].
#[derive(Clone, Debug, PartialEq)]
pub struct StepResult {
    pub observation: Vec<f64>,
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    pub info: Info,
    /// Simulated seconds since the reset.
    pub time: f64,
}

/// `info` of a batch: key → one value per environment (NaN where absent).
pub type InfoColumns = BTreeMap<String, Vec<f64>>;

/// Result of [`RemoteEnv::step_batch`] (next-step autoreset, see the protocol).
#[derive(Clone, Debug, PartialEq)]
pub struct BatchStep {
    /// Row-major `num_envs × obs_dim`.
    pub observations: Vec<f64>,
    pub rewards: Vec<f64>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    pub info: InfoColumns,
}

impl BatchStep {
    /// The results of `envs` environments with `observation_dim` observations each, as
    /// `step` writes them (in their wire form) and returns the info columns.
    pub(crate) fn written(
        envs: usize,
        observation_dim: usize,
        step: impl FnOnce(BatchStepOut<'_>) -> Result<InfoColumns, BridgeError>,
    ) -> Result<Self, BridgeError> {
        let mut observations = vec![0.0; envs * observation_dim];
        let mut rewards = vec![0.0; envs];
        let (mut terminated, mut truncated) = (vec![0; envs], vec![0; envs]);
        let info = write_le_bytes(&mut observations, |observations| {
            write_le_bytes(&mut rewards, |rewards| {
                step(BatchStepOut {
                    observations,
                    rewards,
                    terminated: &mut terminated,
                    truncated: &mut truncated,
                })
            })
        })?;
        let flags = |bytes: Vec<u8>| bytes.into_iter().map(|b| b != 0).collect();
        Ok(Self {
            observations,
            rewards,
            terminated: flags(terminated),
            truncated: flags(truncated),
            info,
        })
    }
}

/// Where a batch step's results go, in their wire form: little-endian `f64` bytes
/// (`observations` row-major `num_envs × obs_dim`, `rewards` one per environment) and one
/// byte per flag, 0 or 1. Python's arrays read such memory in place, so a reply is copied
/// once, from the payload to them ([`crate::vector::step_batches_into`]).
#[derive(Debug)]
pub struct BatchStepOut<'a> {
    pub observations: &'a mut [u8],
    pub rewards: &'a mut [u8],
    pub terminated: &'a mut [u8],
    pub truncated: &'a mut [u8],
}

impl BatchStepOut<'_> {
    /// The environments `envs` of the batch, `observation_dim` observations each.
    pub(crate) fn rows(&mut self, envs: Range<usize>, observation_dim: usize) -> BatchStepOut<'_> {
        let (start, end) = (envs.start, envs.end);
        BatchStepOut {
            observations: &mut self.observations
                [8 * start * observation_dim..8 * end * observation_dim],
            rewards: &mut self.rewards[8 * start..8 * end],
            terminated: &mut self.terminated[start..end],
            truncated: &mut self.truncated[start..end],
        }
    }

    /// Environments the buffers hold, if their lengths agree for `observation_dim`.
    pub(crate) fn envs(&self, observation_dim: usize) -> Option<usize> {
        let envs = self.terminated.len();
        (self.truncated.len() == envs
            && self.rewards.len() == 8 * envs
            && self.observations.len() == 8 * envs * observation_dim)
            .then_some(envs)
    }

    /// Copies `reply` in; its columns must fill the buffers exactly. With `contexts`
    /// (little-endian `f64` bytes, row-major, `context_dim` values per environment) the
    /// reply's observations leave the contexts out, and each row is completed from them.
    fn copy_from(
        &mut self,
        reply: &BatchStepReplyView,
        contexts: Option<(&[u8], usize)>,
    ) -> Result<InfoColumns, rmp_serde::decode::Error> {
        let observations = match contexts {
            Some((contexts, context_dim)) => {
                self.copy_observations(reply.observations.0, contexts, context_dim)?;
                None
            }
            None => Some((
                "observations",
                reply.observations.0,
                &mut *self.observations,
            )),
        };
        let columns = [
            ("rewards", reply.rewards.0, &mut *self.rewards),
            ("terminated", &reply.terminated[..], &mut *self.terminated),
            ("truncated", &reply.truncated[..], &mut *self.truncated),
        ];
        for (name, from, to) in observations.into_iter().chain(columns) {
            if from.len() != to.len() {
                return Err(serde::de::Error::custom(format!(
                    "{} bytes of {name} where the batch takes {}",
                    from.len(),
                    to.len()
                )));
            }
            to.copy_from_slice(from);
        }
        let envs = self.terminated.len();
        reply
            .info
            .iter()
            .map(|(key, values)| {
                if values.len() != envs {
                    return Err(serde::de::Error::custom(format!(
                        "{} values of info `{key}` for {envs} environments",
                        values.len()
                    )));
                }
                let values = F64s::from_le_bytes(values.0).expect("whole values");
                Ok(((*key).to_owned(), values))
            })
            .collect()
    }

    /// Writes each row as its state from `states` (the observations without their
    /// contexts) followed by its context from `contexts`, both little-endian bytes.
    fn copy_observations(
        &mut self,
        states: &[u8],
        contexts: &[u8],
        context_dim: usize,
    ) -> Result<(), rmp_serde::decode::Error> {
        let envs = self.terminated.len();
        let observation_dim = self.observations.len() / (8 * envs).max(1);
        let state_dim = observation_dim.saturating_sub(context_dim);
        if states.len() != 8 * envs * state_dim || contexts.len() != 8 * envs * context_dim {
            return Err(serde::de::Error::custom(format!(
                "{} bytes of states for {envs} environments of {state_dim} state values",
                states.len()
            )));
        }
        let rows = self.observations.chunks_exact_mut(8 * observation_dim);
        let states = states.chunks_exact(8 * state_dim.max(1));
        for ((row, state), context) in rows
            .zip(states)
            .zip(contexts.chunks_exact(8 * context_dim.max(1)))
        {
            let (state_bytes, context_bytes) = row.split_at_mut(8 * state_dim);
            state_bytes.copy_from_slice(state);
            context_bytes.copy_from_slice(context);
        }
        Ok(())
    }
}

/// A session on an engine, owned by the [`Client`] that made it. Closed on drop.
pub struct RemoteEnv {
    /// The session's engine, id, token, Zenoh session and timeout: its controls hold them.
    control: SessionControl,
    spec: EnvSpec,
    num_envs: u32,
    stepper: Querier<'static>,
    frames: Mutex<Option<Subscriber<FifoChannelHandler<Sample>>>>,
    closed: AtomicBool,
    /// The environments' contexts as the engine last reported them: a `step_batch` reply
    /// carries only those that changed since, not one per observation.
    contexts: Mutex<KnownContexts>,
}

/// A client's copy of a batch's contexts, current as of the engine's reply `epoch` (0:
/// none held yet).
#[derive(Debug)]
struct KnownContexts {
    epoch: u64,
    /// Row-major `num_envs × context_dim`, in their wire form (little-endian `f64` bytes):
    /// an update is copied in and each row's context copied out as it is.
    bytes: Vec<u8>,
}

impl KnownContexts {
    /// Applies `update` to this copy of `envs` contexts of `context_dim` values each;
    /// leaves the copy as it was if the update does not fit it.
    fn apply(
        &mut self,
        update: &ContextUpdateView,
        envs: usize,
        context_dim: usize,
    ) -> Result<(), rmp_serde::decode::Error> {
        let fail = |what: String| Err(serde::de::Error::custom(what));
        if update.values.len() != update.envs.len() * context_dim {
            return fail(format!(
                "{} context values for {} environments of {context_dim}",
                update.values.len(),
                update.envs.len()
            ));
        }
        if update.envs.iter().any(|&i| i as usize >= envs) {
            return fail(format!(
                "a context for an environment past the batch's {envs}"
            ));
        }
        if self.epoch == 0 && update.envs.len() != envs {
            return fail(format!(
                "{} of {envs} contexts in the batch's first update",
                update.envs.len()
            ));
        }
        if update.epoch <= self.epoch {
            return fail(format!(
                "context epoch {} after {}",
                update.epoch, self.epoch
            ));
        }
        let width = 8 * context_dim;
        for (&i, context) in update
            .envs
            .iter()
            .zip(update.values.0.chunks_exact(width.max(1)))
        {
            let i = i as usize;
            self.bytes[i * width..(i + 1) * width].copy_from_slice(context);
        }
        self.epoch = update.epoch;
        Ok(())
    }
}

impl RemoteEnv {
    fn new(
        zsession: zenoh::Session,
        address: SessionAddress,
        reply: MakeReply,
        timeout: Duration,
    ) -> Result<Self, BridgeError> {
        let step_op = if reply.num_envs == 1 {
            SessionOp::Step
        } else {
            SessionOp::StepBatch
        };
        let stepper = zsession
            .declare_querier(address.key(step_op.as_str()))
            .consolidation(ConsolidationMode::None)
            .timeout(timeout)
            .wait()
            .map_err(BridgeError::zenoh("declaring the session's step querier"))?;
        let control = SessionControl::new(zsession, address, &reply.token, timeout)?;
        let contexts = KnownContexts {
            epoch: 0,
            bytes: vec![0; 8 * reply.num_envs as usize * reply.spec.context_space.dim()],
        };
        Ok(Self {
            control,
            spec: reply.spec,
            num_envs: reply.num_envs,
            stepper,
            frames: Mutex::new(None),
            closed: AtomicBool::new(false),
            contexts: Mutex::new(contexts),
        })
    }

    pub fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    pub fn engine(&self) -> &str {
        self.control.engine()
    }

    /// The `<session>` chunk of the session's keys.
    pub fn session_id(&self) -> &str {
        self.control.session_id()
    }

    /// The session's secret; whoever holds it may control the session.
    pub fn token(&self) -> &[u8] {
        self.control.token()
    }

    pub fn num_envs(&self) -> u32 {
        self.num_envs
    }

    fn call<R: DeserializeOwned>(
        &self,
        op: SessionOp,
        request: &impl Serialize,
    ) -> Result<R, BridgeError> {
        self.send(op, request)?.reply()
    }

    /// Sends `request` for `op`, its reply left to take.
    fn send(&self, op: SessionOp, request: &impl Serialize) -> Result<Pending<'_>, BridgeError> {
        send_query(
            self.control.zenoh_session(),
            &self.control.key(op.as_str()),
            encode(request),
            self.control.timeout(),
        )
    }

    /// Sends `request` through the session's step querier, its reply left to take.
    fn send_stepper(&self, request: &impl Serialize) -> Result<Pending<'_>, BridgeError> {
        let key = self.stepper.key_expr().to_string();
        Pending::send(key, encode(request), self.control.timeout(), |payload| {
            self.stepper
                .get()
                .payload(payload)
                .wait()
                .map_err(BridgeError::zenoh("sending the step query"))
        })
    }

    /// Gymnasium `reset` of a single-environment session.
    pub fn reset(
        &self,
        seed: Option<u64>,
        options: Option<ResetOptions>,
    ) -> Result<(Vec<f64>, Info), BridgeError> {
        let reply: ResetReply = self.call(SessionOp::Reset, &self.reset_request(seed, options))?;
        Ok((reply.observation.0, reply.info))
    }

    /// Gymnasium `step` of a single-environment session.
    pub fn step(&self, action: &[f64]) -> Result<StepResult, BridgeError> {
        let request = StepRequest {
            v: PROTOCOL_VERSION,
            token: self.control.token_field(),
            action: F64s(action.to_vec()),
        };
        let reply: StepReply = if self.num_envs == 1 {
            self.send_stepper(&request)?.reply()?
        } else {
            self.call(SessionOp::Step, &request)?
        };
        Ok(StepResult {
            observation: reply.observation.0,
            reward: reply.reward,
            terminated: reply.terminated,
            truncated: reply.truncated,
            info: reply.info,
            time: reply.time,
        })
    }

    /// Resets every environment; environment `i` gets its seed of `seeds`
    /// ([`BatchSeeds::of`]: `seed + i` for one seed), and the options' row `i` where they
    /// give one row per environment ([`ResetOptions::rows`]).
    pub fn reset_batch(
        &self,
        seeds: impl Into<BatchSeeds>,
        options: Option<ResetOptions>,
    ) -> Result<(Vec<f64>, InfoColumns), BridgeError> {
        Self::reset_reply(self.send_reset_batch(seeds.into(), options)?)
    }

    /// Sends [`reset_batch`](Self::reset_batch)'s request; [`reset_reply`](Self::reset_reply)
    /// takes its reply.
    pub(crate) fn send_reset_batch(
        &self,
        seeds: BatchSeeds,
        options: Option<ResetOptions>,
    ) -> Result<Pending<'_>, BridgeError> {
        let (seed, seeds) = seeds.into_request();
        let request = ResetRequest {
            seeds,
            ..self.reset_request(seed, options)
        };
        self.send(SessionOp::ResetBatch, &request)
    }

    pub(crate) fn reset_reply(
        pending: Pending<'_>,
    ) -> Result<(Vec<f64>, InfoColumns), BridgeError> {
        let reply: BatchResetReply = pending.reply()?;
        Ok((reply.observations.0, unwrap_columns(reply.info)))
    }

    /// Steps every environment with row-major `actions` (`num_envs × action_dim`).
    pub fn step_batch(&self, actions: &[f64]) -> Result<BatchStep, BridgeError> {
        let observation_dim = self.spec.observation_space.dim();
        BatchStep::written(self.num_envs as usize, observation_dim, |mut out| {
            self.step_reply_into(self.send_step_batch(actions)?, &mut out)
        })
    }

    /// Sends [`step_batch`](Self::step_batch)'s request;
    /// [`step_reply_into`](Self::step_reply_into) takes its reply. The request asks for
    /// the contexts this client does not hold yet, not for one per observation.
    pub(crate) fn send_step_batch(&self, actions: &[f64]) -> Result<Pending<'_>, BridgeError> {
        let request = BatchStepRequest {
            v: PROTOCOL_VERSION,
            token: self.control.token_field(),
            actions: F64Slice(actions),
            known_contexts: Some(self.known_contexts().epoch),
        };
        if self.num_envs == 1 {
            self.send(SessionOp::StepBatch, &request)
        } else {
            self.send_stepper(&request)
        }
    }

    /// Copies the reply to a [`send_step_batch`](Self::send_step_batch) into `out`, which
    /// holds this session's environments; returns the info columns.
    pub(crate) fn step_reply_into(
        &self,
        pending: Pending<'_>,
        out: &mut BatchStepOut<'_>,
    ) -> Result<InfoColumns, BridgeError> {
        pending.reply_with(|payload| {
            let reply: BatchStepReplyView = decode_reply(payload)?;
            let Some(update) = &reply.contexts else {
                // An engine older than context updates sends whole observations.
                return out.copy_from(&reply, None);
            };
            let mut known = self.known_contexts();
            let context_dim = self.spec.context_space.dim();
            known.apply(update, self.num_envs as usize, context_dim)?;
            out.copy_from(&reply, Some((&known.bytes, context_dim)))
        })
    }

    fn known_contexts(&self) -> MutexGuard<'_, KnownContexts> {
        self.contexts.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The expert's action for environment `index`.
    pub fn expert(&self, index: u32) -> Result<Vec<f64>, BridgeError> {
        let reply: ActionReply =
            self.call(SessionOp::Expert, &self.control.session_request(index))?;
        Ok(reply.action.0)
    }

    /// The session's controls: policy runs, pushes, context changes, telemetry.
    pub fn control(&self) -> &SessionControl {
        &self.control
    }

    /// Renders environment `index` as `height × width × 3` RGB bytes, without the trail of
    /// its episode when the session has more than one environment (their engine keeps
    /// none). The frame travels over pub/sub; the query only carries its header.
    pub fn render(&self, index: u32, width: u32, height: u32) -> Result<Vec<u8>, BridgeError> {
        let mut frames = self.frames.lock().unwrap_or_else(|p| p.into_inner());
        let first_use = frames.is_none();
        if first_use {
            let subscriber = self
                .control
                .zenoh_session()
                .declare_subscriber(self.control.key("frame"))
                .wait()
                .map_err(BridgeError::zenoh("subscribing to the session's frames"))?;
            *frames = Some(subscriber);
        }
        let subscriber = frames.as_ref().expect("declared above");
        let request = RenderRequest {
            v: PROTOCOL_VERSION,
            token: self.control.token_field(),
            index,
            width,
            height,
        };
        // A subscriber declared just now may not have reached the engine before the frame
        // was published: then ask once more.
        let attempts = if first_use { 2 } else { 1 };
        let mut lost = None;
        for _ in 0..attempts {
            let reply: RenderReply = self.call(SessionOp::Render, &request)?;
            match receive_frame(
                subscriber,
                reply.frame,
                self.control.timeout().min(Duration::from_secs(2)),
            )? {
                Some(pixels) => return Ok(pixels),
                None => lost = Some(reply.frame.id),
            }
        }
        Err(BridgeError::FrameLost {
            session: self.session_id().to_owned(),
            id: lost.unwrap_or_default(),
            timeout_ms: self.control.timeout().as_millis(),
        })
    }

    /// Closes the session on the engine. Idempotent.
    pub fn close(&self) -> Result<(), BridgeError> {
        if self.closed.swap(true, Ordering::SeqCst) {
            return Ok(());
        }
        let _: AckReply = self.call(SessionOp::Close, &self.control.session_request(0))?;
        Ok(())
    }

    fn reset_request(&self, seed: Option<u64>, options: Option<ResetOptions>) -> ResetRequest {
        ResetRequest {
            v: PROTOCOL_VERSION,
            token: self.control.token_field(),
            seed,
            seeds: None,
            options,
        }
    }
}

impl Drop for RemoteEnv {
    fn drop(&mut self) {
        // Best effort: if the engine is gone there is nothing to close.
        let _ = self.close();
    }
}

/// Waits for frame `header.id`, skipping older ones; `None` on timeout.
fn receive_frame(
    subscriber: &Subscriber<FifoChannelHandler<Sample>>,
    header: FrameHeader,
    timeout: Duration,
) -> Result<Option<Vec<u8>>, BridgeError> {
    let deadline = Instant::now() + timeout;
    while let Some(sample) = subscriber
        .recv_deadline(deadline)
        .map_err(BridgeError::zenoh("receiving a frame"))?
    {
        let Some(attachment) = sample.attachment() else {
            continue;
        };
        let Ok(got) = decode_reply::<FrameHeader>(&attachment.to_bytes()) else {
            continue;
        };
        if got == header {
            return Ok(Some(sample.payload().to_bytes().into_owned()));
        }
    }
    Ok(None)
}

fn unwrap_columns(columns: BTreeMap<String, F64s>) -> InfoColumns {
    columns.into_iter().map(|(k, v)| (k, v.0)).collect()
}

#[cfg(test)]
mod tests {
    use serde_bytes::ByteBuf;

    use super::*;
    use crate::protocol::{BatchStepReply, ContextUpdate};

    /// A reply of two environments with two observations each.
    fn reply() -> Vec<u8> {
        encode(&BatchStepReply {
            v: PROTOCOL_VERSION,
            observations: F64s(vec![1.0, -2.0, f64::from_bits(0x7ff8_dead_beef_0001), -0.0]),
            rewards: F64s(vec![0.5, 1e-300]),
            terminated: ByteBuf::from(vec![1, 0]),
            truncated: ByteBuf::from(vec![0, 1]),
            info: [("distance".to_owned(), F64s(vec![3.0, f64::NAN]))].into(),
            contexts: None,
        })
    }

    /// Copies `payload` into buffers for `envs` environments of two observations; the
    /// copy's error as its message.
    fn copied(payload: &[u8], envs: usize) -> Result<BatchStep, String> {
        let mut refused = None;
        let step = BatchStep::written(envs, 2, |mut out| {
            out.copy_from(&decode_reply(payload).expect("a reply"), None)
                .map_err(|error| {
                    refused = Some(error.to_string());
                    BridgeError::InvalidArgument("refused".into())
                })
        });
        step.map_err(|_| refused.expect("the copy's error"))
    }

    #[test]
    fn a_reply_read_in_place_holds_what_the_owned_decoding_does() {
        let payload = reply();
        let owned: BatchStepReply = decode_reply(&payload).unwrap();
        let step = copied(&payload, 2).expect("a reply of the batch's size");
        let bits = |v: &[f64]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&step.observations), bits(&owned.observations.0));
        assert_eq!(bits(&step.rewards), bits(&owned.rewards.0));
        assert_eq!(step.terminated, [true, false]);
        assert_eq!(step.truncated, [false, true]);
        assert_eq!(
            bits(&step.info["distance"]),
            bits(&owned.info["distance"].0)
        );
    }

    #[test]
    fn a_reply_of_another_size_than_the_batch_is_an_error() {
        let payload = reply();
        for envs in [1, 3] {
            let error = copied(&payload, envs).unwrap_err();
            assert!(
                error.contains("bytes of observations where the batch takes"),
                "{envs}: {error}"
            );
        }
        let mut short_info: BatchStepReply = decode_reply(&payload).unwrap();
        short_info.info.insert("time".into(), F64s(vec![1.0]));
        let error = copied(&encode(&short_info), 2).unwrap_err();
        assert!(
            error.contains("1 values of info `time` for 2 environments"),
            "{error}"
        );
    }

    /// `update` applied to `known` (two environments, one context value each) as its
    /// encoded form, the error as its message.
    fn apply(known: &mut KnownContexts, update: &ContextUpdate) -> Result<(), String> {
        let bytes = encode(update);
        let view: ContextUpdateView = rmp_serde::from_slice(&bytes).unwrap();
        known.apply(&view, 2, 1).map_err(|e| e.to_string())
    }

    fn update(epoch: u64, envs: Vec<u32>, values: Vec<f64>) -> ContextUpdate {
        ContextUpdate {
            epoch,
            envs,
            values: F64s(values),
        }
    }

    #[test]
    fn context_updates_that_do_not_fit_the_copy_are_refused_and_leave_it_as_it_was() {
        let mut known = KnownContexts {
            epoch: 0,
            bytes: vec![0; 16],
        };
        let values = |known: &KnownContexts| F64s::from_le_bytes(&known.bytes).unwrap();
        for (bad, why) in [
            (
                update(1, vec![0], vec![1.0]),
                "1 of 2 contexts in the batch's first update",
            ),
            (
                update(1, vec![0, 1], vec![1.0]),
                "1 context values for 2 environments",
            ),
            (update(1, vec![0, 2], vec![1.0, 2.0]), "past the batch's 2"),
        ] {
            let error = apply(&mut known, &bad).unwrap_err();
            assert!(error.contains(why), "{error}");
            assert_eq!((known.epoch, values(&known)), (0, vec![0.0, 0.0]));
        }
        apply(&mut known, &update(3, vec![0, 1], vec![1.0, 2.0])).unwrap();
        apply(&mut known, &update(4, vec![1], vec![-2.0])).unwrap();
        assert_eq!((known.epoch, values(&known)), (4, vec![1.0, -2.0]));
        let error = apply(&mut known, &update(4, vec![], vec![])).unwrap_err();
        assert!(error.contains("context epoch 4 after 4"), "{error}");
    }

    #[test]
    fn rows_are_rebuilt_from_states_and_the_known_contexts() {
        let states = BatchStepReply {
            observations: F64s(vec![1.0, 2.0, 3.0, 4.0]),
            contexts: Some(update(1, vec![], vec![])),
            ..decode_reply(&reply()).unwrap()
        };
        let payload = encode(&states);
        let step = BatchStep::written(2, 3, |mut out| {
            let view = decode_reply(&payload).expect("a reply");
            out.copy_from(&view, Some((&F64s::le_bytes(&[-1.0, -2.0]), 1)))
                .map_err(|e| BridgeError::InvalidArgument(e.to_string()))
        })
        .unwrap();
        assert_eq!(step.observations, [1.0, 2.0, -1.0, 3.0, 4.0, -2.0]);
        // States of another width than the observations less the contexts.
        let error = BatchStep::written(2, 4, |mut out| {
            let view = decode_reply(&payload).expect("a reply");
            out.copy_from(&view, Some((&F64s::le_bytes(&[-1.0, -2.0]), 1)))
                .map_err(|e| BridgeError::InvalidArgument(e.to_string()))
        })
        .unwrap_err();
        assert!(error.to_string().contains("bytes of states"), "{error}");
    }
}
