//! Python exceptions for bridge errors.

use ciflow_bridge::BridgeError;
use ciflow_bridge::error::full_message;
use pyo3::exceptions::{PyConnectionError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

pyo3::create_exception!(
    _native,
    CiflowError,
    PyRuntimeError,
    "An engine refused a request; `code` is the protocol's error code."
);
pyo3::create_exception!(
    _native,
    EngineUnreachable,
    PyConnectionError,
    "No ciflow engine answered, or the one that took a request did not reply in time; the \
     message says which."
);

/// Converts a bridge error into the matching Python exception, whose message names the
/// error's causes too.
pub fn to_py(error: BridgeError) -> PyErr {
    let message = full_message(&error);
    match error {
        BridgeError::Remote(reply) => remote(&reply, ""),
        BridgeError::NoEngine { .. }
        | BridgeError::NoEngineServing { .. }
        | BridgeError::NoReply { .. }
        | BridgeError::Open { .. }
        | BridgeError::Zenoh { .. }
        | BridgeError::Worker(_) => EngineUnreachable::new_err(message),
        // One engine of several: its refusal with its code, unreachable if it was (or went
        // silent); its name in the message.
        BridgeError::Engine { engine, source } => match *source {
            BridgeError::Remote(reply) => remote(&reply, &format!("engine `{engine}`: ")),
            BridgeError::NoEngine { .. }
            | BridgeError::NoReply { .. }
            | BridgeError::Zenoh { .. } => EngineUnreachable::new_err(message),
            // What the caller asked of it was wrong (e.g. a task it does not serve).
            BridgeError::InvalidArgument(_) => PyValueError::new_err(message),
            _ => CiflowError::new_err(message),
        },
        BridgeError::ConfigFile { .. }
        | BridgeError::ConfigSetting { .. }
        | BridgeError::UnknownMode(_)
        | BridgeError::InvalidArgument(_)
        | BridgeError::UnknownTask(_)
        | BridgeError::TaskDefaults { .. }
        | BridgeError::ReadCheckpoint { .. }
        | BridgeError::CheckpointNotUtf8 { .. }
        | BridgeError::CheckpointConfig { .. } => PyValueError::new_err(message),
        BridgeError::CheckpointNotLoaded { .. }
        | BridgeError::BadReply { .. }
        | BridgeError::BadErrorReply { .. }
        | BridgeError::FrameLost { .. }
        | BridgeError::UnexpectedKey { .. } => CiflowError::new_err(message),
    }
}

/// [`CiflowError`] for an engine's refusal, its `code` attribute set.
fn remote(reply: &ciflow_bridge::protocol::ErrorReply, prefix: &str) -> PyErr {
    Python::attach(|py| {
        let err = CiflowError::new_err(format!("{prefix}{}: {}", reply.code, reply.message));
        // Setting an attribute on a fresh exception instance cannot fail.
        let _ = err.value(py).setattr("code", reply.code.as_str());
        err
    })
}
