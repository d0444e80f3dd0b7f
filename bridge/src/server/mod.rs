//! The engine: hosts environment sessions and answers the protocol's queries.
//!
//! One queryable on `ciflow/v2/engine/<engine>/**` receives every request. Cheap
//! operations of bounded cost (step, reset, expert, a small batch or `act`, …) are
//! answered directly in Zenoh's callback, so a step costs one network round trip and
//! nothing more. Everything whose cost grows with its payload or may wait (`make`,
//! `render`, `reset_batch`, `evaluate`, `stability`, large `step_batch` and `act`) goes to a
//! pool of worker threads (`workers.rs`): Zenoh's own threads must never be held for long,
//! or the links they serve miss their lease and Zenoh drops them, with every session of
//! their clients.
//!
//! Every request is answered within its time budget ([`crate::limits`]) and inside the
//! engine's bounds, or refused with a typed error that leaves nothing allocated. Every
//! request gets exactly one reply; a panic in a task is caught, answered with `internal`,
//! and closes only that session.

mod driver;
mod hot_load;
mod policy_table;
mod reply_memory;
mod reported_contexts;
mod session;
mod slot;
mod telemetry;
mod usage;
mod while_running;
mod workers;

use std::collections::HashMap;
use std::ops::Range;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::AtomicU32;
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant};

use ciflow_envs::actor::Model;
use ciflow_envs::registry::Kwargs;
use ciflow_evaluation::stability::StabilityConfig;
use ciflow_evaluation::{Acting, EpisodeBatch, run_episodes};
use rayon::prelude::*;
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
use zenoh::query::{Query, Queryable};
use zenoh::sample::SampleKind;

use self::driver::{Driver, Schedulers};
use self::hot_load::{RefusalLog, hot_load};
pub(crate) use self::policy_table::PolicyTable;
use self::reply_memory::ReplyMemory;
use self::session::{RunPermit, Session};
use self::slot::EnvSlot;
use self::telemetry::TelemetryWatch;
use self::usage::{ClientTable, Reservation};
use self::while_running::WhileRunning;
use self::workers::Workers;
use crate::config::{NetworkOptions, Role};
use crate::error::{BridgeError, check_name, full_message};
use crate::limits::{Deadline, Limits};
use crate::policy::Policy;
use crate::protocol::keys::{self, Route, SessionOp};
use crate::protocol::{
    AckReply, ActRequest, ActionReply, BatchStepRequest, ContextRequest, ErrorCode, ErrorReply,
    EvaluateReply, EvaluateRequest, F64s, LimitsReply, LimitsRequest, MakeReply, MakeRequest,
    PROTOCOL_VERSION, PerturbRequest, RenderReply, RenderRequest, ResetRequest, RunRequest,
    SessionRequest, StabilityReply, StabilityRequest, StepRequest, TaskInfo, TasksReply,
    TasksRequest, decode_request, encode, requested_deadline,
};
use crate::retry::retry_within;
use crate::signing::TrustedKeys;
use crate::task_factory::TaskFactory;

/// Payloads up to this size of `step_batch` and `act` are served in Zenoh's callback:
/// 512 two-dimensional actions, well under a millisecond of work.
const INLINE_BYTES: usize = 8 << 10;

/// Environments built, or observations evaluated, between two looks at the deadline.
const DEADLINE_CHUNK: usize = 256;

/// How long `make` waits for Zenoh to confirm a client's liveliness token.
const LIVELINESS_TIMEOUT: Duration = Duration::from_secs(2);

/// How long a client whose liveliness token is not found is looked for again before it
/// counts as absent: before its `make` is refused ([`Shared::confirm_alive`]) and before
/// its sessions are reclaimed after its token was deleted ([`Shared::client_token_deleted`]).
const LIVELINESS_SETTLE: Duration = Duration::from_secs(1);

