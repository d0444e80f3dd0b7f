//! Generalized gravity `g(q) = ∂U/∂q`, the gradient of the potential energy
//! `U(q) = −Σₖ mₖ g₀ · cₖ(q)` (`g₀` the gravity vector, `cₖ` body `k`'s centre of mass,
//! all in the base frame).
//!
//! Moving joint `i` moves every body `k ⪰ i` it carries: about the world axis `aᵢ` through
//! the joint origin `pᵢ`, `∂cₖ/∂qᵢ = aᵢ × (cₖ − pᵢ)` (revolute), or along it,
//! `∂cₖ/∂qᵢ = aᵢ` (prismatic). With the subtree's mass `Mᵢ = Σ_{k ⪰ i} mₖ` and first
//! moment `Hᵢ = Σ_{k ⪰ i} mₖ cₖ` (3-vectors),
//!
//! ```text
//! gᵢ = aᵢ · (g₀ × (Hᵢ − Mᵢ pᵢ))    revolute
//! gᵢ = −Mᵢ (g₀ · aᵢ)               prismatic
//! ```
//!
//! Why not the RNEA with `q̇ = q̈ = 0`: that carries spatial accelerations and forces
//! through every joint, where one pass of forward kinematics and a suffix sum of 3-vectors
//! suffice. `tests/rnea.rs` checks the two against each other.

use super::kinematics::{place_bodies, place_joints};
use super::{DynamicsError, check_vector};
use crate::math::{DVector, Real, Vector3};
use crate::model::{Data, JointKind, Model};

/// Generalized gravity `g(q)` (n) into `data.g`; also leaves `ᵖMᵢ` in `data.li_m_i` and
/// `⁰Mᵢ` in `data.o_m_i`.
pub fn generalized_gravity<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
) -> Result<&'d DVector, DynamicsError> {
    check_vector("q", q, model.nv())?;
    let bodies = model.bodies();
    place_joints(model, data, q);
    place_bodies(data);
    // Each body's first moment `mₖ cₖ` in the base frame, in `data.first_moments`.
    for ((body, o_m_i), first_moment) in bodies.iter().zip(&data.o_m_i).zip(&mut data.first_moments)
    {
        *first_moment =
            o_m_i.rotation * body.inertia.first_moment + o_m_i.translation * body.inertia.mass;
    }
    let gravity = model.gravity();
    let (mut mass, mut first_moment) = (0.0, Vector3::zeros());
    for i in (0..bodies.len()).rev() {
        mass += bodies[i].inertia.mass;
        first_moment += data.first_moments[i];
        let (rotation, origin) = (&data.o_m_i[i].rotation, &data.o_m_i[i].translation);
        let axis = rotation * bodies[i].joint.axis;
        data.g[i] = match bodies[i].joint.kind {
            JointKind::Revolute => axis.dot(&gravity.cross(&(first_moment - origin * mass))),
            JointKind::Prismatic => -mass * gravity.dot(&axis),
        };
    }
    Ok(&data.g)
}
