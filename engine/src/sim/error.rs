//! Simulation errors.

use thiserror::Error;

use crate::algorithm::DynamicsError;
use crate::control::ControlError;
use crate::math::Real;
use crate::model::ModelError;

#[derive(Debug, Error)]
pub enum SimError {
    #[error("{name} must be finite and positive, got {value}")]
    InvalidTimeStep { name: &'static str, value: Real },
    #[error("control_dt = {control_dt} is not a whole multiple of physics_dt = {physics_dt}")]
    NotAMultiple { control_dt: Real, physics_dt: Real },
    #[error("invalid robot limits: {0}")]
    Limits(#[from] ModelError),
    #[error("q0[{joint}] = {value} lies outside the joint limits [{min}, {max}]")]
    OutsideLimits {
        joint: usize,
        value: Real,
        min: Real,
        max: Real,
    },
    #[error("invalid perturbation: {0}")]
    InvalidPerturbation(String),
    #[error("the state became non-finite at t = {time} s")]
    NonFiniteState { time: Real },
    #[error(transparent)]
    Dynamics(#[from] DynamicsError),
    #[error(transparent)]
    Control(#[from] ControlError),
}
