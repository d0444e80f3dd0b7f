//! # ciflow-evaluation
//!
//! Every measurement of a trained policy, in one place, without libtorch (evaluating a
//! checkpoint never links the trainer):
//!
//! - [`closed_loop`]: the policy (or the task's expert) acting in its task's environment —
//!   success, collision and spill rates, final distances — under the pushes of [`push`]
//!   and mid-motion context changes, divided into the episodes that replay demonstrations
//!   the model fitted and those its training held out;
//! - [`likelihood`]: the log-likelihood per transition of a flow on a dataset;
//! - [`stability`]: noise-free rollouts in observation space from starts far outside the
//!   data, with a negative control that the check must catch; [`robot_loop`]: the same
//!   through computed torque and the arm's rigid-body dynamics with its real limits;
//!   [`stability_check`]: both, as `ciflow stability` runs them on a checkpoint;
//! - [`rollout`] and [`field`]: the noise-free rollouts and the vector-field and
//!   latent-grid figures of 2-D policies;
//! - [`lasa`]: the LASA handwriting benchmark's reproductions and scores.

pub mod closed_loop;
pub mod error;
pub mod field;
pub mod lasa;
pub mod likelihood;
pub mod push;
pub mod robot_loop;
pub mod rollout;
pub mod stability;
pub mod stability_check;
pub mod summary;
pub mod trace;

pub use closed_loop::*;
pub use error::{EvaluationError, EvaluationResult};
pub use push::{PushConfig, PushOutcome, PushSummary};
pub use summary::Summary;
pub use trace::{TOOL_POINT_KEYS, Trace};
