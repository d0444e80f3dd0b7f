//! The bounded affine transform of `ciflow_engine::flow::layers::affine` in tch.

use tch::Tensor;

/// `y = x e^s + t`, `s = B tanh(ŝ/B)`; element-wise log-determinants.
pub fn affine(x: &Tensor, params: &Tensor, bound: f64, inverse: bool) -> (Tensor, Tensor) {
    let s = (params.select(2, 0) / bound).tanh() * bound;
    let t = params.select(2, 1);
    if inverse {
        ((x - t) * (-&s).exp(), -s)
    } else {
        (x * s.exp() + t, s)
    }
}
