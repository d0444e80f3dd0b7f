//! The hook through which an engine serves loaded policies on `…/policy/<name>/act`:
//! an observation in, the policy's desired acceleration out.

use crate::protocol::PolicyInfo;
use ciflow_envs::actor::{ActorError, Model};
use ciflow_envs::registry::Kwargs;

/// Why a policy could not produce an action.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    /// A checkpoint's actor refused the observation or could not evaluate its model.
    #[error("the checkpoint cannot act")]
    Actor(#[from] ActorError),
    /// The failure of another [`Policy`] implementation.
    #[error("the policy cannot act")]
    Other(#[source] Box<dyn std::error::Error + Send + Sync>),
}

/// A policy evaluated by the engine. Implementations must be cheap to call concurrently
/// (`&self`): several clients and session drivers may ask at once.
pub trait Policy: Send + Sync {
    /// Name, task and dimensions, as listed in the `tasks` reply.
    fn info(&self) -> PolicyInfo;

    /// Writes `a = π(o)` for one observation of `info().observation_dim` elements into
    /// `action` (`info().action_dim` elements).
    fn act_into(&self, observation: &[f64], action: &mut [f64]) -> Result<(), PolicyError>;

    /// The construction arguments of the task it acts in (e.g. `{obstacles: 1}`); a
    /// checkpoint hot-loaded under the policy's name inherits them.
    fn task_kwargs(&self) -> Kwargs {
        Kwargs::new()
    }

    /// The trained model behind the policy, for the closed-loop evaluations an engine
    /// runs (`…/policy/<name>/evaluate`); `None` for policies that are not checkpoints.
    fn model(&self) -> Option<&Model> {
        None
    }

    /// `a = π(o)` as a new vector.
    fn act(&self, observation: &[f64]) -> Result<Vec<f64>, PolicyError> {
        let mut action = vec![0.0; self.info().action_dim as usize];
        self.act_into(observation, &mut action)?;
        Ok(action)
    }
}
