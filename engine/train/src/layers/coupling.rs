//! The conditioned coupling blocks of `ciflow_engine::flow::layers::coupling` in tch,
//! batched over rows, with the same parameter names and floating-point recipe.

use ciflow_engine::flow::layers::context_set::local_sizes;
use ciflow_engine::flow::{CouplingKind, FlowConfig};
use tch::nn;
use tch::{Kind, Tensor};

use super::affine::affine;
use super::spline::rational_quadratic_spline;
use super::taper::taper;
use crate::nn::mlp::Mlp;
use ciflow_engine::flow::checkpoint::names::{CONDITIONER, LOCAL};

/// What the couplings are conditioned on, per row: the conditioning vector `ĉ`
/// `[B, |ĉ|]` and the normalised elements `[B, n, s]` of each context set.
#[derive(Debug)]
pub struct CouplingContext {
    pub encoded: Tensor,
    pub elements: Vec<Tensor>,
}

impl CouplingContext {
    /// The rows of `self`, then those of `other`.
    pub fn cat(&self, other: &Self) -> Self {
        Self {
            encoded: Tensor::cat(&[&self.encoded, &other.encoded], 0),
            elements: self
                .elements
                .iter()
                .zip(&other.elements)
                .map(|(a, b)| Tensor::cat(&[a, b], 0))
                .collect(),
        }
    }
}

/// A conditioned coupling layer (affine or rational-quadratic spline) whose conditioner
/// pools local features of the context's sets when the config has them
/// (`ciflow_engine::flow::layers::conditioner`).
#[derive(Debug)]
pub struct Coupling {
    kind: CouplingKind,
    conditioner: Mlp,
    /// `ψ_k` of every set.
    local: Vec<Mlp>,
    kept: (i64, i64),
    transformed: (i64, i64),
    kept_first: bool,
}

impl Coupling {
    pub fn new(path: &nn::Path, index: usize, config: &FlowConfig) -> Self {
        let (d, k) = (config.state_dim as i64, config.kept_dim() as i64);
        let kept_first = index.is_multiple_of(2);
        let (kept, transformed) = if kept_first {
            ((0, k), (k, d - k))
        } else {
            ((d - k, k), (0, d - k))
        };
        let local = match config.local() {
            Some(local) => (config.context_sets.iter().enumerate())
                .map(|(k, set)| {
                    let sizes =
                        local_sizes(set, config.kept_dim(), config.conditioning_dim(), local);
                    Mlp::new(&(path / LOCAL / k), &sizes, false)
                })
                .collect(),
            None => Vec::new(),
        };
        Self {
            kind: config.coupling.clone(),
            conditioner: Mlp::new(&(path / CONDITIONER), &config.conditioner_sizes(), true),
            local,
            kept,
            transformed,
            kept_first,
        }
    }

    /// Applies the coupling (or its inverse); returns `(output, log|det|)` per row.
    pub fn apply(&self, x: &Tensor, context: &CouplingContext, inverse: bool) -> (Tensor, Tensor) {
        let x_kept = x.narrow(1, self.kept.0, self.kept.1);
        let x_t = x.narrow(1, self.transformed.0, self.transformed.1);
        let rows = x.size()[0];
        let mut inputs = vec![x_kept.shallow_clone()];
        for (psi, elements) in self.local.iter().zip(&context.elements) {
            let count = elements.size()[1];
            let each = |t: &Tensor| t.unsqueeze(1).expand([rows, count, -1], false);
            let input = Tensor::cat(
                &[
                    each(&x_kept),
                    elements.shallow_clone(),
                    each(&context.encoded),
                ],
                2,
            );
            inputs.push(psi.forward(&input).mean_dim(1, false, Kind::Double));
        }
        inputs.push(context.encoded.shallow_clone());
        let input = Tensor::cat(&inputs, 1);
        let params = self
            .conditioner
            .forward(&input)
            .reshape([rows, self.transformed.1, -1]);
        let (y_t, log_det) = match self.kind {
            CouplingKind::Affine {
                scale_bound,
                taper_radius,
            } => {
                let params = match taper_radius {
                    Some(radius) => params * taper(&x_kept, radius).reshape([rows, 1, 1]),
                    None => params,
                };
                affine(&x_t, &params, scale_bound, inverse)
            }
            CouplingKind::Spline { bins, tail_bound } => {
                let p = params.size()[2];
                let (y, ld) = rational_quadratic_spline(
                    &x_t.reshape([-1]),
                    &params.reshape([-1, p]),
                    bins as i64,
                    tail_bound,
                    inverse,
                );
                (y.reshape([rows, -1]), ld.reshape([rows, -1]))
            }
        };
        let y = if self.kept_first {
            Tensor::cat(&[&x_kept, &y_t], 1)
        } else {
            Tensor::cat(&[&y_t, &x_kept], 1)
        };
        (y, log_det.sum_dim_intlist(1, false, Kind::Double))
    }
}
