//! The Coriolis matrix `C(q, q̇)` that makes `Ṁ − 2C` skew-symmetric.
//!
//! With world-frame body velocities `vₖ`, inertias `Iₖ`, joint motion subspaces `Sⱼ` and
//! their rates `Ṡⱼ = vⱼ × Sⱼ`, the Christoffel-consistent factorisation is
//! `C = Σₖ Jₖᵀ (Iₖ J̇ₖ + Bₖ Jₖ)` with
//! `Bₖ = ½ [(vₖ×*) Iₖ − Iₖ (vₖ×) + (Iₖ vₖ)×̄*]` (S. Echeandia, P. M. Wensing, "Numerical
//! methods to compute the Coriolis matrix and Christoffel symbols for rigid-body
//! systems", J. Comput. Nonlinear Dyn. 2021). For a serial chain, with the composites
//! `Iᶜⱼ = Σ_{k ≥ j} Iₖ` and `Bᶜⱼ = Σ_{k ≥ j} Bₖ`:
//!
//! - `Cᵢⱼ = Sᵢᵀ (Iᶜⱼ Ṡⱼ + Bᶜⱼ Sⱼ)` for `i ≤ j`,
//! - `Cᵢⱼ = (Iᶜᵢ Sᵢ)ᵀ Ṡⱼ + (Bᶜᵢᵀ Sᵢ)ᵀ Sⱼ` for `i > j`.
//!
//! Then `C q̇` is the velocity product of the RNEA and `Ṁ = C + Cᵀ`.

use super::{DynamicsError, check_vector};
use crate::math::{DMatrix, Real};
use crate::model::{Data, Model};
use crate::spatial::{Motion, Se3};

/// `C(q, q̇)` (n × n) into `data.c`; also leaves `⁰Mᵢ` in `data.o_m_i`.
pub fn coriolis_matrix<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
    qd: &[Real],
) -> Result<&'d DMatrix, DynamicsError> {
    check_vector("q", q, model.nv())?;
    check_vector("qd", qd, model.nv())?;
    let n = model.nv();
    let mut o_m_i = Se3::identity();
    let mut v = Motion::zero();
    for (i, body) in model.bodies().iter().enumerate() {
        o_m_i = o_m_i * body.joint.transform(q[i]);
        let s = o_m_i.act_motion(&body.joint.motion_subspace());
        v += s * qd[i];
        let inertia = o_m_i.act_inertia(&body.inertia);
        let inertia_matrix = inertia.to_matrix6();
        data.o_m_i[i] = o_m_i;
        data.s_world[i] = s;
        data.s_dot_world[i] = v.cross(&s);
        data.ic_world[i] = inertia_matrix;
        data.bc_world[i] = (v.cross_force_matrix() * inertia_matrix
            - inertia_matrix * v.cross_matrix()
            + (inertia * v).cross_bar_matrix())
            * 0.5;
    }
    for k in (0..n.saturating_sub(1)).rev() {
        let (ic_child, bc_child) = (data.ic_world[k + 1], data.bc_world[k + 1]);
        data.ic_world[k] += ic_child;
        data.bc_world[k] += bc_child;
    }
    for j in 0..n {
        let s_j = data.s_world[j].to_vector6();
        let s_dot_j = data.s_dot_world[j].to_vector6();
        let column = data.ic_world[j] * s_dot_j + data.bc_world[j] * s_j;
        for i in 0..=j {
            data.c[(i, j)] = data.s_world[i].to_vector6().dot(&column);
        }
    }
    for i in 1..n {
        let s_i = data.s_world[i].to_vector6();
        let inertia_s = data.ic_world[i] * s_i;
        let bias_s = data.bc_world[i].tr_mul(&s_i);
        for j in 0..i {
            data.c[(i, j)] = inertia_s.dot(&data.s_dot_world[j].to_vector6())
                + bias_s.dot(&data.s_world[j].to_vector6());
        }
    }
    Ok(&data.c)
}
