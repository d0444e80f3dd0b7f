//! The pouring expert: resolved-acceleration control of the cup's spout and orientation,
//! with the Panda's redundancy resolved toward a fixed nominal posture.
//!
//! Task space (world frame): the spout position `p` and the cup orientation `R`. The
//! desired motion is a first-order system toward the pour point `p*` with an orientation
//! that tilts only near it,
//!
//! `ṗ_des = sat(−k_p (p − p*))`, `ω_des = k_o log(R_des(p) Rᵀ)`,
//! `R_des(p) = Rot(w, θ_des(‖p − p*‖)) R_upright`,
//!
//! where `θ_des` is a smooth step from 0 (farther than [`TILT_START`]) to
//! [`POUR_TILT`] (closer than [`TILT_END`]) and `w = up × u` tilts the cup's opening toward
//! the pour direction `u`. So the cup travels upright to the pre-pour pose above the lip,
//! then tilts. Joint accelerations follow by [`resolved_acceleration`] of the spout's
//! twist `(ṗ_des, ω_des)`.
//!
//! Every term is continuous in the state and the context, and the posture term pins the
//! null-space motion to `q_nom`, so the joint-space solution varies continuously with the
//! pot's pose (tested).

use ciflow_engine::math::{DVector, Isometry3, Matrix3, Vector3};
use ciflow_engine::robot::{DynamicsError, Robot};
use nalgebra::{Rotation3, Unit};

use super::resolved_acceleration::{Gains, cap, resolved_acceleration};

/// Tilt of the cup while pouring, rad.
pub const POUR_TILT: f64 = 1.45;
/// Distance of the spout from the pour point where tilting starts, m.
pub const TILT_START: f64 = 0.05;
/// Distance under which the cup is fully tilted, m.
pub const TILT_END: f64 = 0.012;
/// The cup in the hand frame: its centre, opening axis, spout direction and size.
pub const CUP_CENTRE: [f64; 3] = [0.0, 0.0, 0.11];
pub const CUP_HALF_HEIGHT: f64 = 0.05;
pub const CUP_RADIUS: f64 = 0.035;

const POSITION_GAIN: f64 = 1.5;
const MAX_SPEED: f64 = 0.15;
const ORIENTATION_GAIN: f64 = 3.0;
const MAX_ANGULAR_SPEED: f64 = 1.5;
const GAINS: Gains = Gains {
    velocity: 12.0,
    posture: 10.0,
    posture_damping: 6.0,
    damping: 0.02,
};

/// The cup rigidly held by the hand.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CupPose {
    /// Spout: the rim point on the pouring side, m.
    pub spout: Vector3,
    /// Centre of the cup's bottom and top, m (for drawing).
    pub bottom: Vector3,
    pub top: Vector3,
    /// Opening axis (up when upright).
    pub axis: Vector3,
    /// Orientation of the hand, whose frame fixes the cup's.
    pub hand: Matrix3,
}

impl CupPose {
    /// The cup of a hand at `hand`. In the hand frame the opening axis is `−z` and the
    /// spout lies toward `+x`, so the cup is upright for the Panda's home posture.
    pub fn of_hand(hand: &Isometry3) -> Self {
        let rotation = hand.rotation.to_rotation_matrix().into_inner();
        let axis = -rotation.column(2).into_owned();
        let forward = rotation.column(0).into_owned();
        let centre = hand * nalgebra::Point3::from(Vector3::from(CUP_CENTRE));
        let top = centre.coords + CUP_HALF_HEIGHT * axis;
        Self {
            spout: top + CUP_RADIUS * forward,
            bottom: centre.coords - CUP_HALF_HEIGHT * axis,
            top,
            axis,
            hand: rotation,
        }
    }

    /// The spout in the hand frame (for the Jacobian).
    pub fn spout_in_hand() -> Vector3 {
        Vector3::from(CUP_CENTRE) - CUP_HALF_HEIGHT * Vector3::z() + CUP_RADIUS * Vector3::x()
    }

    /// Angle between the opening axis and the vertical, rad.
    pub fn tilt(&self) -> f64 {
        self.axis.dot(&Vector3::z()).clamp(-1.0, 1.0).acos()
    }
}

/// Where and which way to pour, from the pot's pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PourTarget {
    /// Where the spout should be while pouring, m.
    pub point: Vector3,
    /// Horizontal unit vector the cup's opening tilts toward.
    pub direction: Vector3,
}

impl PourTarget {
    /// Hand orientation with the cup tilted by `tilt` toward the pour direction:
    /// `Rot(up × u, tilt) [u, −(up × u)... ]`, i.e. hand `x = u`, hand `z = −up` at zero tilt.
    pub fn hand_orientation(&self, tilt: f64) -> Matrix3 {
        let up = Vector3::z();
        let x = self.direction;
        let z = -up;
        let upright = Matrix3::from_columns(&[x, z.cross(&x), z]);
        let axis = Unit::new_normalize(up.cross(&self.direction));
        Rotation3::from_axis_angle(&axis, tilt).into_inner() * upright
    }
}

/// Smooth step `3s² − 2s³` of `s` clamped to `[0, 1]`.
fn smoothstep(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// Desired tilt for a spout `distance` m from the pour point.
pub fn desired_tilt(distance: f64) -> f64 {
    POUR_TILT * smoothstep((TILT_START - distance) / (TILT_START - TILT_END))
}

/// The expert's joint accelerations for state `(q, q̇)`.
pub fn expert_acceleration(
    robot: &dyn Robot,
    target: &PourTarget,
    nominal: &[f64],
    q: &[f64],
    qd: &[f64],
) -> Result<DVector, DynamicsError> {
    let frame = robot.end_effector();
    let hand = robot.frame_placement(q, frame)?;
    let cup = CupPose::of_hand(&hand);
    let offset = cup.spout - target.point;
    let velocity = cap(-POSITION_GAIN * offset, MAX_SPEED);
    let desired = target.hand_orientation(desired_tilt(offset.norm()));
    let error = Rotation3::from_matrix_unchecked(desired * cup.hand.transpose()).scaled_axis();
    let angular = cap(ORIENTATION_GAIN * error, MAX_ANGULAR_SPEED);

    let desired_twist = DVector::from_iterator(6, velocity.iter().chain(angular.iter()).copied());
    resolved_acceleration(
        robot,
        frame,
        &CupPose::spout_in_hand(),
        &desired_twist,
        nominal,
        &GAINS,
        q,
        qd,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_upright_hand_orientation_is_the_home_one_for_forward_pouring() {
        let target = PourTarget {
            point: Vector3::zeros(),
            direction: Vector3::x(),
        };
        let home = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
        assert!((target.hand_orientation(0.0) - home).norm() < 1e-12);
        // Tilting turns the opening toward the pour direction by exactly the tilt.
        let tilted = target.hand_orientation(0.7);
        let axis = -tilted.column(2).into_owned();
        assert!((axis.dot(&Vector3::z()).acos() - 0.7).abs() < 1e-12);
        assert!(axis.x > 0.0);
    }

    #[test]
    fn tilt_is_zero_far_away_and_full_at_the_pour_point() {
        assert_eq!(desired_tilt(0.2), 0.0);
        assert_eq!(desired_tilt(TILT_START), 0.0);
        assert_eq!(desired_tilt(0.0), POUR_TILT);
        let mid = desired_tilt((TILT_START + TILT_END) / 2.0);
        assert!((mid - POUR_TILT / 2.0).abs() < 1e-12);
    }
}
