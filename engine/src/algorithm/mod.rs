//! Rigid-body algorithms over a [`Model`](crate::model::Model) and its
//! [`Data`](crate::model::Data) workspace, for `M(q) q̈ + C(q, q̇) q̇ + g(q) = τ`.
//!
//! Each algorithm checks its inputs (dimension, finiteness) and returns a
//! [`DynamicsError`] instead of panicking; none allocates.

mod coriolis;
mod crba;
mod error;
mod forward_dynamics;
mod gravity;
mod jacobian;
mod kinematics;
mod rnea;

pub use coriolis::coriolis_matrix;
pub use crba::crba;
pub use error::DynamicsError;
pub use forward_dynamics::forward_dynamics;
pub use gravity::generalized_gravity;
pub use jacobian::{frame_jacobian, wrench_to_joint_torque};
pub use kinematics::{forward_kinematics, frame_placement};
pub use rnea::{nonlinear_effects, rnea};

pub(crate) use error::{check_len, check_matrix_shape, check_vector};
