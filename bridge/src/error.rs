//! Errors of the bridge library: starting an engine, and everything a client can meet.

use crate::protocol::ErrorReply;

#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error("Zenoh configuration: {0}")]
    Config(String),
    #[error("Zenoh: {0}")]
    Zenoh(String),
    /// Nobody answered at all: no engine is serving that key.
    #[error(
        "no ciflow engine answered on `{key}`. Start one with `ciflow serve` (add \
         `--listen tcp/<host>:<port>` to reach it from other machines), or point the client \
         at a running engine (`engine=\"tcp/<host>:<port>\"` or CIFLOW_ENGINE)"
    )]
    NoEngine { key: String },
    /// The engine refused the request with a typed error.
    #[error("engine refused the request: {0}")]
    Remote(#[from] ErrorReply),
    #[error("undecodable reply on `{key}`: {detail}")]
    BadReply { key: String, detail: String },
    #[error("{0}")]
    InvalidArgument(String),
    #[error("frame {id} of session {session} did not arrive within {timeout_ms} ms")]
    FrameLost {
        session: String,
        id: u64,
        timeout_ms: u128,
    },
}

impl BridgeError {
    pub(crate) fn zenoh(error: impl std::fmt::Display) -> Self {
        BridgeError::Zenoh(error.to_string())
    }
}
