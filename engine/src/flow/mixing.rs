//! Invertible linear mixing `y = L U x + b` (Kingma & Dhariwal 2018, "Glow", §3.2).
//!
//! `L` is unit lower-triangular, `U` upper-triangular with diagonal `exp(s)`, so
//! `det(LU) = exp(Σ s) > 0` for every weight value: the layer is invertible by
//! construction, `log|det| = Σ s`, and the inverse is two triangular solves.

use super::error::FlowResult;
use super::scalar::Scalar;
use super::weights::Weights;

#[derive(Clone, Debug)]
pub struct LuMixing {
    dim: usize,
    /// Row-major; only the strictly lower part is used (unit diagonal implied).
    lower: Vec<f64>,
    /// Row-major; strictly upper part from the weights, diagonal `exp(log_diag)`.
    upper: Vec<f64>,
    bias: Vec<f64>,
    log_det: f64,
}

impl LuMixing {
    pub fn from_weights(weights: &mut Weights, prefix: &str, dim: usize) -> FlowResult<Self> {
        let lower = weights.take(&format!("{prefix}.lower"), &[dim, dim])?;
        let mut upper = weights.take(&format!("{prefix}.upper"), &[dim, dim])?;
        let log_diag = weights.take(&format!("{prefix}.log_diag"), &[dim])?;
        let bias = weights.take(&format!("{prefix}.bias"), &[dim])?;
        for (i, s) in log_diag.iter().enumerate() {
            upper[i * dim + i] = s.exp();
        }
        Ok(Self {
            dim,
            lower,
            upper,
            bias,
            log_det: log_diag.iter().sum(),
        })
    }

    /// `x ← L U x + b`; returns `log|det|`.
    pub fn forward<S: Scalar>(&self, x: &mut [S]) -> f64 {
        let d = self.dim;
        for i in 0..d {
            let row = &self.upper[i * d..(i + 1) * d];
            let mut acc = x[i] * row[i];
            for j in i + 1..d {
                acc += x[j] * row[j];
            }
            x[i] = acc;
        }
        for i in (0..d).rev() {
            let row = &self.lower[i * d..(i + 1) * d];
            let mut acc = x[i] + self.bias[i];
            for j in 0..i {
                acc += x[j] * row[j];
            }
            x[i] = acc;
        }
        self.log_det
    }

    /// `x ← U⁻¹ L⁻¹ (x - b)`; returns `log|det|` of the inverse.
    pub fn inverse<S: Scalar>(&self, x: &mut [S]) -> f64 {
        let d = self.dim;
        for i in 0..d {
            let row = &self.lower[i * d..(i + 1) * d];
            let mut acc = x[i] + (-self.bias[i]);
            for j in 0..i {
                acc += x[j] * (-row[j]);
            }
            x[i] = acc;
        }
        for i in (0..d).rev() {
            let row = &self.upper[i * d..(i + 1) * d];
            let mut acc = x[i];
            for j in i + 1..d {
                acc += x[j] * (-row[j]);
            }
            x[i] = acc * (1.0 / row[i]);
        }
        -self.log_det
    }
}
