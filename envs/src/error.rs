//! The environments' error type.

use ciflow_engine::sim::SimError;

use crate::lasa::LasaError;

/// Why an environment call was refused. Never a panic: every bad input has a variant.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    #[error("{what} has {got} elements, expected {expected}")]
    WrongDimension {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error(
        "{what} has {got} numbers; a batch of {envs} environments takes {per_env} (one value \
         for every environment) or {} (one row of {per_env} per environment)",
        envs * per_env
    )]
    BatchDimension {
        what: &'static str,
        per_env: usize,
        envs: usize,
        got: usize,
    },
    #[error("{what} contains a non-finite value (NaN or inf)")]
    NotFinite { what: &'static str },
    #[error("{what} is outside its space: {detail}")]
    OutOfBounds { what: &'static str, detail: String },
    #[error("invalid option `{name}`: {detail}")]
    InvalidOption { name: String, detail: String },
    #[error("the environment needs a `reset`: it was never reset, or its episode ended")]
    NeedsReset,
    #[error("invalid perturbation")]
    InvalidPerturbation(#[source] SimError),
    #[error("simulation failed")]
    Simulation(#[from] SimError),
    /// The LASA data of a shape chosen by an option could not be loaded.
    #[error("invalid option `{option}`: cannot load the LASA shape `{shape}`")]
    Lasa {
        option: &'static str,
        shape: &'static str,
        #[source]
        source: LasaError,
    },
}
