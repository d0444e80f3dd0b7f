//! Invertible linear mixing `y = L U x + b` (Kingma & Dhariwal 2018, "Glow", §3.2).
//!
//! `L` is unit lower-triangular, `U` upper-triangular with diagonal `exp(s)`, so
//! `det(LU) = exp(Σ s) > 0` for every weight value: the layer is invertible by
//! construction, `log|det| = Σ s`, and `W⁻¹ = U⁻¹ L⁻¹` follows from two triangular solves
//! (done once, at load time).

use crate::flow::checkpoint::names::{self, BIAS, LOG_DIAG, LOWER, UPPER};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::FlowResult;
use crate::nn::scalar::Scalar;

#[derive(Clone, Debug)]
pub struct LuMixing {
    dim: usize,
    /// `W = L U`, row-major.
    matrix: Vec<f64>,
    bias: Vec<f64>,
    /// `W⁻¹ = U⁻¹ L⁻¹`, row-major.
    inverse_matrix: Vec<f64>,
    /// `W⁻¹ b`.
    inverse_shift: Vec<f64>,
    log_det: f64,
}

impl LuMixing {
    /// Multiplies the factors out once: a dense `d × d` product is one short loop per
    /// row, cheaper than two triangular sweeps of ever-changing length at small `d`.
    pub fn from_weights(weights: &mut Weights, prefix: &str, dim: usize) -> FlowResult<Self> {
        let lower = weights.take(&names::name(&[&prefix, &LOWER]), &[dim, dim])?;
        let mut upper = weights.take(&names::name(&[&prefix, &UPPER]), &[dim, dim])?;
        let log_diag = weights.take(&names::name(&[&prefix, &LOG_DIAG]), &[dim])?;
        let bias = weights.take(&names::name(&[&prefix, &BIAS]), &[dim])?;
        for (i, s) in log_diag.iter().enumerate() {
            upper[i * dim + i] = s.exp();
        }
        let (mut matrix, mut inverse_matrix) = (vec![0.0; dim * dim], vec![0.0; dim * dim]);
        let mut column = vec![0.0; dim];
        for j in 0..dim {
            column.fill(0.0);
            column[j] = 1.0;
            lu_multiply(&lower, &upper, &mut column);
            for (i, v) in column.iter().enumerate() {
                matrix[i * dim + j] = *v;
            }
            column.fill(0.0);
            column[j] = 1.0;
            lu_solve(&lower, &upper, &mut column);
            for (i, v) in column.iter().enumerate() {
                inverse_matrix[i * dim + j] = *v;
            }
        }
        let mut inverse_shift = bias.clone();
        lu_solve(&lower, &upper, &mut inverse_shift);
        Ok(Self {
            dim,
            matrix,
            bias,
            inverse_matrix,
            inverse_shift,
            log_det: log_diag.iter().sum(),
        })
    }

    /// `x ← W x + b`; returns `log|det|`. `buffer` holds at least `d` values.
    pub fn forward<S: Scalar>(&self, x: &mut [S], buffer: &mut [S]) -> f64 {
        self.affine(&self.matrix, Some((&self.bias, 1.0)), x, buffer);
        self.log_det
    }

    /// `dx ← W dx`, the tangent of [`forward`](Self::forward) (the layer is affine).
    pub fn tangent<S: Scalar>(&self, dx: &mut [S], buffer: &mut [S]) {
        self.affine(&self.matrix, None, dx, buffer);
    }

    /// `x ← W x + b` and `dx ← W dx` in one sweep over `W`; `buffer` holds `2 d` values.
    pub fn forward_with_tangent(&self, x: &mut [f64], dx: &mut [f64], buffer: &mut [f64]) {
        let d = self.dim;
        let (x, dx) = (&mut x[..d], &mut dx[..d]);
        let (values, tangents) = buffer[..2 * d].split_at_mut(d);
        for (i, (value, tangent)) in values.iter_mut().zip(tangents.iter_mut()).enumerate() {
            let row = &self.matrix[i * d..(i + 1) * d];
            let (mut acc, mut acc_tangent) = (self.bias[i], 0.0);
            for ((w, xj), dj) in row.iter().zip(&*x).zip(&*dx) {
                acc += xj * w;
                acc_tangent += dj * w;
            }
            *value = acc;
            *tangent = acc_tangent;
        }
        x.copy_from_slice(values);
        dx.copy_from_slice(tangents);
    }

    /// `x ← W⁻¹ (x - b)`; returns `log|det|` of the inverse.
    pub fn inverse<S: Scalar>(&self, x: &mut [S], buffer: &mut [S]) -> f64 {
        self.affine(
            &self.inverse_matrix,
            Some((&self.inverse_shift, -1.0)),
            x,
            buffer,
        );
        -self.log_det
    }

    /// `x ← M x + sign · shift`.
    #[inline]
    fn affine<S: Scalar>(
        &self,
        matrix: &[f64],
        shift: Option<(&[f64], f64)>,
        x: &mut [S],
        buffer: &mut [S],
    ) {
        let d = self.dim;
        let (x, buffer) = (&mut x[..d], &mut buffer[..d]);
        for (i, out) in buffer.iter_mut().enumerate() {
            let row = &matrix[i * d..(i + 1) * d];
            let mut acc = S::constant(shift.map_or(0.0, |(s, sign)| sign * s[i]));
            for (xj, w) in x.iter().zip(row) {
                acc += *xj * *w;
            }
            *out = acc;
        }
        x.copy_from_slice(buffer);
    }
}

/// `x ← L U x` in place (`L` unit lower-triangular, `U` upper-triangular, row-major).
fn lu_multiply(lower: &[f64], upper: &[f64], x: &mut [f64]) {
    let d = x.len();
    for i in 0..d {
        x[i] = (i..d).map(|j| upper[i * d + j] * x[j]).sum();
    }
    for i in (0..d).rev() {
        x[i] += (0..i).map(|j| lower[i * d + j] * x[j]).sum::<f64>();
    }
}

/// `x ← U⁻¹ L⁻¹ x` in place: forward then backward substitution.
fn lu_solve(lower: &[f64], upper: &[f64], x: &mut [f64]) {
    let d = x.len();
    for i in 0..d {
        x[i] -= (0..i).map(|j| lower[i * d + j] * x[j]).sum::<f64>();
    }
    for i in (0..d).rev() {
        let tail: f64 = (i + 1..d).map(|j| upper[i * d + j] * x[j]).sum();
        x[i] = (x[i] - tail) / upper[i * d + i];
    }
}
