//! The composite rigid-body algorithm (CRBA): the joint-space inertia matrix `M(q)`.
//! Featherstone (2008), §6.2, in world coordinates (as Pinocchio's world convention):
//! with `⁰Mᵢ` the placement of body `i`, its motion subspace `Sᵢ` and inertia `Iᵢ` mapped
//! to the base frame, the composite inertia `Iᶜᵢ = Σ_{k ⪰ i} Iₖ` and
//! `Mⱼᵢ = Sⱼᵀ Iᶜᵢ Sᵢ` for `j ⪯ i`; the joints' armature adds `diag(I_a)`
//! ([`Model::armature`](crate::model::Model::armature)).
//!
//! Why world coordinates: the body-frame form carries `Iᶜᵢ Sᵢ` to every ancestor through
//! a chain of dependent force transforms (`n(n−1)/2` of them); here every `Mⱼᵢ` is an
//! independent 6-vector dot product and the composites are plain sums, at the price of
//! one inertia transform per body (the body-frame form needs `n − 1`).

use super::kinematics::{place_bodies, place_joints};
use super::{DynamicsError, check_vector};
use crate::math::{DMatrix, Real};
use crate::model::{Data, Model};

/// The joint-space inertia matrix `M(q)` (n × n, both triangles filled) into `data.m`;
/// also leaves `ᵖMᵢ` in `data.li_m_i` and `⁰Mᵢ` in `data.o_m_i`.
pub fn crba<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
) -> Result<&'d DMatrix, DynamicsError> {
    check_vector("q", q, model.nv())?;
    place_joints(model, data, q);
    bodies_in_world(model, data);
    composite_rigid_body(model, data);
    Ok(&data.m)
}

/// Every body in world coordinates: its placement `⁰Mᵢ` into `data.o_m_i` (from the
/// joints' placements in `data.li_m_i`), its joint's motion subspace `Sᵢ` into
/// `data.s_world` and its own inertia `Iᵢ` (not yet the composite) into `data.ic_world`.
/// Forward dynamics runs its bias forces on them, the Coriolis matrix its rates.
#[inline(always)]
pub(crate) fn bodies_in_world(model: &Model, data: &mut Data) {
    place_bodies(data);
    for (body, (o_m_i, (s_world, ic_world))) in model.bodies().iter().zip(
        data.o_m_i
            .iter()
            .zip(data.s_world.iter_mut().zip(data.ic_world.iter_mut())),
    ) {
        *s_world = o_m_i.act_motion(&body.joint.motion_subspace());
        *ic_world = o_m_i.act_inertia(&body.inertia);
    }
}

/// The CRBA proper on [`bodies_in_world`]'s quantities: the composites `Iᶜᵢ` (in
/// `data.ic_world`, replacing the bodies' own inertias) and `M` into `data.m`.
#[inline(always)]
pub(crate) fn composite_rigid_body(model: &Model, data: &mut Data) {
    let n = model.nv();
    for i in (1..n).rev() {
        let child = data.ic_world[i];
        data.ic_world[i - 1] += child;
    }
    for i in 0..n {
        let force = data.ic_world[i] * data.s_world[i];
        data.m[(i, i)] = force.dot(&data.s_world[i]) + model.armature()[i];
        for j in 0..i {
            let m_ji = force.dot(&data.s_world[j]);
            data.m[(j, i)] = m_ji;
            data.m[(i, j)] = m_ji;
        }
    }
}
