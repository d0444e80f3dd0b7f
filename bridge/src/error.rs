//! Errors of the bridge library: starting an engine, and everything a client can meet.

use std::path::PathBuf;
use std::time::Duration;

use ciflow_engine::flow::FlowError;
use ciflow_envs::EnvError;

use crate::protocol::ErrorReply;
pub use crate::protocol::error::full_message;

/// `Ok` when `name` can be one chunk of a key expression (engine, identity, session and
/// policy names must); otherwise the error says which `what` it is and what is allowed.
pub(crate) fn check_name(what: &str, name: &str) -> Result<(), BridgeError> {
    if crate::protocol::keys::is_plain_chunk(name) {
        Ok(())
    } else {
        Err(BridgeError::InvalidArgument(format!(
            "{what} `{name}` must be letters, digits, `-`, `_` or `.`"
        )))
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error("cannot read Zenoh config {}", path.display())]
    ConfigFile {
        path: PathBuf,
        #[source]
        source: zenoh::Error,
    },
    #[error("bad Zenoh setting {key} = {value}")]
    ConfigSetting {
        key: String,
        value: String,
        #[source]
        source: zenoh::Error,
    },
    #[error("unknown Zenoh mode `{0}`; expected peer, client or router")]
    UnknownMode(String),
    /// The Zenoh session could not be opened; `hint` says what usually causes it.
    #[error("cannot {action} ({hint})")]
    Open {
        action: &'static str,
        hint: &'static str,
        #[source]
        source: zenoh::Error,
    },
    /// A Zenoh operation on an open session failed.
    #[error("Zenoh failed while {action}")]
    Zenoh {
        action: &'static str,
        #[source]
        source: zenoh::Error,
    },
    #[error("cannot spawn the engine's worker threads")]
    Worker(#[source] std::io::Error),
    /// Nobody answered at all: no engine is serving that key.
    #[error(
        "no ciflow engine answered on `{key}`. Start one with `ciflow serve` (add \
         `--listen tcp/<host>:<port>` to reach it from other machines), or point the client \
         at a running engine (`engine=\"tcp/<host>:<port>\"` or CIFLOW_ENGINE)"
    )]
    NoEngine { key: String },
    /// An engine took the request but its reply did not come before the timeout: it is
    /// overloaded or stuck, or the link dropped while it worked.
    #[error(
        "no reply on `{key}` within {waited:.1?}: an engine serves that key but did not answer \
         in time (overloaded, stuck, or the link dropped); check the engine's log, or raise \
         the client's timeout for slow requests"
    )]
    NoReply { key: String, waited: Duration },
    /// The engine refused the request with a typed error.
    #[error("engine refused the request: {0}")]
    Remote(#[from] ErrorReply),
    #[error("undecodable reply on `{key}`")]
    BadReply {
        key: String,
        #[source]
        source: rmp_serde::decode::Error,
    },
    /// A sample arrived on a key outside the layout its subscription expects.
    #[error("a sample on `{key}`, which is not {expected}")]
    UnexpectedKey { key: String, expected: &'static str },
    /// An error reply that is not a protocol [`ErrorReply`]; `payload` is its text.
    #[error("undecodable error reply on `{key}`: {payload}")]
    BadErrorReply {
        key: String,
        payload: String,
        #[source]
        source: rmp_serde::decode::Error,
    },
    /// A check of the caller's arguments failed (names, counts).
    #[error("{0}")]
    InvalidArgument(String),
    #[error("cannot look up the task")]
    UnknownTask(#[source] EnvError),
    #[error("task {task} fails with its default arguments")]
    TaskDefaults {
        task: String,
        #[source]
        source: EnvError,
    },
    #[error("cannot read {}", path.display())]
    ReadCheckpoint {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{} is not UTF-8", path.display())]
    CheckpointNotUtf8 {
        path: PathBuf,
        #[source]
        source: std::string::FromUtf8Error,
    },
    #[error("bad checkpoint configuration in {}", dir.display())]
    CheckpointConfig {
        dir: PathBuf,
        #[source]
        source: FlowError,
    },
    /// One engine of several failed (`ciflow evaluate --engines`).
    #[error("engine `{engine}`")]
    Engine {
        engine: String,
        #[source]
        source: Box<BridgeError>,
    },
    /// Engines did not serve a published checkpoint in time.
    #[error(
        "engine(s) {engines} did not load the checkpoint within {seconds} s: an engine that \
         trusts keys loads only signed checkpoints (--signing-key), and an engine must serve \
         the checkpoint's task (its log says why it refused)"
    )]
    CheckpointNotLoaded { engines: String, seconds: u64 },
    #[error("frame {id} of session {session} did not arrive within {timeout_ms} ms")]
    FrameLost {
        session: String,
        id: u64,
        timeout_ms: u128,
    },
}

impl BridgeError {
    /// The error of a Zenoh operation, `action` saying what was being done ("declaring
    /// the engine's queryable").
    pub(crate) fn zenoh(action: &'static str) -> impl FnOnce(zenoh::Error) -> Self {
        move |source| BridgeError::Zenoh { action, source }
    }
}

#[cfg(test)]
mod tests {
    use std::error::Error as _;

    use super::*;
    use crate::config::{NetworkOptions, Role};

    #[test]
    fn a_zenoh_error_is_carried_as_the_source() {
        let cause: zenoh::Error = Box::new(std::io::Error::other("connection refused"));
        let error = BridgeError::zenoh("declaring the engine's queryable")(cause);
        let source = error.source().expect("the Zenoh error is the source");
        assert!(source.downcast_ref::<std::io::Error>().is_some());
        assert_eq!(
            full_message(&error),
            "Zenoh failed while declaring the engine's queryable: connection refused"
        );

        let bad = NetworkOptions {
            listen: vec!["not an endpoint".into()],
            ..Default::default()
        }
        .to_zenoh_config(Role::Engine)
        .unwrap_err();
        assert!(matches!(bad, BridgeError::ConfigSetting { .. }));
        assert!(bad.source().is_some());
    }

    #[test]
    fn full_message_does_not_repeat_a_cause_printed_by_its_error() {
        #[derive(Debug, thiserror::Error)]
        #[error("outer: {0}")]
        struct Prints(#[source] std::io::Error);
        let error = Prints(std::io::Error::other("inner"));
        assert_eq!(full_message(&error), "outer: inner");
    }
}
