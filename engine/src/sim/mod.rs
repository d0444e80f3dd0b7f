//! Fixed-step simulation of a [`Robot`](crate::robot::Robot) under the computed-torque
//! layer, with external perturbations scheduled in simulated time.

mod config;
mod error;
mod integrator;
mod perturbation;
mod simulator;

pub use config::SimConfig;
pub use error::SimError;
pub use integrator::Integrator;
pub use perturbation::{Perturbation, PerturbationKind};
pub use simulator::{Simulator, StepReport};
