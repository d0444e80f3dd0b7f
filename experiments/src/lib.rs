//! # ciflow-experiments
//!
//! Experiments that train policies and then measure them, end to end in one run: the
//! trainer ([`ciflow_train`], libtorch) fits the models, the evaluation home
//! ([`ciflow_evaluation`], no libtorch) scores them, and this crate puts the two together
//! and writes the reports.
//!
//! - [`lasa`]: the LASA handwriting benchmark — per shape, a stable flow against the
//!   unconstrained behaviour-cloning baseline trained in the same run on the same data,
//!   with settings of its own — and
//!   [`lasa::ablation`], what each choice of the flow's recipe buys.

pub mod error;
pub mod lasa;

pub use error::{ExperimentError, ExperimentResult};
