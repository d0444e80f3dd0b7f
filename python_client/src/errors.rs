//! Python exceptions for bridge errors.

use ciflow_bridge::BridgeError;
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
    "No ciflow engine answered; the message says how to start one."
);

/// Converts a bridge error into the matching Python exception.
pub fn to_py(error: BridgeError) -> PyErr {
    match error {
        BridgeError::Remote(reply) => Python::attach(|py| {
            let err = CiflowError::new_err(format!("{}: {}", reply.code, reply.message));
            // Setting an attribute on a fresh exception instance cannot fail.
            let _ = err.value(py).setattr("code", reply.code.as_str());
            err
        }),
        BridgeError::NoEngine { .. } | BridgeError::Zenoh(_) => {
            EngineUnreachable::new_err(error.to_string())
        }
        BridgeError::Config(_) | BridgeError::InvalidArgument(_) => {
            PyValueError::new_err(error.to_string())
        }
        BridgeError::BadReply { .. } | BridgeError::FrameLost { .. } => {
            CiflowError::new_err(error.to_string())
        }
    }
}