/// What an engine serves and how.
#[derive(Clone)]
pub struct ServerOptions {
    /// The `<engine>` chunk of its keys; default: the Zenoh session id.
    pub name: Option<String>,
    /// Upper bound on telemetry samples per second per session.
    pub telemetry_hz: f64,
    pub tasks: Vec<TaskFactory>,
    pub policies: Vec<Arc<dyn Policy>>,
    pub limits: Limits,
    /// Keys whose signature a published checkpoint needs to be hot-loaded; `None` loads
    /// unsigned publications too (the zero-configuration default).
    pub trusted_keys: Option<TrustedKeys>,
}

impl Default for ServerOptions {
    fn default() -> Self {
        Self {
            name: None,
            telemetry_hz: 60.0,
            tasks: TaskFactory::registry(),
            policies: Vec::new(),
            limits: Limits::DEFAULT,
            trusted_keys: None,
        }
    }
}

/// A running engine. Dropping it closes every session, withdraws its queryable,
/// subscribers and liveliness token, lets its workers answer the requests they hold and
/// its callbacks end (up to 5 s), and closes its Zenoh session before the drop returns.
pub struct EngineServer {
    shared: Arc<Shared>,
    /// The state as the threads that confirm a client vanished see it.
    while_running: Arc<WhileRunning<Shared>>,
    /// Each `None` once withdrawn, as the engine is dropped.
    queryable: Option<Queryable<()>>,
    clients: Option<Subscriber<()>>,
    checkpoints: Option<Subscriber<()>>,
    _token: LivelinessToken,
    joined: bool,
}

impl EngineServer {
    /// Opens a Zenoh session for an engine (listening on the default endpoint unless
    /// `network` says otherwise) and starts serving. With no network options and the
    /// default endpoint already taken (another engine on this machine), it joins that
    /// one instead ([`NetworkOptions::joining_default`]): its clients reach both.
    /// [`EngineServer::joined`] tells which happened.
    pub fn open(network: &NetworkOptions, options: ServerOptions) -> Result<Self, BridgeError> {
        let open = |network: &NetworkOptions| {
            network.open(
                Role::Engine,
                "open the engine's Zenoh session",
                "is another engine already listening on that endpoint?",
            )
        };
        let (session, joined) = match open(network) {
            Ok(session) => (session, false),
            Err(error) if network.is_default() => match open(&network.joining_default()) {
                Ok(session) => (session, true),
                Err(_) => return Err(error),
            },
            Err(error) => return Err(error),
        };
        let mut server = Self::start(session, options)?;
        server.joined = joined;
        Ok(server)
    }

    /// Whether [`EngineServer::open`] found the default endpoint taken and joined the
    /// engine there instead of listening on it.
    pub fn joined(&self) -> bool {
        self.joined
    }

