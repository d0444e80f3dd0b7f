//! The engine: hosts environment sessions and answers the protocol's queries.
//!
//! One queryable on `ciflow/v1/engine/<engine>/**` receives every request. Cheap,
//! non-blocking operations (step, reset, expert, …) are answered directly in Zenoh's
//! callback, so a step costs one network round trip and nothing more; `make` (which may
//! have to ask Zenoh whether the client is alive) and `render` (which publishes a large
//! frame) go to a worker thread. Every request gets exactly one reply; a panic in a task
//! is caught, answered with `internal`, and closes only that session.

mod driver;
mod hot_load;
mod policy_table;
mod session;
mod slot;
mod telemetry;

use std::collections::{HashMap, HashSet};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, RwLock};
use std::time::Duration;

use ciflow_envs::EnvError;
use ciflow_envs::registry::Kwargs;
use zenoh::Wait;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
use zenoh::query::{Query, Queryable};
use zenoh::sample::SampleKind;

use self::driver::Driver;
use self::hot_load::hot_load;
pub(crate) use self::policy_table::PolicyTable;
use self::session::Session;
use self::slot::EnvSlot;
use self::telemetry::TelemetryPublisher;
use crate::config::{NetworkOptions, Role};
use crate::error::{BridgeError, full_message};
use crate::policy::Policy;
use crate::protocol::keys::{self, Route, SessionOp};
use crate::protocol::{
    AckReply, ActRequest, ActionReply, BatchStepRequest, ContextRequest, ErrorCode, ErrorReply,
    F64s, MakeReply, MakeRequest, PROTOCOL_VERSION, PerturbRequest, RenderReply, RenderRequest,
    ResetRequest, RunRequest, SessionRequest, StepRequest, TaskInfo, TasksReply, TasksRequest,
    decode_request, encode,
};
use crate::task_factory::TaskFactory;

/// Most environments one session may hold.
pub const MAX_ENVS_PER_SESSION: u32 = 1 << 20;

/// How long `make` waits for Zenoh to confirm a client's liveliness token.
const LIVELINESS_TIMEOUT: Duration = Duration::from_secs(2);

/// What an engine serves and how.
#[derive(Clone)]
pub struct ServerOptions {
    /// The `<engine>` chunk of its keys; default: the Zenoh session id.
    pub name: Option<String>,
    /// Upper bound on telemetry samples per second per session.
    pub telemetry_hz: f64,
    pub tasks: Vec<TaskFactory>,
    pub policies: Vec<Arc<dyn Policy>>,
}

impl Default for ServerOptions {
    fn default() -> Self {
        Self {
            name: None,
            telemetry_hz: 60.0,
            tasks: TaskFactory::registry(),
            policies: Vec::new(),
        }
    }
}

/// A running engine. Dropping it withdraws its liveliness token and queryable and closes
/// every session.
pub struct EngineServer {
    shared: Arc<Shared>,
    _queryable: Queryable<()>,
    _clients: Subscriber<()>,
    _checkpoints: Subscriber<()>,
    _token: LivelinessToken,
}

impl EngineServer {
    /// Opens a Zenoh session for an engine (listening on the default endpoint unless
    /// `network` says otherwise) and starts serving.
    pub fn open(network: &NetworkOptions, options: ServerOptions) -> Result<Self, BridgeError> {
        let session = network.open(
            Role::Engine,
            "open the engine's Zenoh session",
            "is another engine already listening on that endpoint?",
        )?;
        Self::start(session, options)
    }

