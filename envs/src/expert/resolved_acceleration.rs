//! Resolved-acceleration control of a point on a robot, with the redundancy resolved
//! toward a nominal posture (Siciliano et al., "Robotics", §3.5 and §8.6): the arm
//! experts' joint accelerations for a desired task-space velocity.
//!
//! With `J` the first `m` rows (`m = 3`: the point's linear velocity; `m = 6`: and the
//! angular one) of the world-aligned Jacobian of the point (`m × n`),
//!
//! `q̈ = J⁺_λ (k_v (ẋ_des − J q̇) − J̇ q̇) + (I − J⁺_λ J)(k_n (q_nom − q) − d_n q̇)`,
//! `J⁺_λ = Jᵀ (J Jᵀ + λ² I)⁻¹`:
//!
//! the task velocity is pulled onto `ẋ_des` at rate `k_v` (with `J̇ q̇` by a forward
//! difference along the motion), damped least squares keeps it bounded near
//! singularities, and the null-space term pins the remaining motion to `q_nom`. Every term
//! is continuous in the state and in `ẋ_des`.

use ciflow_engine::math::{DMatrix, DVector, Vector3};
use ciflow_engine::robot::{DynamicsError, Robot};

/// The gains of the law (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gains {
    /// `k_v`, 1/s.
    pub velocity: f64,
    /// `k_n`, 1/s².
    pub posture: f64,
    /// `d_n`, 1/s.
    pub posture_damping: f64,
    /// `λ`, the damping of the least squares.
    pub damping: f64,
}

/// Caps the norm of `v` at `max` (a desired velocity's speed limit).
pub fn cap(v: Vector3, max: f64) -> Vector3 {
    let n = v.norm();
    if n > max { v * (max / n) } else { v }
}

/// `q̈` for the desired task velocity `desired` (its length `m` picks the Jacobian's
/// rows) of `point` (coordinates in `frame`), at state `(q, q̇)`.
#[allow(clippy::too_many_arguments)]
pub fn resolved_acceleration(
    robot: &dyn Robot,
    frame: usize,
    point: &Vector3,
    desired: &DVector,
    nominal: &[f64],
    gains: &Gains,
    q: &[f64],
    qd: &[f64],
) -> Result<DVector, DynamicsError> {
    let (n, m) = (q.len(), desired.len());
    let mut full = DMatrix::zeros(6, n);
    robot.frame_jacobian(q, frame, point, &mut full)?;
    // J̇ q̇ by a forward difference along the motion.
    const H: f64 = 1e-6;
    let ahead: Vec<f64> = q.iter().zip(qd).map(|(q, v)| q + H * v).collect();
    let mut full_ahead = DMatrix::zeros(6, n);
    robot.frame_jacobian(&ahead, frame, point, &mut full_ahead)?;
    let jacobian = full.rows(0, m).into_owned();
    let qd = DVector::from_column_slice(qd);
    let bias = (full_ahead.rows(0, m) - &jacobian) * &qd / H;

    let twist = &jacobian * &qd;
    let task = gains.velocity * (desired - twist) - bias;

    let jjt = &jacobian * jacobian.transpose() + DMatrix::identity(m, m) * gains.damping.powi(2);
    let pseudo_inverse = jacobian.transpose()
        * jjt
            .cholesky()
            .expect("J Jᵀ + λ² I is positive definite")
            .inverse();
    let posture = DVector::from_iterator(
        n,
        (0..n).map(|i| gains.posture * (nominal[i] - q[i]) - gains.posture_damping * qd[i]),
    );
    let null_space = DMatrix::identity(n, n) - &pseudo_inverse * &jacobian;
    Ok(&pseudo_inverse * task + null_space * posture)
}
