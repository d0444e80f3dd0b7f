//! Control of a session: start or stop a policy run, push the robot, change the context,
//! read the telemetry. The session's owner holds one ([`RemoteEnv::control`]); any other
//! process that knows the session's id and token gets one with [`Client::attach`] — with
//! the engine's name, or through a wildcard when it does not know which engine holds the
//! session. Dropping it leaves the session to its owner.
//!
//! [`RemoteEnv::control`]: crate::client::RemoteEnv::control
//! [`Client::attach`]: crate::client::Client::attach

use std::time::Duration;

use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_bytes::ByteBuf;
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

use crate::error::{BridgeError, check_name};
use crate::protocol::keys::{self, SessionOp};
use crate::protocol::{
    AckReply, ContextCheckReply, ContextRequest, ErrorCode, F64s, PROTOCOL_VERSION, PerturbRequest,
    PerturbationMsg, RunRequest, SessionRequest, Telemetry, decode_reply, encode,
};
use crate::query::query_all;

/// Any engine: the session's keys with a wildcard in place of the engine's name.
pub const ANY_ENGINE: &str = "*";

/// Where a session lives: its engine (or [`ANY_ENGINE`]), its owner's identity and its id.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct SessionAddress {
    engine: String,
    identity: String,
    session: String,
}

impl SessionAddress {
    pub(crate) fn new(engine: &str, identity: &str, session: &str) -> Self {
        Self {
            engine: engine.to_owned(),
            identity: identity.to_owned(),
            session: session.to_owned(),
        }
    }

    /// The key of the session's `leaf` (an operation, `telemetry`, `frame`).
    pub(crate) fn key(&self, leaf: &str) -> String {
        keys::session(&self.engine, &self.identity, &self.session, leaf)
    }
}

/// The controls of one session (module docs).
#[derive(Clone)]
pub struct SessionControl {
    zsession: zenoh::Session,
    address: SessionAddress,
    token: ByteBuf,
    timeout: Duration,
}

impl SessionControl {
    pub(crate) fn new(
        zsession: zenoh::Session,
        address: SessionAddress,
        token: &[u8],
        timeout: Duration,
    ) -> Result<Self, BridgeError> {
        let SessionAddress {
            engine,
            identity,
            session,
        } = &address;
        check_name("identity", identity)?;
        for (what, chunk) in [("engine", engine), ("session", session)] {
            if chunk != ANY_ENGINE {
                check_name(what, chunk)?;
            }
        }
        if session == ANY_ENGINE {
            return Err(BridgeError::InvalidArgument(
                "name one session, not `*`".into(),
            ));
        }
        Ok(Self {
            zsession,
            address,
            token: ByteBuf::from(token.to_vec()),
            timeout,
        })
    }

    /// The engine's name, or [`ANY_ENGINE`].
    pub fn engine(&self) -> &str {
        &self.address.engine
    }

    pub fn session_id(&self) -> &str {
        &self.address.session
    }

    /// The session's secret; whoever holds it may control the session.
    pub fn token(&self) -> &[u8] {
        &self.token
    }

    pub(crate) fn zenoh_session(&self) -> &zenoh::Session {
        &self.zsession
    }

    pub(crate) fn timeout(&self) -> Duration {
        self.timeout
    }

    /// The key of the session's `leaf` (an operation, `telemetry`, `frame`).
    pub(crate) fn key(&self, leaf: &str) -> String {
        self.address.key(leaf)
    }

    /// A request that only names environment `index`, with the token.
    pub(crate) fn session_request(&self, index: u32) -> SessionRequest {
        SessionRequest {
            v: PROTOCOL_VERSION,
            token: self.token.clone(),
            index,
        }
    }

    /// The token as requests carry it.
    pub(crate) fn token_field(&self) -> ByteBuf {
        self.token.clone()
    }

    /// One request to the session. Through a wildcard every engine answers: the engine
    /// holding the session with its reply, the others with `unknown_session`, so the
    /// first success wins and otherwise the most telling error.
    fn call<R: DeserializeOwned>(
        &self,
        op: SessionOp,
        request: &impl Serialize,
    ) -> Result<R, BridgeError> {
        let key = self.key(op.as_str());
        let replies = query_all(&self.zsession, &key, encode(request), self.timeout)?;
        let mut errors = Vec::new();
        for reply in replies {
            match reply {
                Ok(bytes) => {
                    return decode_reply(&bytes).map_err(|source| BridgeError::BadReply {
                        key: key.clone(),
                        source,
                    });
                }
                Err(error) => errors.push(error),
            }
        }
        errors.sort_by_key(|e| e.code == ErrorCode::UnknownSession);
        match errors.into_iter().next() {
            Some(error) => Err(BridgeError::Remote(error)),
            None => Err(BridgeError::NoEngine { key }),
        }
    }

