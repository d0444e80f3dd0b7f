//! Robots behind one object-safe trait: the [`SerialChain`] (e.g. the Franka [`panda`])
//! and the planar [`PointMass2d`].

mod panda;
mod point_mass;
mod rigid_body;
mod serial_chain;

pub use crate::algorithm::DynamicsError;
pub use crate::model::{Frame, JointLimits, LockedJoint};
pub use panda::{PANDA_ARMATURE, PANDA_HOME, PANDA_URDF, panda, panda_from_dh, panda_limits};
pub use point_mass::PointMass2d;
pub use rigid_body::Robot;
pub use serial_chain::{SerialChain, UrdfOptions};
