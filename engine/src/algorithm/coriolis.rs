//! The Coriolis matrix `C(q, q̇)` that makes `Ṁ − 2C` skew-symmetric.
//!
//! With world-frame body velocities `vₖ`, inertias `Iₖ`, joint motion subspaces `Sⱼ` and
//! their rates `Ṡⱼ = vⱼ × Sⱼ`, the Christoffel-consistent factorisation is
//! `C = Σₖ Jₖᵀ (Iₖ J̇ₖ + Bₖ Jₖ)` with
//! `Bₖ = ½ [(vₖ×*) Iₖ − Iₖ (vₖ×) + (Iₖ vₖ)×̄*] = ½ [İₖ + (Iₖ vₖ)×̄*]` (S. Echeandia,
//! P. M. Wensing, "Numerical methods to compute the Coriolis matrix and Christoffel symbols
//! for rigid-body systems", J. Comput. Nonlinear Dyn. 2021). For a serial chain, with the
//! composites `Iᶜⱼ = Σ_{k ≥ j} Iₖ`, `İᶜⱼ = Σ_{k ≥ j} İₖ` and `hᶜⱼ = Σ_{k ≥ j} Iₖ vₖ`, so that
//! `Bᶜⱼ x = ½ (İᶜⱼ x + x ×* hᶜⱼ)` and `Bᶜⱼᵀ x = ½ (İᶜⱼ x − x ×* hᶜⱼ)` (`İ` is symmetric,
//! `×̄*` skew):
//!
//! - `Cᵢⱼ = Sᵢᵀ (Iᶜⱼ Ṡⱼ + Bᶜⱼ Sⱼ)` for `i ≤ j`,
//! - `Cᵢⱼ = (Iᶜᵢ Sᵢ)ᵀ Ṡⱼ + (Bᶜᵢᵀ Sᵢ)ᵀ Sⱼ` for `i > j`.
//!
//! Then `C q̇` is the velocity product of the RNEA and `Ṁ = C + Cᵀ`. Every product is a
//! structured spatial operation (no 6 × 6 matrix is formed).

use super::crba::bodies_in_world;
use super::kinematics::place_joints;
use super::{DynamicsError, check_vector};
use crate::math::{DMatrix, Real};
use crate::model::{Data, Model};
use crate::spatial::{Force, Motion};

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
    place_joints(model, data, q);
    bodies_in_world(model, data);
    let mut v = Motion::zero();
    let bodies = data.s_world.iter().zip(&data.ic_world).zip(qd);
    let rates = data
        .s_dot_world
        .iter_mut()
        .zip(data.ic_dot_world.iter_mut().zip(data.hc_world.iter_mut()));
    for (((s, inertia), qd), (s_dot, (ic_dot, hc))) in bodies.zip(rates) {
        v += *s * *qd;
        *s_dot = v.cross(s);
        *ic_dot = inertia.variation(&v);
        *hc = *inertia * v;
    }
    for k in (0..n.saturating_sub(1)).rev() {
        let (ic, ic_dot, hc) = (
            data.ic_world[k + 1],
            data.ic_dot_world[k + 1],
            data.hc_world[k + 1],
        );
        data.ic_world[k] += ic;
        data.ic_dot_world[k] += ic_dot;
        data.hc_world[k] += hc;
    }
    // `2 Bᶜ x` (sign +1) or `2 Bᶜᵀ x` (sign −1) of composite `k`.
    let twice_b = |data: &Data, k: usize, x: &Motion, sign: Real| -> Force {
        data.ic_dot_world[k] * *x + x.cross_force(&data.hc_world[k]) * sign
    };
    for j in 0..n {
        let (s_j, s_dot_j) = (data.s_world[j], data.s_dot_world[j]);
        let column = data.ic_world[j] * s_dot_j + twice_b(data, j, &s_j, 1.0) * 0.5;
        for i in 0..=j {
            data.c[(i, j)] = column.dot(&data.s_world[i]);
        }
    }
    for i in 1..n {
        let s_i = data.s_world[i];
        let inertia_s = data.ic_world[i] * s_i;
        let bt_s = twice_b(data, i, &s_i, -1.0);
        for j in 0..i {
            data.c[(i, j)] = inertia_s.dot(&data.s_dot_world[j]) + 0.5 * bt_s.dot(&data.s_world[j]);
        }
    }
    Ok(&data.c)
}
