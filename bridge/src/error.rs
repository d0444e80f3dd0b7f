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
        source: ZenohCause,
    },
    #[error("bad Zenoh setting {key} = {value}")]
    ConfigSetting {
        key: String,
        value: String,
        #[source]
        source: ZenohCause,
    },
    #[error("unknown Zenoh mode `{0}`; expected peer, client or router")]
    UnknownMode(String),
    /// The Zenoh session could not be opened; `hint` says what usually causes it.
    #[error("cannot {action} ({hint})")]
    Open {
        action: &'static str,
        hint: &'static str,
        #[source]
        source: ZenohCause,
    },
    /// A Zenoh operation on an open session failed.
    #[error("Zenoh failed while {action}")]
    Zenoh {
        action: &'static str,
        #[source]
        source: ZenohCause,
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
    /// Asked for every engine serving a task (`*`), none that serves it answered.
    #[error("no engine serving {task} answered; start some with `ciflow serve`")]
    NoEngineServing { task: String },
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
        move |source| BridgeError::Zenoh {
            action,
            source: source.into(),
        }
    }
}

/// A Zenoh error as its reader needs it: Zenoh's messages end with the path and line of
/// the Zenoh source that raised them, and wrap JSON5 errors in their debug form
/// (`Json5Err(Message { msg: "…", location: … })`); this shows the message alone. The
/// error itself stays reachable as [`ZenohCause::0`] and through `source()`.
#[derive(Debug)]
pub struct ZenohCause(pub zenoh::Error);

impl From<zenoh::Error> for ZenohCause {
    fn from(error: zenoh::Error) -> Self {
        Self(error)
    }
}

impl std::fmt::Display for ZenohCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&readable_zenoh_message(&self.0.to_string()))
    }
}

impl std::error::Error for ZenohCause {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.0.source()
    }
}

/// `text` without Zenoh's JSON5 debug wrapping and its ` at <file>.rs:<line>.` suffixes.
fn readable_zenoh_message(text: &str) -> String {
    const JSON5: &str = "Json5Err(Message { msg: \"";
    let text = match text.find(JSON5) {
        Some(start) => {
            let message = &text[start + JSON5.len()..];
            let end = message.find("\", location").unwrap_or(message.len());
            message[..end].replace("\\\"", "\"")
        }
        None => text.to_owned(),
    };
    let mut readable = String::with_capacity(text.len());
    let mut rest = text.as_str();
    while let Some(at) = rest.find(" at ") {
        let location = &rest[at + 4..];
        // `<path>.rs:<line>`, then an optional full stop.
        let path_end = location.find(char::is_whitespace).unwrap_or(location.len());
        let path = location[..path_end].trim_end_matches('.');
        let is_location = path
            .rsplit_once(".rs:")
            .is_some_and(|(_, line)| !line.is_empty() && line.bytes().all(|b| b.is_ascii_digit()));
        if is_location {
            readable.push_str(&rest[..at]);
            rest = &location[path_end..];
        } else {
            readable.push_str(&rest[..at + 4]);
            rest = location;
        }
    }
    readable.push_str(rest);
    without_single_wrappers(readable.trim_end())
}

/// `text` with Zenoh's debug form of one endpoint, `Single(<endpoint>)` (as in "Unable to
/// connect to any of [Single(tcp/…)]!"), shown as the endpoint alone.
fn without_single_wrappers(text: &str) -> String {
    const SINGLE: &str = "Single(";
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(SINGLE) {
        let inner = &rest[at + SINGLE.len()..];
        let Some(end) = inner.find(')') else { break };
        out.push_str(&rest[..at]);
        out.push_str(&inner[..end]);
        rest = &inner[end + 1..];
    }
    out.push_str(rest);
    out
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
        let cause = source
            .downcast_ref::<ZenohCause>()
            .expect("carried as it came");
        assert!(cause.0.downcast_ref::<std::io::Error>().is_some());
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
    fn zenoh_messages_read_without_source_locations_or_debug_wrapping() {
        let bad = NetworkOptions {
            listen: vec!["foo".into()],
            ..Default::default()
        }
        .to_zenoh_config(Role::Engine)
        .unwrap_err();
        let message = full_message(&bad);
        assert!(
            message.contains("Endpoints must be of the form"),
            "{message}"
        );
        assert!(
            !message.contains("Json5Err") && !message.contains(".rs:"),
            "{message}"
        );
        assert_eq!(
            readable_zenoh_message(
                "Json5Err(Message { msg: \"bad \\\"x\\\" at /a/b/c.rs:12.\", location: None }) \
                 at /z/config.rs:86."
            ),
            "bad \"x\""
        );
        assert_eq!(
            readable_zenoh_message("refused at /z/link.rs:7. Retry at noon, at 12.rs:x"),
            "refused Retry at noon, at 12.rs:x"
        );
        assert_eq!(
            readable_zenoh_message(
                "Unable to connect to any of [Single(tcp/127.0.0.1:1), Single(tcp/[::1]:2)]! \
                 at /z/orchestrator.rs:447."
            ),
            "Unable to connect to any of [tcp/127.0.0.1:1, tcp/[::1]:2]!"
        );
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
