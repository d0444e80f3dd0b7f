//! # ciflow-envs
//!
//! The paper's tasks as environments with Gymnasium semantics ([`Env`]): observation and
//! action spaces, seeded `reset`, `step`, `render`, plus what a learning-from-demonstration
//! workflow needs on top — the expert's action, context changes and perturbations during
//! an episode.

pub mod env;
pub mod space;

pub use env::{Env, EnvError, EnvSpec, Info, ResetOptions, Step};
pub use space::{BoxSpace, Dtype};
pub mod registry;
pub use registry::{make, tasks};
