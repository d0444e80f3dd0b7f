//! # ciflow-envs
//!
//! The paper's tasks as environments with Gymnasium semantics ([`Env`]): observation and
//! action spaces, seeded `reset`, `step`, `render`, plus what a learning-from-demonstration
//! workflow needs on top — the expert's action, context changes and perturbations during
//! an episode — and the demonstration [`dataset`] format (Minari's Arrow layout).
//!
//! Tasks: [`tasks::limit_cycle`], [`tasks::obstacle_avoidance`], [`tasks::pouring`],
//! [`tasks::lasa`]; list them with
//! [`tasks()`], build them with [`make`].

pub mod actor;
pub mod arm;
pub mod dataset;
pub mod env;
pub mod error;
pub mod expert;
pub mod info;
pub mod kwargs;
pub mod lasa;
pub mod learning_curve;
pub mod planar;
pub mod python;
pub mod raster;
pub mod recipes;
pub mod registry;
pub mod rollout;
pub mod scene;
pub mod seeding;
pub mod shading;
mod simulated;
pub mod space;
pub mod tasks;
pub mod trail;
pub mod vitruvian;

pub use env::{Env, EnvError, EnvSpec, Info, ResetOptions, Step, StepOutcome};
pub use registry::{make, make_with, tasks};
pub use space::{BoxSpace, Dtype};
