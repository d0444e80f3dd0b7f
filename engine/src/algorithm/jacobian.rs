//! Geometric Jacobians and the joint torques of an external wrench.

use super::kinematics::body_placement;
use super::{DynamicsError, check_len, check_matrix_shape, check_vector};
use crate::math::{DMatrix, DVector, Real, Vector3};
use crate::model::{JointKind, Model};
use crate::spatial::Se3;

/// The geometric Jacobian `J(q)` (6 × n, world-aligned, rows `[linear; angular]`) of the
/// point `point` (coordinates in frame `frame`): `[ṗ; ω] = J(q) q̇`. Column `j` is
/// `[zⱼ × (p − oⱼ); zⱼ]` for a revolute joint and `[zⱼ; 0]` for a prismatic one that moves
/// the frame (`zⱼ`, `oⱼ` the world axis and origin of joint `j`), zero otherwise.
pub fn frame_jacobian(
    model: &Model,
    q: &[Real],
    frame: usize,
    point: &Vector3,
    jacobian: &mut DMatrix,
) -> Result<(), DynamicsError> {
    check_matrix_shape("jacobian", jacobian, 6, model.nv())?;
    let target = super::frame_placement(model, q, frame)?.act_point(point);
    jacobian.fill(0.0);
    let body = model.frames()[frame].body;
    for_each_joint_axis(model, q, body, |j, kind, axis, origin| {
        let (linear, angular) = match kind {
            JointKind::Revolute => (axis.cross(&(target - origin)), axis),
            JointKind::Prismatic => (axis, Vector3::zeros()),
        };
        jacobian.fixed_view_mut::<3, 1>(0, j).copy_from(&linear);
        jacobian.fixed_view_mut::<3, 1>(3, j).copy_from(&angular);
    });
    Ok(())
}

/// The joint torques `τ = J(q)ᵀ w` of a wrench `w = (force, torque)` (world-aligned)
/// applied at the origin `p` of movable link `link`: `τⱼ = zⱼ · (torque + (p − oⱼ) × force)`
/// for a revolute joint and `zⱼ · force` for a prismatic one that moves the link, zero
/// otherwise.
pub fn wrench_to_joint_torque(
    model: &Model,
    q: &[Real],
    link: usize,
    force: &Vector3,
    torque: &Vector3,
    tau: &mut DVector,
) -> Result<(), DynamicsError> {
    check_vector("q", q, model.nv())?;
    check_vector("force", force.as_slice(), 3)?;
    check_vector("torque", torque.as_slice(), 3)?;
    check_len("tau", tau.len(), model.nv())?;
    if link >= model.nv() {
        return Err(DynamicsError::NoSuchLink {
            index: link,
            count: model.nv(),
        });
    }
    let point = body_placement(model, q, Some(link)).translation;
    tau.fill(0.0);
    for_each_joint_axis(model, q, Some(link), |j, kind, axis, origin| {
        tau[j] = match kind {
            JointKind::Revolute => axis.dot(&(torque + (point - origin).cross(force))),
            JointKind::Prismatic => axis.dot(force),
        };
    });
    Ok(())
}

/// Calls `visit(j, kind, zⱼ, oⱼ)` with the kind, world axis and origin of each joint
/// moving `body`.
fn for_each_joint_axis(
    model: &Model,
    q: &[Real],
    body: Option<usize>,
    mut visit: impl FnMut(usize, JointKind, Vector3, Vector3),
) {
    let count = body.map_or(0, |b| b + 1);
    let mut o_m = Se3::identity();
    for (j, (body, &qj)) in model.bodies()[..count].iter().zip(q).enumerate() {
        o_m = o_m * body.joint.transform(qj);
        let joint = &body.joint;
        visit(j, joint.kind, o_m.rotation * joint.axis, o_m.translation);
    }
}
