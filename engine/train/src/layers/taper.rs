//! The taper of `ciflow_engine::flow::layers::taper` in tch: `w(x) = 1 / (1 + (‖x‖²/R²)²)`
//! of the kept coordinates, by which an affine coupling's conditioner outputs are scaled.

use tch::{Kind, Tensor};

/// `w` per row of the kept coordinates `kept` `[B, k]`, as `[B]`.
pub fn taper(kept: &Tensor, radius: f64) -> Tensor {
    let q = kept.square().sum_dim_intlist(1, false, Kind::Double) / (radius * radius);
    (q.square() + 1.0).reciprocal()
}