    /// Starts serving on an open Zenoh session.
    pub fn start(zsession: zenoh::Session, options: ServerOptions) -> Result<Self, BridgeError> {
        let name = options
            .name
            .clone()
            .unwrap_or_else(|| zsession.zid().to_string());
        if !keys::is_plain_chunk(&name) {
            return Err(BridgeError::InvalidArgument(format!(
                "engine name `{name}` must be letters, digits, `-`, `_` or `.`"
            )));
        }
        let tasks = options
            .tasks
            .iter()
            .map(|factory| {
                let env =
                    (factory.make)(&Kwargs::new()).map_err(|source| BridgeError::TaskDefaults {
                        task: factory.id.clone(),
                        source,
                    })?;
                Ok(TaskInfo {
                    name: factory.name.clone(),
                    spec: env.spec().clone(),
                })
            })
            .collect::<Result<_, BridgeError>>()?;
        let policies = Arc::new(PolicyTable::default());
        for policy in &options.policies {
            policies.insert(Arc::clone(policy));
        }
        let shared = Arc::new(Shared {
            zsession: zsession.clone(),
            name,
            task_infos: tasks,
            factories: options.tasks,
            policies,
            telemetry_hz: options.telemetry_hz,
            sessions: RwLock::new(HashMap::new()),
            live_clients: Mutex::new(HashSet::new()),
        });

        let clients = {
            let shared = Arc::clone(&shared);
            zsession
                .liveliness()
                .declare_subscriber(keys::ALL_CLIENTS_ALIVE)
                .history(true)
                .callback(move |sample| {
                    let client = sample.key_expr().as_str().rsplit('/').next().unwrap_or("");
                    match sample.kind() {
                        SampleKind::Put => shared.client_appeared(client),
                        SampleKind::Delete => shared.client_vanished(client),
                    }
                })
                .wait()
                .map_err(BridgeError::zenoh(
                    "declaring the subscriber to client tokens",
                ))?
        };

        let checkpoints = {
            let shared = Arc::clone(&shared);
            zsession
                .declare_subscriber(keys::ALL_POLICY_CHECKPOINTS)
                .callback(move |sample| {
                    let key = sample.key_expr().as_str();
                    match hot_load(
                        &shared.policies,
                        &shared.factories,
                        key,
                        &sample.payload().to_bytes(),
                    ) {
                        Ok(info) => eprintln!(
                            "ciflow engine `{}`: serving policy `{}` for {} (epoch {}, \
                             validation NLL {:.4})",
                            shared.name,
                            info.name,
                            info.task,
                            info.epoch.unwrap_or(0),
                            info.validation_nll.unwrap_or(f64::NAN)
                        ),
                        // A bad publication must not disturb serving: report and go on.
                        Err(error) => eprintln!(
                            "ciflow engine `{}`: ignored checkpoint on `{key}`: {}",
                            shared.name,
                            full_message(&error)
                        ),
                    }
                })
                .wait()
                .map_err(BridgeError::zenoh(
                    "declaring the subscriber to checkpoint publications",
                ))?
        };

        let (slow_tx, slow_rx) = mpsc::channel::<Query>();
        {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name(format!("ciflow-engine-{}", shared.name))
                .spawn(move || {
                    for query in slow_rx {
                        shared.answer(&query);
                    }
                })
                .map_err(BridgeError::Worker)?;
        }
        let queryable = {
            let shared = Arc::clone(&shared);
            let slow_tx = Mutex::new(slow_tx);
            zsession
                .declare_queryable(format!("{}/**", keys::engine(&shared.name)))
                .callback(move |query| {
                    let needs_worker = matches!(
                        keys::parse_route(query.key_expr().as_str()),
                        Some(Route::Make)
                            | Some(Route::Session {
                                op: SessionOp::Render,
                                ..
                            })
                    );
                    if needs_worker {
                        let sent = slow_tx
                            .lock()
                            .unwrap_or_else(|poisoned| poisoned.into_inner())
                            .send(query);
                        if let Err(mpsc::SendError(query)) = sent {
                            shared.answer(&query);
                        }
                    } else {
                        shared.answer(&query);
                    }
                })
                .wait()
                .map_err(BridgeError::zenoh("declaring the engine's queryable"))?
        };
        let token = zsession
            .liveliness()
            .declare_token(keys::engine_alive(&shared.name))
            .wait()
            .map_err(BridgeError::zenoh(
                "declaring the engine's liveliness token",
            ))?;
        Ok(Self {
            shared,
            _queryable: queryable,
            _clients: clients,
            _checkpoints: checkpoints,
            _token: token,
        })
    }

