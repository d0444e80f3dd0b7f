//! # ciflow-train
//!
//! Exact maximum-likelihood training of the policies in `ciflow_engine::flow`, with tch.
//! This crate is the only one in the workspace that links libtorch: inference, the
//! environments, the bridge and the Python extension never load it.
//!
//! The tch model ([`policy::FlowModel`]) mirrors the engine's network and latent dynamics
//! parameter for parameter and runs in f64, file for file under the same names ([`nn`],
//! [`layers`], [`latent`], [`policy`]); [`trainer::TrainedFlow::save`] writes a
//! checkpoint directory the pure-Rust `Policy::load` reads. [`baseline`] trains the
//! unconstrained behaviour-cloning MLP used as the stability check's negative control.
//! [`dataset`] reads the demonstrations from a `ciflow demos` dataset; each task's
//! default [`TrainConfig`] is its registry entry's recipe (`ciflow_envs::recipes`), which
//! [`overrides`] replaces setting by setting.

pub mod baseline;
pub mod data;
pub mod dataset;
pub mod error;
pub mod latent;
pub mod layers;
pub mod nn;
pub mod optimise;
pub mod overrides;
pub mod policy;
pub mod synthetic;
pub mod trainer;

pub use baseline::{BaselineTrainConfig, TrainedBaseline, train_baseline};
pub use data::{Contexts, Demonstrations, Episode};
pub use dataset::{Screened, Screening};
pub use error::{TrainError, TrainResult};
pub use optimise::{Keep, OptimConfig, Progress};
pub use overrides::{ContextOverrides, OverrideError, RecipeOverrides};
pub use trainer::{
    DEFAULT_STATE_NOISE, Snapshot, TrainConfig, TrainedFlow, train_flow, train_flow_into,
};
