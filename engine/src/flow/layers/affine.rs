//! Affine coupling transform (Dinh et al. 2017, "Real NVP") with a bounded log-scale:
//! `y = x·e^s + t`, `s = B·tanh(ŝ/B)`. Because `|s| < B` the layer can neither overflow
//! nor collapse far from the data, and `log|dy/dx| = s`.

use crate::nn::scalar::Scalar;

#[derive(Clone, Copy, Debug)]
pub struct AffineTransform {
    pub scale_bound: f64,
}

impl AffineTransform {
    #[inline(always)]
    fn log_scale<S: Scalar>(&self, raw: S) -> S {
        (raw * (1.0 / self.scale_bound)).tanh() * self.scale_bound
    }

    /// `params = [ŝ, t]`; returns `(y, log|dy/dx|)`.
    #[inline(always)]
    pub fn forward<S: Scalar>(&self, x: S, params: &[S]) -> (S, S) {
        let s = self.log_scale(params[0]);
        (x * s.exp() + params[1], s)
    }

    /// Returns `(x, log|dx/dy|)`.
    #[inline(always)]
    pub fn inverse<S: Scalar>(&self, y: S, params: &[S]) -> (S, S) {
        let s = self.log_scale(params[0]);
        ((y - params[1]) * (-s).exp(), -s)
    }
}
