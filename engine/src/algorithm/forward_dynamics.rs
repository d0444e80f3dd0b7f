//! Forward dynamics `q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q))` by CRBA, RNEA and an in-place
//! Cholesky factorisation `M = L Lᵀ`.

use super::crba::composite_rigid_body;
use super::{DynamicsError, check_vector, nonlinear_effects};
use crate::math::{DMatrix, DVector, Real};
use crate::model::{Data, Model};

/// `q̈` into `data.ddq`; `data.m` and `data.nle` hold `M(q)` and `C q̇ + g` afterwards.
pub fn forward_dynamics<'d>(
    model: &Model,
    data: &'d mut Data,
    q: &[Real],
    qd: &[Real],
    tau: &[Real],
) -> Result<&'d DVector, DynamicsError> {
    check_vector("tau", tau, model.nv())?;
    // The RNEA leaves the joint placements `ᵖMᵢ(q)` in `data.li_m_i` for the CRBA.
    nonlinear_effects(model, data, q, qd)?;
    composite_rigid_body(model, data);
    data.cholesky.copy_from(&data.m);
    cholesky_in_place(&mut data.cholesky)?;
    for (i, ddq) in data.ddq.iter_mut().enumerate() {
        *ddq = tau[i] - data.nle[i];
    }
    cholesky_solve_in_place(&data.cholesky, &mut data.ddq);
    Ok(&data.ddq)
}

/// Overwrites the lower triangle of the symmetric `matrix` with `L`, `matrix = L Lᵀ`.
fn cholesky_in_place(matrix: &mut DMatrix) -> Result<(), DynamicsError> {
    let n = matrix.nrows();
    for j in 0..n {
        let mut diagonal = matrix[(j, j)];
        for k in 0..j {
            diagonal -= matrix[(j, k)] * matrix[(j, k)];
        }
        // Also rejects a NaN pivot.
        if diagonal.is_nan() || diagonal <= 0.0 {
            return Err(DynamicsError::NotPositiveDefinite);
        }
        let l_jj = diagonal.sqrt();
        matrix[(j, j)] = l_jj;
        for i in j + 1..n {
            let mut value = matrix[(i, j)];
            for k in 0..j {
                value -= matrix[(i, k)] * matrix[(j, k)];
            }
            matrix[(i, j)] = value / l_jj;
        }
    }
    Ok(())
}

/// Solves `L Lᵀ x = b` in place (`b` becomes `x`), `L` the lower triangle of `factor`.
fn cholesky_solve_in_place(factor: &DMatrix, b: &mut DVector) {
    let n = b.len();
    for i in 0..n {
        let mut value = b[i];
        for k in 0..i {
            value -= factor[(i, k)] * b[k];
        }
        b[i] = value / factor[(i, i)];
    }
    for i in (0..n).rev() {
        let mut value = b[i];
        for k in i + 1..n {
            value -= factor[(k, i)] * b[k];
        }
        b[i] = value / factor[(i, i)];
    }
}