    /// Starts serving on an open Zenoh session.
    pub fn start(zsession: zenoh::Session, options: ServerOptions) -> Result<Self, BridgeError> {
        let name = options
            .name
            .clone()
            .unwrap_or_else(|| zsession.zid().to_string());
        check_name("engine name", &name)?;
        options.limits.check()?;
        // The table keeps one policy per name: a second would silently replace the first.
        let mut policy_names = std::collections::BTreeSet::new();
        if let Some(twice) = options
            .policies
            .iter()
            .map(|policy| policy.info().name)
            .find(|policy_name| !policy_names.insert(policy_name.clone()))
        {
            return Err(BridgeError::InvalidArgument(format!(
                "two policies are named `{twice}`; an engine serves each under its own name \
                 (`ciflow serve --policy NAME=DIR`)"
            )));
        }
        if !(options.telemetry_hz.is_finite() && options.telemetry_hz > 0.0) {
            return Err(BridgeError::InvalidArgument(format!(
                "the telemetry rate must be a positive number of samples per second, not {}",
                options.telemetry_hz
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
        let telemetry = TelemetryWatch::declare(&zsession, &name, options.telemetry_hz)?;
        let schedulers = Schedulers::spawn(&name).map_err(BridgeError::Worker)?;
        let shared = Arc::new(Shared {
            zsession: zsession.clone(),
            name,
            task_infos: tasks,
            factories: options.tasks,
            policies,
            trusted_keys: options.trusted_keys,
            refusals: RefusalLog::default(),
            telemetry,
            limits: options.limits,
            sessions: RwLock::new(HashMap::new()),
            clients: ClientTable::default(),
            runs: Arc::new(AtomicU32::new(0)),
            schedulers,
            reply_memory: ReplyMemory::new(&zsession),
        });

        let while_running = Arc::new(WhileRunning::new(&shared));
        let clients = {
            let (shared, while_running) = (Arc::clone(&shared), Arc::clone(&while_running));
            zsession
                .liveliness()
                .declare_subscriber(keys::ALL_CLIENTS_ALIVE)
                .history(true)
                .callback(move |sample| {
                    let Some(client) = keys::parse_client_alive(sample.key_expr().as_str()) else {
                        return;
                    };
                    match sample.kind() {
                        SampleKind::Put => shared.client_appeared(client),
                        SampleKind::Delete => shared.client_token_deleted(&while_running, client),
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
                        shared.trusted_keys.as_ref(),
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
                        // A bad publication must not disturb serving: report (at most once
                        // a minute for each key and kind) and go on.
                        Err(error) => {
                            if let Some(suppressed) =
                                shared.refusals.admit(key, error.kind(), Instant::now())
                            {
                                let more = match suppressed {
                                    0 => String::new(),
                                    n => format!(" ({n} more like it since the last report)"),
                                };
                                eprintln!(
                                    "ciflow engine `{}`: ignored checkpoint on `{key}`: {}{more}",
                                    shared.name,
                                    full_message(&error)
                                );
                            }
                        }
                    }
                })
                .wait()
                .map_err(BridgeError::zenoh(
                    "declaring the subscriber to checkpoint publications",
                ))?
        };

        let workers = {
            let shared = Arc::clone(&shared);
            let name = shared.name.clone();
            Workers::spawn(&name, move |(query, received): (Query, Instant)| {
                let route = keys::parse_route(query.key_expr().as_str());
                shared.answer(&query, route, received)
            })
            .map_err(BridgeError::Worker)?
        };
        let queryable = {
            let shared = Arc::clone(&shared);
            zsession
                .declare_queryable(format!("{}/**", keys::engine(&shared.name)))
                .callback(move |query| {
                    let received = Instant::now();
                    let route = keys::parse_route(query.key_expr().as_str());
                    if runs_inline(route, &query) {
                        shared.answer(&query, route, received);
                    } else if let Err((query, _)) = workers.submit((query, received)) {
                        shared.reply(
                            &query,
                            None,
                            Err(ErrorReply::new(
                                ErrorCode::LimitExceeded,
                                "the engine's work queue is full; retry later",
                            )),
                        );
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
            while_running,
            queryable: Some(queryable),
            clients: Some(clients),
            checkpoints: Some(checkpoints),
            _token: token,
            joined: false,
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

    /// The bounds this engine enforces.
    pub fn limits(&self) -> Limits {
        self.shared.limits
    }
}

/// Whether a query on `route` is cheap enough to answer in Zenoh's callback (see the
/// module doc).
fn runs_inline(route: Option<Route<'_>>, query: &Query) -> bool {
    let small = || query.payload().is_none_or(|p| p.len() <= INLINE_BYTES);
    match route {
        Some(Route::Make { .. } | Route::PolicyEvaluate { .. } | Route::PolicyStability { .. }) => {
            false
        }
        Some(Route::PolicyAct { .. }) => small(),
        Some(Route::Session { op, .. }) => match op {
            SessionOp::Render | SessionOp::ResetBatch => false,
            SessionOp::StepBatch => small(),
            _ => true,
        },
        _ => true,
    }
}

/// How long a dropped engine waits for its workers and callbacks to end.
const STOP_WITHIN: Duration = Duration::from_secs(5);

impl Drop for EngineServer {
    fn drop(&mut self) {
        // First, so that no thread confirming a vanished client takes the state again
        // (`while_running.rs`); it waits for a liveliness query in progress.
        self.while_running.stop();
        self.shared.sessions_mut().clear();
        // Withdrawing the queryable drops the workers' queue, and the workers end once
        // they have answered what they hold. The workers and any callback Zenoh is still
        // running hold the state, Zenoh session included: waiting until the engine holds
        // it alone means the session closes here. Otherwise the last of them closed it a
        // moment later, and if the program was exiting meanwhile, Zenoh's statics were
        // gone (a panic at exit, seen in the tests).
        if let Some(queryable) = self.queryable.take() {
            let _ = queryable.undeclare().wait();
        }
        for subscriber in [self.clients.take(), self.checkpoints.take()]
            .into_iter()
            .flatten()
        {
            let _ = subscriber.undeclare().wait();
        }
        let holders = || Arc::strong_count(&self.shared);
        if retry_within(STOP_WITHIN, holders, |&holders| holders > 1) > 1 {
            eprintln!(
                "ciflow engine `{}`: requests or callbacks still running {} s after the \
                 engine was stopped; its Zenoh session closes when they end",
                self.shared.name,
                STOP_WITHIN.as_secs()
            );
        }
    }
}

struct Shared {
    zsession: zenoh::Session,
    name: String,
    task_infos: Vec<TaskInfo>,
    factories: Vec<TaskFactory>,
    policies: Arc<PolicyTable>,
    trusted_keys: Option<TrustedKeys>,
    refusals: RefusalLog,
    /// Whether anyone views any session's telemetry; each session's publisher.
    telemetry: TelemetryWatch,
    limits: Limits,
    /// Every open session by [`slot`].
    sessions: RwLock<HashMap<String, Arc<Mutex<Session>>>>,
    /// Who is alive and what each client holds; see [`usage`] for the lock order.
    clients: ClientTable,
    /// Policy runs driving a session now.
    runs: Arc<AtomicU32>,
    schedulers: Schedulers,
    /// Where `step_batch` replies are written.
    reply_memory: ReplyMemory,
}

/// A reply encoded by the operation that answers.
type Encoded = Result<Vec<u8>, ErrorReply>;
/// A reply as it is sent: most are [`Encoded`], a `step_batch` one may be in shared memory.
type Answer = Result<ZBytes, ErrorReply>;

/// Where the engine keeps session `id` of `identity`: sessions are found by their owner's
/// identity and id together, so a key under one identity never reaches another's session.
fn slot(identity: &str, id: &str) -> String {
    format!("{identity}/{id}")
}

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

    fn client_appeared(&self, client: &str) {
        self.clients.appeared(client);
    }

    /// Believes a deleted client token only once liveliness queries, asked again for
    /// [`LIVELINESS_SETTLE`], no longer find it, then closes the client's sessions. Zenoh
    /// also deletes a token it declares again at once (a link re-established, a route
    /// rebuilt): a client that never went away keeps its sessions. Looked at on a thread
    /// of its own, since Zenoh's callback must not block; it uses the engine only while the
    /// engine runs ([`WhileRunning`]).
    fn client_token_deleted(&self, engine: &Arc<WhileRunning<Self>>, client: &str) {
        let engine = Arc::clone(engine);
        let owner = client.to_owned();
        let confirm = move || {
            // `None` once the engine stopped: its sessions went with it.
            let look = || engine.with(|shared| shared.query_alive(&owner));
            if retry_within(LIVELINESS_SETTLE, look, |alive| *alive == Some(false)) == Some(false) {
                engine.with(|shared| shared.client_vanished(&owner));
            }
        };
        let spawned = std::thread::Builder::new()
            .name("ciflow-vanished".into())
            .spawn(confirm);
        if spawned.is_err() {
            // No thread to wait on: reclaim now rather than never.
            self.client_vanished(client);
        }
    }

    /// Closes every session of a client whose liveliness token went away: a lookup of its
    /// own sessions, not a scan of everyone's.
    fn client_vanished(&self, client: &str) {
        let ids = self.clients.vanished(client);
        let closed: Vec<_> = {
            let mut sessions = self.sessions_mut();
            ids.iter().filter_map(|id| sessions.remove(id)).collect()
        };
        // Freed outside the lock: freeing many environments takes a while, and every
        // other request needs the map.
        drop(closed);
    }

    /// Closes the session in `slot` and returns what it held to its owner's allowance.
    fn remove_session(&self, slot: &str) {
        let removed = self.sessions_mut().remove(slot);
        if let Some(session) = &removed {
            let (owner, num_envs) = match session.lock() {
                Ok(session) => (session.owner.clone(), session.num_envs()),
                Err(poisoned) => {
                    let session = poisoned.into_inner();
                    (session.owner.clone(), session.num_envs())
                }
            };
            self.clients.release(&owner, slot, num_envs);
        }
        drop(removed);
    }

    /// Answers one query on `route` with exactly one reply, within its deadline.
    fn answer(&self, query: &Query, route: Option<Route<'_>>, received: Instant) {
        let payload = query.payload().map(|p| p.to_bytes()).unwrap_or_default();
        let deadline = self.limits.deadline(received, requested_deadline(&payload));
        let answer = if payload.len() > self.limits.max_request_bytes as usize {
            Err(ErrorReply::new(
                ErrorCode::PayloadTooLarge,
                format!(
                    "request of {} bytes exceeds this engine's limit of {} bytes",
                    payload.len(),
                    self.limits.max_request_bytes
                ),
            ))
        } else if deadline.passed() {
            Err(deadline_exceeded("before the engine could start on it"))
        } else {
            catch_unwind(AssertUnwindSafe(|| {
                self.handle(route, &payload, query, deadline)
            }))
            .unwrap_or_else(|_| {
                if let Some(Route::Session {
                    identity, session, ..
                }) = route
                {
                    self.remove_session(&slot(identity, session));
                }
                Err(ErrorReply::new(
                    ErrorCode::Internal,
                    "the engine hit a bug while serving this request; the session was closed",
                ))
            })
        };
        self.reply(query, route, answer);
    }

    /// Sends the one reply of `query`.
    fn reply(&self, query: &Query, route: Option<Route<'_>>, answer: Answer) {
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

    fn handle(
        &self,
        route: Option<Route<'_>>,
        payload: &[u8],
        query: &Query,
        deadline: Deadline,
    ) -> Answer {
        let encoded = match route {
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
            Some(Route::Make { identity }) => {
                self.make(identity, decode_request(payload)?, deadline)
            }
            Some(Route::Ping) => Ok(payload.to_vec()),
            Some(Route::Limits { identity }) => {
                let request: LimitsRequest = decode_request(payload)?;
                Ok(encode(&LimitsReply {
                    v: PROTOCOL_VERSION,
                    limits: self.limits,
                    usage: request
                        .instance
                        .map(|instance| self.clients.usage(&keys::client(identity, &instance))),
                }))
            }
            Some(Route::Session {
                identity,
                session,
                op,
            }) => return self.session_op(identity, session, op, payload),
            Some(Route::PolicyAct { policy }) => {
                self.act(policy, decode_request(payload)?, deadline)
            }
            Some(Route::PolicyEvaluate { policy }) => {
                self.evaluate(policy, decode_request(payload)?, deadline)
            }
            Some(Route::PolicyStability { policy }) => {
                self.stability(policy, decode_request(payload)?, deadline)
            }
        };
        encoded.map(ZBytes::from)
    }

    /// Opens a session for the process `<identity>/<instance>`. The identity comes from
    /// the key, which a router's access control can tie to an authenticated peer; the
    /// payload only says which of the identity's processes owns the session.
    fn make(&self, identity: &str, request: MakeRequest, deadline: Deadline) -> Encoded {
        if !keys::is_plain_chunk(&request.instance) {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!(
                    "instance name `{}` must be letters, digits, `-`, `_` or `.`",
                    request.instance
                ),
            ));
        }
        let client = keys::client(identity, &request.instance);
        let factory = self.factory(&request.task)?;
        if request.num_envs == 0 {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                "num_envs must be at least 1",
            ));
        }
        if request.num_envs > self.limits.max_envs_per_session {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "num_envs {} exceeds this engine's limit of {} environments per session",
                    request.num_envs, self.limits.max_envs_per_session
                ),
            ));
        }
        if !self.confirm_alive(&client) {
            return Err(ErrorReply::new(
                ErrorCode::NoLiveliness,
                format!(
                    "client `{client}` has no liveliness token; declare `{}` before `make`",
                    keys::client_alive(&client)
                ),
            ));
        }
        let reservation = self
            .clients
            .reserve(&client, request.num_envs, &self.limits)?;
        let envs = build_envs(factory, &request.kwargs, request.num_envs, deadline)?;
        let spec = envs[0].env.spec().clone();
        let id = format!("{:016x}", rand::random::<u64>());
        let token: session::Token = rand::random();
        let telemetry = self
            .telemetry
            .session(identity, &id)
            .map_err(|e| ErrorReply::new(ErrorCode::Internal, full_message(&e)))?;
        let session = Session::new(
            id.clone(),
            client,
            token,
            request.kwargs.clone(),
            envs,
            telemetry,
        );
        // A deadline passed while building, or a client that vanished meanwhile
        // (nobody would ever close its session): nothing is kept.
        if deadline.passed() {
            return Err(deadline_exceeded("while building the session"));
        }
        self.commit_session(reservation, &slot(identity, &id), session)?;
        Ok(encode(&MakeReply {
            v: PROTOCOL_VERSION,
            session: id,
            token: serde_bytes::ByteBuf::from(token.to_vec()),
            num_envs: request.num_envs,
            spec,
        }))
    }

    /// Opens a built session in `slot` under its reservation (see [`ClientTable::commit`]).
    fn commit_session(
        &self,
        reservation: Reservation<'_>,
        slot: &str,
        session: Session,
    ) -> Result<(), ErrorReply> {
        self.clients.commit(reservation, slot, || {
            self.sessions_mut()
                .insert(slot.to_owned(), Arc::new(Mutex::new(session)));
        })
    }

    /// Whether `client` holds its liveliness token, asking Zenoh if the subscriber has not
    /// seen it yet. Runs on the worker thread: it may block for a round trip.
    fn confirm_alive(&self, client: &str) -> bool {
        // A token declared just before the `make` may not be routed to this engine yet
        // (seen through a router: the liveliness query found nothing, a later one would
        // have), so an empty answer is asked again for a moment before it counts.
        let alive = || self.clients.is_alive(client) || self.query_alive(client);
        retry_within(LIVELINESS_SETTLE, alive, |alive| !alive)
    }

    /// Whether a liveliness query finds `client`'s token (recording the client if so).
    fn query_alive(&self, client: &str) -> bool {
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

    /// Serves `op` on session `id`, which must be `identity`'s: a session of another
    /// identity is as unknown as one never made, so keys say nothing about other owners.
    fn session_op(&self, identity: &str, id: &str, op: SessionOp, payload: &[u8]) -> Answer {
        let slot = slot(identity, id);
        let handle = self.read_sessions().get(&slot).cloned().ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::UnknownSession,
                format!(
                    "no session `{id}` of `{identity}` on engine `{}` (closed, reclaimed or \
                     never made)",
                    self.name
                ),
            )
        })?;
        let Ok(mut session) = handle.lock() else {
            self.remove_session(&slot);
            return Err(ErrorReply::new(
                ErrorCode::Internal,
                format!("session `{id}` was closed after an internal error"),
            ));
        };
        let encoded = match op {
            SessionOp::Describe => Ok(session.describe()),
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
                return session.step_batch(
                    &request.actions.0,
                    request.known_contexts,
                    &self.reply_memory,
                );
            }
            SessionOp::Run => {
                let request: RunRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                let policy = self.policy(&request.policy)?;
                let permit =
                    RunPermit::take(&self.runs, self.limits.max_runs).ok_or_else(|| {
                        ErrorReply::new(
                            ErrorCode::LimitExceeded,
                            format!(
                                "{} policy runs are driving sessions, this engine's limit",
                                self.limits.max_runs
                            ),
                        )
                    })?;
                let run = session.start_run(&request, policy.as_ref(), permit)?;
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
                if self.schedulers.start(driver).is_err() {
                    session.stop_run()?;
                    return Err(ErrorReply::new(
                        ErrorCode::Internal,
                        "the engine's run schedulers are gone",
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
            SessionOp::CheckContext => {
                let request: ContextRequest = decode_request(payload)?;
                session.authorize(&request.token)?;
                session.check_context(&request)
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
                    .put(keys::session(&self.name, identity, id, "frame"), pixels)
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
                self.remove_session(&slot);
                Ok(encode(&AckReply {
                    v: PROTOCOL_VERSION,
                    time,
                }))
            }
        };
        encoded.map(ZBytes::from)
    }

    /// The factory of `task` (Gymnasium id or short name).
    fn factory(&self, task: &str) -> Result<&TaskFactory, ErrorReply> {
        self.factories
            .iter()
            .find(|f| f.is_named(task))
            .ok_or_else(|| {
                ErrorReply::new(
                    ErrorCode::UnknownTask,
                    format!(
                        "unknown task `{task}`; this engine has: {}",
                        self.factories
                            .iter()
                            .map(|f| f.id.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })
    }

    /// Episodes `first..first + count` of the evaluation `request.config` of checkpoint
    /// policy `name`, one at a time so the deadline is looked at between episodes.
    fn evaluate(&self, name: &str, request: EvaluateRequest, deadline: Deadline) -> Encoded {
        let policy = self.policy(name)?;
        let model = checkpoint_model(name, policy.as_ref())?;
        let config = &request.config;
        let episodes = share(request.first, request.count, config.episodes, "episodes")?;
        config
            .validate()
            .map_err(|e| ErrorReply::new(ErrorCode::InvalidRequest, full_message(&e)))?;
        let mut env = (self.factory(&policy.info().task)?.make)(&policy.task_kwargs())
            .map_err(ErrorReply::from)?;
        let mut batch: Option<EpisodeBatch> = None;
        one_at_a_time(episodes, deadline, "episodes", |episode| {
            let one = run_episodes(
                env.as_mut(),
                Acting::Model(model),
                config,
                episode..episode + 1,
                |_| {},
            )
            .map_err(|e| ErrorReply::new(ErrorCode::Simulation, full_message(&e)))?;
            match &mut batch {
                None => batch = Some(one),
                Some(batch) => batch.append(one),
            }
            Ok(())
        })?;
        Ok(encode(&EvaluateReply {
            v: PROTOCOL_VERSION,
            batch: batch.expect("a share holds at least one episode"),
        }))
    }

    /// Rollouts `first..first + count` of the stability check `request.config` of
    /// checkpoint policy `name` (or of its negative control), one at a time so the
    /// deadline is looked at between rollouts; on one thread, the request being one of
    /// several in flight.
    fn stability(&self, name: &str, request: StabilityRequest, deadline: Deadline) -> Encoded {
        let policy = self.policy(name)?;
        let model = checkpoint_model(name, policy.as_ref())?;
        let config = StabilityConfig {
            threads: 1,
            ..request.config
        };
        let trials = share(request.first, request.count, config.starts, "rollouts")?;
        let mut endings = Vec::with_capacity(trials.len());
        one_at_a_time(trials, deadline, "rollouts", |trial| {
            let ending = request
                .subject
                .rollouts(model, &config, trial..trial + 1, |_| {})
                .map_err(|e| ErrorReply::new(ErrorCode::InvalidRequest, full_message(&e)))?;
            endings.extend(ending);
            Ok(())
        })?;
        Ok(encode(&StabilityReply {
            v: PROTOCOL_VERSION,
            endings,
        }))
    }

    fn policy(&self, name: &str) -> Result<Arc<dyn Policy>, ErrorReply> {
        self.policies.get(name).ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::UnknownPolicy,
                match self.policies.names()[..] {
                    [] => format!(
                        "no policy `{name}`: this engine serves none (start it with `ciflow \
                         serve --policy {name}=CHECKPOINT_DIR`, or publish one with `ciflow \
                         train --publish {name}`)"
                    ),
                    ref names => {
                        format!("no policy `{name}`; this engine has: {}", names.join(", "))
                    }
                },
            )
        })
    }

    fn act(&self, name: &str, request: ActRequest, deadline: Deadline) -> Encoded {
        let policy = self.policy(name)?;
        let info = policy.info();
        let observation_dim = info.observation_dim as usize;
        let observations = &request.observations.0;
        let count = observations.len() / observation_dim.max(1);
        if count > self.limits.max_act_observations as usize {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "{count} observations exceed this engine's limit of {} per `act`",
                    self.limits.max_act_observations
                ),
            ));
        }
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
        let mut actions = vec![0.0; count * action_dim];
        for (index, (observation, action)) in observations
            .chunks_exact(observation_dim)
            .zip(actions.chunks_exact_mut(action_dim))
            .enumerate()
        {
            if index % DEADLINE_CHUNK == 0 && deadline.passed() {
                return Err(deadline_exceeded(&format!(
                    "after {index} of {count} observations; send smaller batches"
                )));
            }
            policy
                .act_into(observation, action)
                .map_err(|e| ErrorReply::new(ErrorCode::Policy, full_message(&e)))?;
            if action.iter().any(|a| !a.is_finite()) {
                return Err(ErrorReply::new(
                    ErrorCode::Policy,
                    format!(
                        "the policy's action for observation {index} is not finite (an \
                         observation far outside what it was trained on?)"
                    ),
                ));
            }
        }
        Ok(encode(&ActionReply {
            v: PROTOCOL_VERSION,
            action: F64s(actions),
        }))
    }
}

