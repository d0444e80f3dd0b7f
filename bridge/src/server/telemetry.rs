//! Telemetry of one session: published only while a subscriber matches, and at most
//! `hz` times per wall-clock second, with congestion control `Drop` so that a slow viewer
//! never slows stepping.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;

use super::slot::EnvSlot;
use crate::error::BridgeError;
use crate::protocol::{F64s, PROTOCOL_VERSION, Telemetry, encode};

pub(crate) struct TelemetryPublisher {
    publisher: Publisher<'static>,
    /// Set by the matching listener; read on every step, so an atomic and no query.
    matching: Arc<AtomicBool>,
    min_interval: Duration,
    last_sent: Option<Instant>,
}

impl TelemetryPublisher {
    pub fn declare(session: &zenoh::Session, key: String, hz: f64) -> Result<Self, BridgeError> {
        let publisher = session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(BridgeError::zenoh("declaring the telemetry publisher"))?;
        let matching = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&matching);
        publisher
            .matching_listener()
            .callback(move |status| flag.store(status.matching(), Ordering::Relaxed))
            .background()
            .wait()
            .map_err(BridgeError::zenoh(
                "declaring the telemetry matching listener",
            ))?;
        Ok(Self {
            publisher,
            matching,
            min_interval: Duration::from_secs_f64(1.0 / hz.max(1e-3)),
            last_sent: None,
        })
    }

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
        if !self.matching.load(Ordering::Relaxed) {
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
        };
        // A dropped telemetry sample is harmless; the next step sends a fresh one.
        let _ = self.publisher.put(encode(&message)).wait();
    }
}
