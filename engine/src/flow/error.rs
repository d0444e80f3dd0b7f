//! Typed errors of the flow module.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum FlowError {
    #[error("{what}: expected dimension {expected}, got {found}")]
    Dimension {
        what: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("{what} contains a non-finite value (NaN or infinity)")]
    NonFinite { what: &'static str },
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    #[error("checkpoint is for task `{found}`, expected task `{expected}`")]
    TaskMismatch { expected: String, found: String },
    #[error("checkpoint holds a `{found}` model, expected a `{expected}` model")]
    ModelMismatch {
        expected: &'static str,
        found: &'static str,
    },
    #[error("weight `{name}` is missing from the checkpoint")]
    MissingTensor { name: String },
    #[error("weight `{name}` has shape {found:?}, the configuration needs {expected:?}")]
    ShapeMismatch {
        name: String,
        expected: Vec<usize>,
        found: Vec<usize>,
    },
    #[error("weight `{name}` is not part of this architecture")]
    UnexpectedTensor { name: String },
    #[error("weight `{name}` has unsupported dtype {dtype} (expected F64 or F32)")]
    UnsupportedDtype { name: String, dtype: String },
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("malformed configuration {path}: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("malformed checkpoint configuration: {0}")]
    ConfigText(serde_json::Error),
    #[error("malformed safetensors file: {0}")]
    SafeTensors(#[from] safetensors::SafeTensorError),
}

pub type FlowResult<T> = Result<T, FlowError>;

pub(crate) fn invalid(message: String) -> FlowError {
    FlowError::InvalidConfig(message)
}

/// Checks a slice's length.
pub(crate) fn check_dim(what: &'static str, expected: usize, values: &[f64]) -> FlowResult<()> {
    if values.len() != expected {
        return Err(FlowError::Dimension {
            what,
            expected,
            found: values.len(),
        });
    }
    Ok(())
}

/// Checks a slice's length and that every entry is finite.
pub(crate) fn check_input(what: &'static str, expected: usize, values: &[f64]) -> FlowResult<()> {
    check_dim(what, expected, values)?;
    if values.iter().any(|v| !v.is_finite()) {
        return Err(FlowError::NonFinite { what });
    }
    Ok(())
}
