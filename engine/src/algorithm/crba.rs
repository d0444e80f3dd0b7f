//! The composite rigid-body algorithm (CRBA): the joint-space inertia matrix `M(q)`.
//! Featherstone (2008), Table 6.2: `Mᵢⱼ = Sⱼᵀ ʲXᵢ* Iᶜᵢ Sᵢ` for `j ⪯ i`, with the composite
//! inertia `Iᶜᵢ = Iᵢ + Σ_children Iᶜ`; the joints' armature adds `diag(I_a)`
//! ([`Model::armature`](crate::model::Model::armature)).

use super::{DynamicsError, check_vector};
use crate::math::{DMatrix, Real};
use crate::model::{Data, Model};

/// The joint-space inertia matrix `M(q)` (n × n, both triangles filled) into `data.m`.
pub fn crba<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
) -> Result<&'d DMatrix, DynamicsError> {
    check_vector("q", q, model.nv())?;
    for (i, body) in model.bodies().iter().enumerate() {
        data.li_m_i[i] = body.joint.transform(q[i]);
    }
    composite_rigid_body(model, data);
    Ok(&data.m)
}

/// The CRBA proper, on the placements `ᵖMᵢ(q)` already in `data.li_m_i` (forward
/// dynamics reuses those of the RNEA).
pub(crate) fn composite_rigid_body(model: &Model, data: &mut Data) {
    let bodies = model.bodies();
    for (ycrb, body) in data.ycrb.iter_mut().zip(bodies) {
        *ycrb = body.inertia;
    }
    for i in (0..bodies.len()).rev() {
        let mut force = data.ycrb[i] * bodies[i].joint.motion_subspace();
        data.m[(i, i)] = bodies[i].joint.project(&force) + model.armature()[i];
        for j in (0..i).rev() {
            force = data.li_m_i[j + 1].act_force(&force);
            let m_ij = bodies[j].joint.project(&force);
            data.m[(i, j)] = m_ij;
            data.m[(j, i)] = m_ij;
        }
        if i > 0 {
            let composite = data.li_m_i[i].act_inertia(&data.ycrb[i]);
            data.ycrb[i - 1] += composite;
        }
    }
}
