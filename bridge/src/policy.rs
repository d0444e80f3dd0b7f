//! The hook through which an engine serves loaded policies on `…/policy/<name>/act`:
//! an observation in, the policy's desired acceleration out.

use crate::protocol::PolicyInfo;

/// Why a policy could not produce an action.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PolicyError(pub String);

/// A policy evaluated by the engine. Implementations must be cheap to call concurrently
/// (`&self`): several clients may ask at once.
pub trait Policy: Send + Sync {
    /// Name, task and dimensions, as listed in the `tasks` reply.
    fn info(&self) -> PolicyInfo;

    /// `a = π(o)` for one observation of `info().observation_dim` elements.
    fn act(&self, observation: &[f64]) -> Result<Vec<f64>, PolicyError>;
}
