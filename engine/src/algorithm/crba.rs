//! The composite rigid-body algorithm (CRBA): the joint-space inertia matrix `M(q)`, with
//! `Mⱼᵢ = Sⱼᵀ Iᶜᵢ Sᵢ` for `j ⪯ i`, `Iᶜᵢ = Σ_{k ⪰ i} Iₖ` the composite inertia of the
//! subtree of body `i` and `Sᵢ` its joint's motion subspace (Featherstone 2008, §6.2);
//! the joints' armature adds `diag(I_a)` ([`Model::armature`](crate::model::Model::armature)).
//!
//! Two forms, both exact, picked by the model:
//!
//! - **In joint frames** (Featherstone's Table 6.2), for chains whose joints all turn
//!   about their own z axis and whose joint placements are axis-aligned
//!   ([`Model::axis_aligned_placements`]: the Panda, the UR5e, the iiwa): the composites
//!   are carried from child to parent, `Iᶜₚ = Iₚ + ᵖXᵢ* Iᶜᵢ ⁱXₚ`, and each column's force
//!   `Fᵢ = Iᶜᵢ Sᵢ` from frame to frame towards the base, `Mⱼᵢ = Sⱼᵀ Fᵢ` in each frame on
//!   the way. With `ᵖXᵢ = (R_p Rz(qᵢ), p)` the steps are cheap: `Sᵢ = (0, e_z)` reads
//!   `Fᵢ`, `Mᵢᵢ` and every `Mⱼᵢ` off entries, `Rz(q)` mixes two coordinates and the
//!   axis-aligned `R_p` only moves entries, so an inertia changes frame in about 60
//!   operations instead of the 130 of a dense transform, and no world placement is
//!   needed. On the Panda: 3 600 instructions instead of 4 400 (Valgrind).
//! - **In world coordinates** (as Pinocchio's world convention), for any chain: with
//!   `⁰Mᵢ` the placement of body `i`, `Sᵢ` and `Iᵢ` are mapped to the base frame, the
//!   composites are plain sums and every `Mⱼᵢ` an independent 6-vector dot product, at the
//!   price of one dense inertia transform per body. Forward dynamics and the Coriolis
//!   matrix share its world quantities ([`bodies_in_world`], [`composite_rigid_body`]).

use super::kinematics::place_joints;
use super::{DynamicsError, check_vector};
use crate::math::{DMatrix, Real, Vector3};
use crate::model::{Data, Model};
use crate::spatial::{AxisAlignedRotation, Force, Inertia, Se3};

/// The joint-space inertia matrix `M(q)` (n × n, both triangles filled) into `data.m`.
pub fn crba<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
) -> Result<&'d DMatrix, DynamicsError> {
    check_vector("q", q, model.nv())?;
    match model.axis_aligned_placements() {
        Some(placements) => crba_in_joint_frames(model, placements, data, q),
        None => crba_in_world(model, data, q),
    }
    Ok(&data.m)
}

/// The CRBA in world coordinates, for any chain (see the module docs); leaves `ᵖMᵢ` in
/// `data.li_m_i`, `⁰Mᵢ` in `data.o_m_i` and the composites in `data.ic_world`.
#[inline(always)]
fn crba_in_world(model: &Model, data: &mut Data, q: &[Real]) {
    place_joints(model, data, q);
    bodies_in_world(model, data);
    composite_rigid_body(model, data);
}

/// The CRBA in joint frames (see the module docs): every joint turns about its z axis and
/// `placements[i]` is the rotation of joint `i`'s placement. Leaves `ᵖMᵢ` in
/// `data.li_m_i`; uses `data.f` as scratch.
#[inline(always)]
fn crba_in_joint_frames(
    model: &Model,
    placements: &[AxisAlignedRotation],
    data: &mut Data,
    q: &[Real],
) {
    let n = model.nv();
    let bodies = model.bodies();
    // The forces cross the joints through their dense transforms `ᵖXᵢ`: for a 6-vector a
    // dense product costs what moving entries does.
    place_joints(model, data, q);
    let (sin, cos) = (&data.sin_q, &data.cos_q);
    let m = data.m.as_mut_slice();
    assert_eq!(m.len(), n * n);
    // The composites, from the tip down: `Iᶜᵢ` in frame `i` stays in registers, and
    // leaves `Fᵢ` and `Mᵢᵢ` behind.
    let mut composite = Inertia::zero();
    for i in (0..n).rev() {
        composite += bodies[i].inertia;
        // `Fᵢ = Iᶜᵢ (0, e_z) = (−h × e_z, I_o e_z)`, and `Mᵢᵢ = e_z · I_o e_z`.
        let (h, rotational) = (&composite.first_moment, &composite.rotational);
        data.f[i] = Force::new(
            Vector3::new(-h.y, h.x, 0.0),
            rotational.column(2).into_owned(),
        );
        m[i + i * n] = rotational[(2, 2)] + model.armature()[i];
        if i > 0 {
            let turned = composite.rotated_about_z(sin[i], cos[i]);
            composite = placements[i]
                .rotate_inertia(&turned)
                .translated(&bodies[i].joint.placement.translation);
        }
    }
    // The forces cross the joints one joint at a time: across joint `j + 1`, every
    // `Fᵢ` with `i > j` moves from frame `j + 1` into frame `j` and gives `Mⱼᵢ`. Those moves
    // are independent of each other, so the CPU overlaps them; column by column, each
    // would wait for the one before. Moving them four at a time, a vector lane each, was
    // slower (258 → 294 ns on an AVX-512 CPU, `bench/dynamics_vs_pinocchio.sh`): most
    // crossings move fewer than four, and the lanes must be filled and read one by one.
    for j in (1..n.saturating_sub(1)).rev() {
        let joint = data.li_m_i[j + 1];
        for (i, force) in data.f.iter_mut().enumerate().skip(j + 1) {
            *force = joint.act_force(force);
            m[j + i * n] = force.angular.z;
        }
    }
    // Across the first joint the forces go no further: only `M₀ᵢ`, the moment's z
    // component in frame 0, is read.
    if n > 1 {
        let joint = data.li_m_i[1];
        for (i, force) in data.f.iter().enumerate().skip(1) {
            m[i * n] = joint.act_force_moment_z(force);
        }
    }
    data.m.fill_lower_triangle_with_upper_triangle();
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

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::math::DVector;
    use crate::robot::panda;

    /// On the Panda (joint frames apply) the two forms give the same matrix, armature
    /// included, over random configurations.
    #[test]
    fn joint_frames_and_world_coordinates_agree() {
        let mut model = panda().model().clone();
        model
            .set_armature(DVector::from_fn(model.nv(), |i, _| 0.05 * (i + 1) as Real))
            .unwrap();
        let placements = model
            .axis_aligned_placements()
            .expect("the Panda is axis-aligned");
        let (mut in_joints, mut in_world) = (Data::new(&model), Data::new(&model));
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let q: Vec<Real> = (0..model.nv())
                .map(|_| rng.random_range(-3.0..3.0))
                .collect();
            crba_in_joint_frames(&model, placements, &mut in_joints, &q);
            crba_in_world(&model, &mut in_world, &q);
            let error = (&in_joints.m - &in_world.m).amax();
            assert!(error < 1e-13 * in_world.m.amax(), "off by {error}");
        }
    }
}
