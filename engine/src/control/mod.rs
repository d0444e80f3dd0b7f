//! The computed-torque layer between a policy's desired accelerations and the robot.

mod computed_torque;
mod joint_mask;

pub use computed_torque::{ComputedTorque, ControlError, Saturation};
pub use joint_mask::JointMask;
