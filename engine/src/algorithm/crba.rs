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

use super::kinematics::place_joints;
use super::{DynamicsError, check_vector};
use crate::math::{DMatrix, Real};
use crate::model::{Data, Model};
use crate::spatial::{Inertia, Se3};

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
    // One pass, placements included: their chain is serial, and each body's own
    // transforms beside it give the CPU independent work while it waits.
    let mut o_m_i = Se3::identity();
    let bodies = (data.li_m_i.iter().zip(&mut data.o_m_i))
        .zip(data.s_world.iter_mut().zip(&mut data.ic_world));
    for (body, ((li_m_i, o_m), (s_world, ic_world))) in model.bodies().iter().zip(bodies) {
        o_m_i = o_m_i * *li_m_i;
        *o_m = o_m_i;
        *s_world = body.joint.motion_subspace_in(&o_m_i);
        *ic_world = o_m_i.act_inertia(&body.inertia);
    }
}

/// The CRBA proper on [`bodies_in_world`]'s quantities: the composites `Iᶜᵢ` (in
/// `data.ic_world`, replacing the bodies' own inertias) and `M` into `data.m`.
#[inline(always)]
pub(crate) fn composite_rigid_body(model: &Model, data: &mut Data) {
    let n = model.nv();
    // The running composite stays in registers: adding each child into its parent's slot
    // would reload, every step, what the step before had just stored.
    let mut composite = Inertia::zero();
    for i in (0..n).rev() {
        composite += data.ic_world[i];
        data.ic_world[i] = composite;
        let force = composite * data.s_world[i];
        data.m[(i, i)] = force.dot(&data.s_world[i]) + model.armature()[i];
        for j in 0..i {
            let m_ji = force.dot(&data.s_world[j]);
            data.m[(j, i)] = m_ji;
            data.m[(i, j)] = m_ji;
        }
    }
}
