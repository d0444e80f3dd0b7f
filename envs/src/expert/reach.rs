//! The reach expert: the tool point heads straight for the goal at a capped speed,
//! `ṗ_des = cap(−k_p (p − p*), v_max)`, resolved into joint accelerations with the
//! redundancy pinned to a nominal posture ([`resolved_acceleration`]). Continuous in the
//! state and the goal; for an arm of 6 or more joints the null space keeps the posture.

use ciflow_engine::math::{DVector, Vector3};
use ciflow_engine::robot::{DynamicsError, Robot};

use super::resolved_acceleration::{Gains, cap, resolved_acceleration};

/// `k_p`, 1/s: the tool closes 1/e of its distance every 0.5 s once below the cap.
pub const POSITION_GAIN: f64 = 2.0;
/// `v_max`, m/s.
pub const MAX_SPEED: f64 = 0.25;
const GAINS: Gains = Gains {
    velocity: 12.0,
    posture: 10.0,
    posture_damping: 6.0,
    damping: 0.02,
};

/// The expert's joint accelerations for state `(q, q̇)`: the robot's tool frame origin
/// toward `goal` (base frame, m), the rest of the arm toward `nominal`.
pub fn expert_acceleration(
    robot: &dyn Robot,
    goal: &Vector3,
    nominal: &[f64],
    q: &[f64],
    qd: &[f64],
) -> Result<DVector, DynamicsError> {
    let frame = robot.end_effector();
    let tool = robot.frame_placement(q, frame)?.translation.vector;
    let velocity = cap(-POSITION_GAIN * (tool - goal), MAX_SPEED);
    let desired = DVector::from_column_slice(velocity.as_slice());
    resolved_acceleration(
        robot,
        frame,
        &Vector3::zeros(),
        &desired,
        nominal,
        &GAINS,
        q,
        qd,
    )
}