    /// The `<engine>` chunk of this engine's keys.
    pub fn name(&self) -> &str {
        &self.shared.name
    }

    /// The Zenoh session it serves on (clients in the same process may share it).
    pub fn zenoh_session(&self) -> &zenoh::Session {
        &self.shared.zsession
    }

    /// Number of open sessions (for tests and monitoring).
    pub fn session_count(&self) -> usize {
        self.shared.read_sessions().len()
    }
}

impl Drop for EngineServer {
    fn drop(&mut self) {
        self.shared.sessions_mut().clear();
    }
}

struct Shared {
    zsession: zenoh::Session,
    name: String,
    task_infos: Vec<TaskInfo>,
    factories: Vec<TaskFactory>,
    policies: Arc<PolicyTable>,
    telemetry_hz: f64,
    sessions: RwLock<HashMap<String, Arc<Mutex<Session>>>>,
    live_clients: Mutex<HashSet<String>>,
}

type Answer = Result<Vec<u8>, ErrorReply>;

impl Shared {
    fn read_sessions(
        &self,
    ) -> std::sync::RwLockReadGuard<'_, HashMap<String, Arc<Mutex<Session>>>> {
        self.sessions.read().unwrap_or_else(|p| p.into_inner())
    }

    fn sessions_mut(
        &self,
    ) -> std::sync::RwLockWriteGuard<'_, HashMap<String, Arc<Mutex<Session>>>> {
        self.sessions.write().unwrap_or_else(|p| p.into_inner())
    }

    fn live_clients(&self) -> std::sync::MutexGuard<'_, HashSet<String>> {
        self.live_clients.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn client_appeared(&self, client: &str) {
        self.live_clients().insert(client.to_owned());
    }

    /// Closes every session of a client whose liveliness token went away.
    fn client_vanished(&self, client: &str) {
        self.live_clients().remove(client);
        self.sessions_mut()
            .retain(|_, session| match session.lock() {
                Ok(session) => session.owner != client,
                Err(_) => false,
            });
    }

    /// Answers one query with exactly one reply.
    fn answer(&self, query: &Query) {
        let key = query.key_expr().as_str();
        let route = keys::parse_route(key);
        let payload = query.payload().map(|p| p.to_bytes()).unwrap_or_default();
        let answer = catch_unwind(AssertUnwindSafe(|| self.handle(route, &payload, query)))
            .unwrap_or_else(|_| {
                if let Some(Route::Session { session, .. }) = route {
                    self.sessions_mut().remove(session);
                }
                Err(ErrorReply::new(
                    ErrorCode::Internal,
                    "the engine hit a bug while serving this request; the session was closed",
                ))
            });
        // A failed reply means the querier is gone; there is nobody left to tell.
        let _ = match answer {
            // `tasks` may be asked with a wildcard key: answer with this engine's own key.
            Ok(bytes) if route == Some(Route::Tasks) => {
                query.reply(keys::tasks(&self.name), bytes).wait()
            }
            Ok(bytes) => query.reply(query.key_expr().clone(), bytes).wait(),
            Err(error) => query.reply_err(encode(&error)).wait(),
        };
    }

    fn handle(&self, route: Option<Route<'_>>, payload: &[u8], query: &Query) -> Answer {
        match route {
            None => Err(ErrorReply::new(
                ErrorCode::UnknownOperation,
                format!(
                    "`{}` is not an operation of protocol v{PROTOCOL_VERSION}",
                    query.key_expr()
                ),
            )),
            Some(Route::Tasks) => {
                decode_request::<TasksRequest>(payload)?;
                Ok(encode(&TasksReply {
                    v: PROTOCOL_VERSION,
                    engine: self.name.clone(),
                    tasks: self.task_infos.clone(),
                    policies: self.policies.infos(),
                }))
            }
            Some(Route::Make) => self.make(decode_request(payload)?),
            Some(Route::Ping) => Ok(payload.to_vec()),
            Some(Route::Session { session, op }) => self.session_op(session, op, payload),
            Some(Route::PolicyAct { policy }) => self.act(policy, decode_request(payload)?),
        }
    }

    fn make(&self, request: MakeRequest) -> Answer {
        if !keys::is_plain_chunk(&request.client) {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!(
                    "client name `{}` must be letters, digits, `-`, `_` or `.`",
                    request.client
                ),
            ));
        }
        let factory = self
            .factories
            .iter()
            .find(|f| f.id == request.task || f.name == request.task)
            .ok_or_else(|| {
                ErrorReply::new(
                    ErrorCode::UnknownTask,
                    format!(
                        "unknown task `{}`; this engine has: {}",
                        request.task,
                        self.factories
                            .iter()
                            .map(|f| f.id.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })?;
        if request.num_envs == 0 || request.num_envs > MAX_ENVS_PER_SESSION {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!(
                    "num_envs {} outside 1..={MAX_ENVS_PER_SESSION}",
                    request.num_envs
                ),
            ));
        }
        if !self.confirm_alive(&request.client) {
            return Err(ErrorReply::new(
                ErrorCode::NoLiveliness,
                format!(
                    "client `{0}` has no liveliness token; declare `{1}` before `make`",
                    request.client,
                    keys::client_alive(&request.client)
                ),
            ));
        }
        let envs: Vec<EnvSlot> = (0..request.num_envs)
            .map(|_| (factory.make)(&request.kwargs).map(EnvSlot::new))
            .collect::<Result<_, EnvError>>()?;
        let spec = envs[0].env.spec().clone();
        let id = format!("{:016x}", rand::random::<u64>());
        let token: session::Token = rand::random();
        let telemetry = TelemetryPublisher::declare(
            &self.zsession,
            keys::session(&self.name, &id, "telemetry"),
            self.telemetry_hz,
        )
        .map_err(|e| ErrorReply::new(ErrorCode::Internal, full_message(&e)))?;
        let session = Session::new(id.clone(), request.client.clone(), token, envs, telemetry);
        self.sessions_mut()
            .insert(id.clone(), Arc::new(Mutex::new(session)));
        // The client may have vanished while we built the session: then nobody would
        // ever close it.
        if !self.live_clients().contains(&request.client) {
            self.sessions_mut().remove(&id);
            return Err(ErrorReply::new(
                ErrorCode::NoLiveliness,
                format!("client `{}` vanished during `make`", request.client),
            ));
        }
        Ok(encode(&MakeReply {
            v: PROTOCOL_VERSION,
            session: id,
            token: serde_bytes::ByteBuf::from(token.to_vec()),
            num_envs: request.num_envs,
            spec,
        }))
    }

    /// Whether `client` holds its liveliness token, asking Zenoh if the subscriber has not
    /// seen it yet. Runs on the worker thread: it may block for a round trip.
    fn confirm_alive(&self, client: &str) -> bool {
        if self.live_clients().contains(client) {
            return true;
        }
        let Ok(replies) = self
            .zsession
            .liveliness()
            .get(keys::client_alive(client))
            .timeout(LIVELINESS_TIMEOUT)
            .wait()
        else {
            return false;
        };
        let alive = replies.iter().any(|reply| reply.result().is_ok());
        if alive {
            self.client_appeared(client);
        }
        alive
    }

    fn session_op(&self, id: &str, op: SessionOp, payload: &[u8]) -> Answer {
        let handle = self.read_sessions().get(id).cloned().ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::UnknownSession,
                format!(
                    "no session `{id}` on engine `{}` (closed, reclaimed or never made)",
                    self.name
                ),
            )
        })?;
        let Ok(mut session) = handle.lock() else {
            self.sessions_mut().remove(id);
            return Err(ErrorReply::new(
                ErrorCode::Internal,
                format!("session `{id}` was closed after an internal error"),
            ));
        };
        match op {
            SessionOp::Reset => {
                let request: ResetRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.ensure_idle(op.as_str())?;
                session.reset(request)
            }
            SessionOp::Step => {
                let request: StepRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.ensure_idle(op.as_str())?;
                session.step(&request.action.0)
            }
            SessionOp::ResetBatch => {
                let request: ResetRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.ensure_idle(op.as_str())?;
                session.reset_batch(request)
            }
            SessionOp::StepBatch => {
                let request: BatchStepRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.ensure_idle(op.as_str())?;
                session.step_batch(&request.actions.0)
            }
            SessionOp::Run => {
                let request: RunRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                let policy = self.policy(&request.policy)?;
                let run = session.start_run(&request, policy.as_ref())?;
                let time = session.time();
                let driver = Driver {
                    session: Arc::downgrade(&handle),
                    policies: Arc::clone(&self.policies),
                    run,
                    speed: request.speed,
                    steps: request.steps,
                    control_dt: session.control_dt(),
                    action_dim: policy.info().action_dim as usize,
                };
                if let Err(e) = driver.spawn() {
                    session.stop_run()?;
                    return Err(ErrorReply::new(
                        ErrorCode::Internal,
                        format!("cannot start the policy driver: {e}"),
                    ));
                }
                Ok(encode(&AckReply {
                    v: PROTOCOL_VERSION,
                    time,
                }))
            }
            SessionOp::Stop => {
                let request: SessionRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.stop_run()
            }
            SessionOp::Expert => {
                let request: SessionRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.expert(request.index)
            }
            SessionOp::Context => {
                let request: ContextRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.set_context(&request)
            }
            SessionOp::Perturb => {
                let request: PerturbRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.perturb(request)
            }
            SessionOp::Render => {
                let request: RenderRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                let (frame, pixels) =
                    session.render(request.index, request.width, request.height)?;
                self.zsession
                    .put(keys::session(&self.name, id, "frame"), pixels)
                    .attachment(encode(&frame))
                    .congestion_control(CongestionControl::Block)
                    .wait()
                    .map_err(|e| {
                        ErrorReply::new(
                            ErrorCode::Internal,
                            format!("publishing the frame failed: {e}"),
                        )
                    })?;
                Ok(encode(&RenderReply {
                    v: PROTOCOL_VERSION,
                    frame,
                }))
            }
            SessionOp::Close => {
                let request: SessionRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                let time = session.time();
                drop(session);
                self.sessions_mut().remove(id);
                Ok(encode(&AckReply {
                    v: PROTOCOL_VERSION,
                    time,
                }))
            }
        }
    }

    fn policy(&self, name: &str) -> Result<Arc<dyn Policy>, ErrorReply> {
        self.policies.get(name).ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::UnknownPolicy,
                format!(
                    "no policy `{name}`; this engine has: {}",
                    self.policies.names().join(", ")
                ),
            )
        })
    }

    fn act(&self, name: &str, request: ActRequest) -> Answer {
        let policy = self.policy(name)?;
        let info = policy.info();
        let observation_dim = info.observation_dim as usize;
        let observations = &request.observations.0;
        if observation_dim == 0
            || observations.is_empty()
            || !observations.len().is_multiple_of(observation_dim)
        {
            return Err(ErrorReply::new(
                ErrorCode::WrongDimension,
                format!(
                    "observations has {} elements, expected a positive multiple of {observation_dim}",
                    observations.len()
                ),
            ));
        }
        if observations.iter().any(|v| !v.is_finite()) {
            return Err(ErrorReply::new(
                ErrorCode::NotFinite,
                "observations contain NaN or inf",
            ));
        }
        let action_dim = info.action_dim as usize;
        let mut actions = vec![0.0; observations.len() / observation_dim * action_dim];
        for (observation, action) in observations
            .chunks_exact(observation_dim)
            .zip(actions.chunks_exact_mut(action_dim))
        {
            policy
                .act_into(observation, action)
                .map_err(|e| ErrorReply::new(ErrorCode::Policy, full_message(&e)))?;
        }
        Ok(encode(&ActionReply {
            v: PROTOCOL_VERSION,
            action: F64s(actions),
        }))
    }
}
