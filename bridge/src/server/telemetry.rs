//! Telemetry of the engine's sessions: published only while a viewer subscribes, at most
//! `hz` times per wall-clock second and session, with congestion control `Drop` so that a
//! slow viewer never slows stepping.
//!
//! Sessions declare nothing in Zenoh. Zenoh's session keeps its publishers and matching
//! listeners in lists it scans on every declaration and subscription change, so one
//! publisher per session made every `make` and `close` — and every step, through the
//! interest traffic — cost more the more sessions were open. Instead one engine-wide
//! publisher on `…/session/*/telemetry` tells, through its matching listener, whether any
//! viewer listens to any session; while one does, each session puts its samples on its
//! own key and Zenoh delivers them to whoever subscribed there.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;

use super::slot::EnvSlot;
use crate::error::BridgeError;
use crate::protocol::{F64s, PROTOCOL_VERSION, Telemetry, encode, keys};

/// Whether any viewer subscribes to the telemetry of any of an engine's sessions, and the
/// publisher of each session's samples.
pub(crate) struct TelemetryWatch {
    /// Declared for its matching listener only; nothing is put on it.
    _publisher: Publisher<'static>,
    viewers: Arc<AtomicBool>,
    zsession: zenoh::Session,
    engine: String,
    min_interval: Duration,
}

impl TelemetryWatch {
    /// Watches `engine`'s telemetry keys; its sessions publish at most `hz` samples per
    /// second each.
    pub fn declare(session: &zenoh::Session, engine: &str, hz: f64) -> Result<Self, BridgeError> {
        let publisher = session
            .declare_publisher(keys::session(engine, "*", "*", "telemetry"))
            .wait()
            .map_err(BridgeError::zenoh("declaring the telemetry publisher"))?;
        let viewers = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&viewers);
        publisher
            .matching_listener()
            .callback(move |status| flag.store(status.matching(), Ordering::Relaxed))
            .background()
            .wait()
            .map_err(BridgeError::zenoh(
                "declaring the telemetry matching listener",
            ))?;
        Ok(Self {
            _publisher: publisher,
            viewers,
            zsession: session.clone(),
            engine: engine.to_owned(),
            min_interval: Duration::from_secs_f64(1.0 / hz.max(1e-3)),
        })
    }

    /// The telemetry of session `id`.
    pub fn session(&self, identity: &str, id: &str) -> Result<TelemetryPublisher, BridgeError> {
        let key = KeyExpr::try_from(keys::session(&self.engine, identity, id, "telemetry"))
            .map_err(BridgeError::zenoh("building the telemetry key"))?;
        Ok(TelemetryPublisher {
            zsession: self.zsession.clone(),
            key,
            viewers: Arc::clone(&self.viewers),
            min_interval: self.min_interval,
            last_sent: None,
        })
    }
}

pub(crate) struct TelemetryPublisher {
    zsession: zenoh::Session,
    key: KeyExpr<'static>,
    /// Set by the engine's matching listener; read on every step, so an atomic.
    viewers: Arc<AtomicBool>,
    min_interval: Duration,
    last_sent: Option<Instant>,
}

impl TelemetryPublisher {
    /// Publishes the state of `slot` if a viewer listens and the rate limit allows.
    pub fn offer(&mut self, session: &str, slot: &EnvSlot) {
        self.publish(session, slot, false, false);
    }

    /// Publishes a sample of a policy-driven session. `running` tells viewers whether
    /// the driver continues; a sample that ends the run is sent regardless of the rate
    /// limit, so that viewers learn the run ended.
    pub fn offer_run(&mut self, session: &str, slot: &EnvSlot, running: bool) {
        self.publish(session, slot, running, !running);
    }

    fn publish(&mut self, session: &str, slot: &EnvSlot, running: bool, always: bool) {
        if !self.viewers.load(Ordering::Relaxed) {
            return;
        }
        let now = Instant::now();
        if !always
            && self
                .last_sent
                .is_some_and(|last| now.duration_since(last) < self.min_interval)
        {
            return;
        }
        self.last_sent = Some(now);
        let message = Telemetry {
            v: PROTOCOL_VERSION,
            session: session.to_owned(),
            step: slot.steps,
            time: slot.time(),
            state: F64s(slot.state().to_vec()),
            command: F64s(slot.command.clone()),
            context: F64s(slot.context().to_vec()),
            reward: slot.reward,
            running,
            episode_done: slot.episode_over,
            perturbed: slot.perturbed,
        };
        // A dropped telemetry sample is harmless; the next step sends a fresh one.
        let _ = self
            .zsession
            .put(&self.key, encode(&message))
            .congestion_control(CongestionControl::Drop)
            .wait();
    }
}