/// The trained model of policy `name`, which `evaluate` and `stability` need.
fn checkpoint_model<'p>(name: &str, policy: &'p dyn Policy) -> Result<&'p Model, ErrorReply> {
    policy.model().ok_or_else(|| {
        ErrorReply::new(
            ErrorCode::InvalidRequest,
            format!("policy `{name}` is not a checkpoint; only checkpoints are evaluated"),
        )
    })
}

/// `first..first + count` as indices, if it is a non-empty part of `0..total` `what`.
fn share(first: u64, count: u64, total: usize, what: &str) -> Result<Range<usize>, ErrorReply> {
    usize::try_from(first)
        .ok()
        .zip(usize::try_from(count).ok())
        .and_then(|(first, count)| Some(first..first.checked_add(count)?))
        .filter(|share| !share.is_empty() && share.end <= total)
        .ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!("{what} {first}..{first}+{count} are not a non-empty part of 0..{total}"),
            )
        })
}

/// `run(i)` for each `i` of `items` in order, the deadline looked at before each: a
/// request of several episodes or rollouts stops between two of them.
fn one_at_a_time(
    items: Range<usize>,
    deadline: Deadline,
    what: &str,
    mut run: impl FnMut(usize) -> Result<(), ErrorReply>,
) -> Result<(), ErrorReply> {
    for item in items.clone() {
        if deadline.passed() {
            return Err(deadline_exceeded(&format!(
                "after {} of {} {what}; ask for fewer at a time",
                item - items.start,
                items.len()
            )));
        }
        run(item)?;
    }
    Ok(())
}

fn deadline_exceeded(when: &str) -> ErrorReply {
    ErrorReply::new(
        ErrorCode::DeadlineExceeded,
        format!("the request's time budget ran out {when}; nothing was kept"),
    )
}

/// `num_envs` environments of `factory`'s task, built in parallel; refused with nothing
/// kept if the deadline passes first.
fn build_envs(
    factory: &TaskFactory,
    kwargs: &Kwargs,
    num_envs: u32,
    deadline: Deadline,
) -> Result<Vec<EnvSlot>, ErrorReply> {
    (0..num_envs)
        .into_par_iter()
        .with_min_len(DEADLINE_CHUNK)
        .map(|_| {
            if deadline.passed() {
                return Err(deadline_exceeded(&format!(
                    "while building {num_envs} environments"
                )));
            }
            (factory.make)(kwargs)
                .map(|mut env| {
                    // Nobody watches the environments of a batch one by one: their
                    // episodes' trails would outweigh the rest of them.
                    env.record_trail(num_envs == 1);
                    EnvSlot::new(env)
                })
                .map_err(ErrorReply::from)
        })
        .collect()
}
