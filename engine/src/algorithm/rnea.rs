//! The recursive Newton–Euler algorithm (RNEA): inverse dynamics
//! `τ = M(q) q̈ + C(q, q̇) q̇ + g(q)`, and its special case `C q̇ + g` (q̈ = 0).
//! Featherstone (2008), Table 5.1, in body coordinates; gravity enters as the base
//! acceleration `a₀ = −g`. The joints' armature adds `I_a ⊙ q̈`
//! ([`Model::armature`](crate::model::Model::armature)). (`g(q)` alone has a cheaper
//! algorithm of its own, [`generalized_gravity`](super::generalized_gravity).)

use super::kinematics::place_joints;
use super::{DynamicsError, check_vector};
use crate::math::{DVector, Real, Vector3};
use crate::model::{Data, Model};
use crate::spatial::Motion;

/// Inverse dynamics `τ = M(q) q̈ + C(q, q̇) q̇ + g(q)` (all of dimension n) into `data.tau`.
pub fn rnea<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
    qd: &[Real],
    qdd: &[Real],
) -> Result<&'d DVector, DynamicsError> {
    check_vector("q", q, model.nv())?;
    check_vector("qd", qd, model.nv())?;
    check_vector("qdd", qdd, model.nv())?;
    newton_euler(model, data, q, qd, Some(qdd));
    Ok(&data.tau)
}

/// Nonlinear effects `b(q, q̇) = C(q, q̇) q̇ + g(q)` = RNEA with `q̈ = 0`, into `data.nle`.
pub fn nonlinear_effects<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
    qd: &[Real],
) -> Result<&'d DVector, DynamicsError> {
    check_vector("q", q, model.nv())?;
    check_vector("qd", qd, model.nv())?;
    newton_euler(model, data, q, qd, None);
    data.nle.copy_from(&data.tau);
    Ok(&data.nle)
}

/// The two passes of the RNEA into `data.tau`; a missing `qdd` counts as zero.
/// Inputs are already checked.
fn newton_euler(model: &Model, data: &mut Data, q: &[Real], qd: &[Real], qdd: Option<&[Real]>) {
    let bodies = model.bodies();
    let base_acceleration = Motion::new(-model.gravity(), Vector3::zeros());
    place_joints(model, data, q);
    for (i, body) in bodies.iter().enumerate() {
        let li_m_i = data.li_m_i[i];
        let s = body.joint.motion_subspace();
        let (mut v, mut a) = match i {
            0 => (Motion::zero(), li_m_i.act_inv_motion(&base_acceleration)),
            _ => (
                li_m_i.act_inv_motion(&data.v[i - 1]),
                li_m_i.act_inv_motion(&data.a[i - 1]),
            ),
        };
        let joint_velocity = s * qd[i];
        v += joint_velocity;
        a += v.cross(&joint_velocity);
        if let Some(qdd) = qdd {
            a += s * qdd[i];
        }
        let inertia = body.inertia;
        data.f[i] = inertia * a + v.cross_force(&(inertia * v));
        data.v[i] = v;
        data.a[i] = a;
    }
    for i in (0..bodies.len()).rev() {
        data.tau[i] = bodies[i].joint.project(&data.f[i]);
        if let Some(qdd) = qdd {
            data.tau[i] += model.armature()[i] * qdd[i];
        }
        if i > 0 {
            let f_parent = data.li_m_i[i].act_force(&data.f[i]);
            data.f[i - 1] += f_parent;
        }
    }
}
