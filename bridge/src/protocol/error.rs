//! The typed error every refused request gets as its one reply (a Zenoh error reply).

use std::fmt;

use ciflow_envs::EnvError;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::PROTOCOL_VERSION;

/// Why a request was refused; on the wire a snake_case string such as `"unknown_session"`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// The request's `v` is not the server's protocol version.
    VersionMismatch,
    /// The payload is not a MessagePack map of the operation's request layout.
    Malformed,
    /// The payload exceeds the engine's `max_request_bytes` (at most
    /// [`super::MAX_REQUEST_BYTES`]).
    PayloadTooLarge,
    /// The key names no operation of this protocol.
    UnknownOperation,
    UnknownTask,
    UnknownSession,
    UnknownPolicy,
    /// The session's secret token is missing or wrong: the caller does not own it.
    Forbidden,
    /// The operation does not fit the session, e.g. `step` on a batch of 8.
    InvalidRequest,
    /// The client has no liveliness token, so its sessions could never be reclaimed.
    NoLiveliness,
    WrongDimension,
    NotFinite,
    OutOfBounds,
    InvalidOption,
    NeedsReset,
    /// A perturbation names a link or joint count the robot does not have.
    InvalidPerturbation,
    Simulation,
    /// The policy evaluator failed.
    Policy,
    /// A bug in the engine or a task (caught, never a crash); the session is closed.
    Internal,
    /// The session is driven by a policy (`run`): `step`/`reset` wait until it stops.
    Busy,
    /// The request would exceed one of the engine's bounds (`limits` lists them).
    LimitExceeded,
    /// The engine could not answer within the request's time budget; nothing was kept.
    DeadlineExceeded,
}

impl ErrorCode {
    const ALL: [ErrorCode; 22] = [
        ErrorCode::VersionMismatch,
        ErrorCode::Malformed,
        ErrorCode::PayloadTooLarge,
        ErrorCode::UnknownOperation,
        ErrorCode::UnknownTask,
        ErrorCode::UnknownSession,
        ErrorCode::UnknownPolicy,
        ErrorCode::Forbidden,
        ErrorCode::InvalidRequest,
        ErrorCode::NoLiveliness,
        ErrorCode::WrongDimension,
        ErrorCode::NotFinite,
        ErrorCode::OutOfBounds,
        ErrorCode::InvalidOption,
        ErrorCode::NeedsReset,
        ErrorCode::InvalidPerturbation,
        ErrorCode::Simulation,
        ErrorCode::Policy,
        ErrorCode::Internal,
        ErrorCode::Busy,
        ErrorCode::LimitExceeded,
        ErrorCode::DeadlineExceeded,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::VersionMismatch => "version_mismatch",
            ErrorCode::Malformed => "malformed",
            ErrorCode::PayloadTooLarge => "payload_too_large",
            ErrorCode::UnknownOperation => "unknown_operation",
            ErrorCode::UnknownTask => "unknown_task",
            ErrorCode::UnknownSession => "unknown_session",
            ErrorCode::UnknownPolicy => "unknown_policy",
            ErrorCode::Forbidden => "forbidden",
            ErrorCode::InvalidRequest => "invalid_request",
            ErrorCode::NoLiveliness => "no_liveliness",
            ErrorCode::WrongDimension => "wrong_dimension",
            ErrorCode::NotFinite => "not_finite",
            ErrorCode::OutOfBounds => "out_of_bounds",
            ErrorCode::InvalidOption => "invalid_option",
            ErrorCode::NeedsReset => "needs_reset",
            ErrorCode::InvalidPerturbation => "invalid_perturbation",
            ErrorCode::Simulation => "simulation",
            ErrorCode::Policy => "policy",
            ErrorCode::Internal => "internal",
            ErrorCode::Busy => "busy",
            ErrorCode::LimitExceeded => "limit_exceeded",
            ErrorCode::DeadlineExceeded => "deadline_exceeded",
        }
    }

    pub fn parse(code: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.as_str() == code)
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Serialize for ErrorCode {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for ErrorCode {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let code = String::deserialize(deserializer)?;
        Self::parse(&code)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown error code `{code}`")))
    }
}

/// Payload of every error reply: `{v, code, message}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, thiserror::Error)]
#[error("{code}: {message}")]
pub struct ErrorReply {
    pub v: u16,
    pub code: ErrorCode,
    pub message: String,
}

impl ErrorReply {
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            v: PROTOCOL_VERSION,
            code,
            message: message.into(),
        }
    }
}

impl From<EnvError> for ErrorReply {
    fn from(error: EnvError) -> Self {
        let code = match error {
            EnvError::WrongDimension { .. } | EnvError::BatchDimension { .. } => {
                ErrorCode::WrongDimension
            }
            EnvError::NotFinite { .. } => ErrorCode::NotFinite,
            EnvError::OutOfBounds { .. } => ErrorCode::OutOfBounds,
            EnvError::InvalidOption { .. } => ErrorCode::InvalidOption,
            EnvError::NeedsReset => ErrorCode::NeedsReset,
            EnvError::InvalidPerturbation(_) => ErrorCode::InvalidPerturbation,
            EnvError::Simulation(_) => ErrorCode::Simulation,
            EnvError::Lasa { .. } => ErrorCode::InvalidOption,
        };
        // The message carries the whole chain: a client sees why the simulation failed,
        // not only that it did.
        Self::new(code, full_message(&error))
    }
}

/// An error's message followed by those of its sources, `outer: cause: …`, for where only
/// text travels on (protocol error replies, Python exceptions, logs). A cause whose text
/// already ends the message (an error that prints its source itself) is not repeated, and
/// one that begins with the message (`invalid perturbation` caused by `invalid
/// perturbation: link 7 …`) replaces it.
pub fn full_message(error: &(dyn std::error::Error + 'static)) -> String {
    let mut message = error.to_string();
    let mut source = error.source();
    while let Some(cause) = source {
        let text = cause.to_string();
        if text.starts_with(&message) {
            // The cause says what the message says, and more.
            message = text;
        } else if !message.ends_with(&text) {
            message = format!("{message}: {text}");
        }
        source = cause.source();
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_env_error_s_reply_names_its_causes() {
        use ciflow_engine::sim::SimError;
        let cause = SimError::NonFiniteState { time: 1.5 };
        let reply = ErrorReply::from(EnvError::Simulation(cause));
        assert_eq!(reply.code, ErrorCode::Simulation);
        assert_eq!(
            reply.message,
            "simulation failed: the state became non-finite at t = 1.5 s"
        );
    }

    #[test]
    fn a_cause_that_repeats_the_message_is_said_once() {
        use ciflow_engine::sim::SimError;
        let cause = SimError::InvalidPerturbation("link 7 does not exist".into());
        let reply = ErrorReply::from(EnvError::InvalidPerturbation(cause));
        assert_eq!(reply.message, "invalid perturbation: link 7 does not exist");
    }

    #[test]
    fn codes_round_trip_as_strings() {
        for code in ErrorCode::ALL {
            let bytes = rmp_serde::to_vec(&code).unwrap();
            let text: String = rmp_serde::from_slice(&bytes).unwrap();
            assert_eq!(text, code.as_str());
            assert_eq!(rmp_serde::from_slice::<ErrorCode>(&bytes).unwrap(), code);
        }
    }
}
