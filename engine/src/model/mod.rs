//! Kinematic and inertial description of a serial chain of revolute joints, in the
//! Pinocchio split: a read-only [`Model`] and a mutable [`Data`] workspace that the
//! [`algorithm`](crate::algorithm)s fill.
//!
//! Body `i` (0-based) is the rigid body moved by joint `i`; its frame is the joint frame.
//! Fixed joints of a URDF are lumped into the inertia of the body they hang from and kept
//! as named [`Frame`]s.

mod data;
mod dh;
mod error;
mod frame;
mod joint;
mod limits;
#[allow(clippy::module_inception)]
mod model;
mod urdf;

pub use data::Data;
pub use dh::ModifiedDh;
pub use error::ModelError;
pub use frame::Frame;
pub use joint::{Joint, JointKind};
pub use limits::JointLimits;
pub use model::{ARMATURE, Body, Model};
pub use urdf::LockedJoint;