    /// Replaces the context of environment `index`; returns the simulated time.
    pub fn set_context(&self, index: u32, context: &[f64]) -> Result<f64, BridgeError> {
        let reply: AckReply =
            self.call(SessionOp::Context, &self.context_request(index, context))?;
        Ok(reply.time)
    }

    /// Whether environment `index`'s task accepts `context`: `None` if it does, else why
    /// not. Nothing changes.
    pub fn check_context(
        &self,
        index: u32,
        context: &[f64],
    ) -> Result<Option<String>, BridgeError> {
        let request = self.context_request(index, context);
        let reply: ContextCheckReply = self.call(SessionOp::CheckContext, &request)?;
        Ok((!reply.valid).then(|| {
            reply
                .reason
                .unwrap_or_else(|| "the engine gave no reason".into())
        }))
    }

    fn context_request(&self, index: u32, context: &[f64]) -> ContextRequest {
        ContextRequest {
            v: PROTOCOL_VERSION,
            token: self.token.clone(),
            index,
            context: F64s(context.to_vec()),
        }
    }

    /// Lets policy `policy` drive environment `index` (`speed` 1 = real time, 0 = as fast
    /// as possible; `steps` absent = until the episode ends). Returns the simulated time
    /// at the start. `step`/`reset` answer `busy` until the run ends or [`stop`](Self::stop).
    pub fn run(
        &self,
        index: u32,
        policy: &str,
        speed: f64,
        steps: Option<u32>,
    ) -> Result<f64, BridgeError> {
        let reply: AckReply = self.call(
            SessionOp::Run,
            &RunRequest {
                v: PROTOCOL_VERSION,
                token: self.token.clone(),
                index,
                policy: policy.to_owned(),
                speed,
                steps,
            },
        )?;
        Ok(reply.time)
    }

    /// Stops a policy run (no effect without one); returns the simulated time.
    pub fn stop(&self) -> Result<f64, BridgeError> {
        let reply: AckReply = self.call(SessionOp::Stop, &self.session_request(0))?;
        Ok(reply.time)
    }

    /// Schedules a perturbation of environment `index`; returns the simulated time at
    /// which the engine accepted it.
    pub fn perturb(&self, index: u32, perturbation: PerturbationMsg) -> Result<f64, BridgeError> {
        let reply: AckReply = self.call(
            SessionOp::Perturb,
            &PerturbRequest {
                v: PROTOCOL_VERSION,
                token: self.token.clone(),
                index,
                perturbation,
            },
        )?;
        Ok(reply.time)
    }

    /// Subscribes to this session's telemetry (subscribe before starting what you want
    /// to record).
    pub fn telemetry(&self) -> Result<TelemetryStream, BridgeError> {
        TelemetryStream::subscribe(&self.zsession, &self.address.key("telemetry"))
    }
}

/// A telemetry sample and the engine and owner identity of its session.
#[derive(Clone, Debug, PartialEq)]
pub struct SourcedTelemetry {
    pub engine: String,
    pub identity: String,
    pub telemetry: Telemetry,
}

/// The telemetry samples of one session (or of every session a [`crate::Client::watch`]
/// matches), as they arrive.
pub struct TelemetryStream {
    subscriber: Subscriber<FifoChannelHandler<Sample>>,
}

impl TelemetryStream {
    /// Subscribes to the telemetry keys `key` matches (telemetry needs no token; behind
    /// access control, only the owner's identity may subscribe).
    pub(crate) fn subscribe(zsession: &zenoh::Session, key: &str) -> Result<Self, BridgeError> {
        let subscriber = zsession
            .declare_subscriber(key.to_owned())
            .wait()
            .map_err(BridgeError::zenoh("subscribing to the telemetry"))?;
        Ok(Self { subscriber })
    }

    /// The next sample, or `None` if none arrives within `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<Telemetry>, BridgeError> {
        Ok(self.recv_sourced(timeout)?.map(|sample| sample.telemetry))
    }

    /// The next sample with the engine and owner it came from, or `None` if none arrives
    /// within `timeout`.
    pub fn recv_sourced(&self, timeout: Duration) -> Result<Option<SourcedTelemetry>, BridgeError> {
        let sample = match self.subscriber.recv_timeout(timeout) {
            Ok(Some(sample)) => sample,
            Ok(None) => return Ok(None),
            Err(source) => {
                return Err(BridgeError::zenoh("receiving the telemetry")(source));
            }
        };
        let key = sample.key_expr().as_str();
        let (engine, identity, _) =
            keys::parse_telemetry(key).ok_or_else(|| BridgeError::UnexpectedKey {
                key: key.to_owned(),
                expected: "a session's telemetry key",
            })?;
        let telemetry =
            decode_reply(&sample.payload().to_bytes()).map_err(|source| BridgeError::BadReply {
                key: key.to_owned(),
                source,
            })?;
        Ok(Some(SourcedTelemetry {
            engine: engine.to_owned(),
            identity: identity.to_owned(),
            telemetry,
        }))
    }
}
