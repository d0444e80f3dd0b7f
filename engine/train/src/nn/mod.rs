//! The neural-network numerics of `ciflow_engine::nn` in tch.

use tch::{Kind, Tensor};

pub mod mlp;

/// `values` as an f64 row `[1, n]`, to broadcast over a batch.
pub(crate) fn row(values: &[f64]) -> Tensor {
    Tensor::from_slice(values)
        .to_kind(Kind::Double)
        .reshape([1, -1])
}
