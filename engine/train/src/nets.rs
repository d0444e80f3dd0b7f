//! The network layers of `ciflow_engine::flow` in tch, batched over rows, with the same
//! parameter names and the same floating-point recipe (see the engine modules for the
//! equations: `mlp`, `mixing`, `affine`, `spline`, `coupling`).

use ciflow_engine::flow::config::{SPLINE_MIN_BIN, SPLINE_MIN_DERIVATIVE};
use ciflow_engine::flow::context_set::local_sizes;
use ciflow_engine::flow::{CouplingKind, FlowConfig};
use tch::nn::{self, Module};
use tch::{Kind, Tensor};

/// `tanh` MLP with a linear last layer, named `{path}.{j}.weight|bias` like the engine.
#[derive(Debug)]
pub struct Mlp {
    layers: Vec<nn::Linear>,
}

impl Mlp {
    /// `zero_last`: initialise the last layer to zero (the coupling starts as the identity).
    pub fn new(path: &nn::Path, sizes: &[usize], zero_last: bool) -> Self {
        let n = sizes.len() - 1;
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(j, io)| {
                let config = if zero_last && j + 1 == n {
                    nn::LinearConfig {
                        ws_init: nn::Init::Const(0.0),
                        bs_init: Some(nn::Init::Const(0.0)),
                        bias: true,
                    }
                } else {
                    nn::LinearConfig::default()
                };
                nn::linear(path / j, io[0] as i64, io[1] as i64, config)
            })
            .collect();
        Self { layers }
    }

    pub fn forward(&self, x: &Tensor) -> Tensor {
        let (last, hidden) = self.layers.split_last().expect("an MLP has a layer");
        let h = hidden
            .iter()
            .fold(x.shallow_clone(), |h, l| l.forward(&h).tanh());
        last.forward(&h)
    }
}

/// LU mixing `y = L U x + b`.
#[derive(Debug)]
pub struct LuMixing {
    lower: Tensor,
    upper: Tensor,
    log_diag: Tensor,
    bias: Tensor,
}

impl LuMixing {
    pub fn new(path: &nn::Path, d: usize) -> Self {
        let d = d as i64;
        let small = nn::Init::Randn {
            mean: 0.0,
            stdev: 0.1,
        };
        Self {
            lower: path.var("lower", &[d, d], small),
            upper: path.var("upper", &[d, d], small),
            log_diag: path.var("log_diag", &[d], nn::Init::Const(0.0)),
            bias: path.var("bias", &[d], nn::Init::Const(0.0)),
        }
    }

    fn matrix(&self) -> Tensor {
        let d = self.log_diag.size()[0];
        let eye = Tensor::eye(d, (self.lower.kind(), self.lower.device()));
        let l = self.lower.tril(-1) + eye;
        let u = self.upper.triu(1) + self.log_diag.exp().diag_embed(0, -2, -1);
        l.matmul(&u)
    }

    /// Returns `(y, log|det|)`, the log-determinant a scalar tensor.
    pub fn forward(&self, x: &Tensor) -> (Tensor, Tensor) {
        (
            x.matmul(&self.matrix().tr()) + &self.bias,
            self.log_diag.sum(Kind::Double),
        )
    }

    pub fn inverse(&self, y: &Tensor) -> (Tensor, Tensor) {
        let inv = self.matrix().inverse();
        (
            (y - &self.bias).matmul(&inv.tr()),
            -self.log_diag.sum(Kind::Double),
        )
    }
}

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
/// (`ciflow_engine::flow::conditioner`).
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
                    Mlp::new(&(path / "local" / k), &sizes, false)
                })
                .collect(),
            None => Vec::new(),
        };
        Self {
            kind: config.coupling.clone(),
            conditioner: Mlp::new(&(path / "conditioner"), &config.conditioner_sizes(), true),
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
            CouplingKind::Affine { scale_bound } => affine(&x_t, &params, scale_bound, inverse),
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

/// `y = x e^s + t`, `s = B tanh(ŝ/B)`; element-wise log-determinants.
fn affine(x: &Tensor, params: &Tensor, bound: f64, inverse: bool) -> (Tensor, Tensor) {
    let s = (params.select(2, 0) / bound).tanh() * bound;
    let t = params.select(2, 1);
    if inverse {
        ((x - t) * (-&s).exp(), -s)
    } else {
        (x * s.exp() + t, s)
    }
}

/// Knots `[N, K+1]` from unnormalised sizes `[N, K]` (softmax, minimum size, `[-B, B]`).
fn knots(raw: &Tensor, bins: i64, bound: f64) -> Tensor {
    let sizes =
        raw.softmax(-1, Kind::Double) * (1.0 - SPLINE_MIN_BIN * bins as f64) + SPLINE_MIN_BIN;
    let cumulative = sizes.cumsum(-1, Kind::Double) * (2.0 * bound) - bound;
    let n = raw.size()[0];
    let left = Tensor::full([n, 1], -bound, (Kind::Double, raw.device()));
    let right = Tensor::full([n, 1], bound, (Kind::Double, raw.device()));
    Tensor::cat(&[&left, &cumulative.narrow(1, 0, bins - 1), &right], 1)
}

fn gather(t: &Tensor, index: &Tensor) -> Tensor {
    t.gather(1, index, false).squeeze_dim(1)
}

/// Rational-quadratic spline on `[-B, B]`, identity outside (Durkan et al. 2019).
/// `x: [N]`, `params: [N, 3K-1]`; returns `(y, log|dy/dx|)` (or the inverse's).
pub fn rational_quadratic_spline(
    x: &Tensor,
    params: &Tensor,
    bins: i64,
    bound: f64,
    inverse: bool,
) -> (Tensor, Tensor) {
    let inside = x.ge(-bound).logical_and(&x.le(bound));
    // Discarded branches still get gradients: keep them finite by clamping.
    let xc = x.clamp(-bound, bound);
    let xs = knots(&params.narrow(1, 0, bins), bins, bound);
    let ys = knots(&params.narrow(1, bins, bins), bins, bound);
    let n = x.size()[0];
    let shift = (1.0 - SPLINE_MIN_DERIVATIVE).exp_m1().ln();
    let ones = Tensor::ones([n, 1], (Kind::Double, x.device()));
    let interior =
        (params.narrow(1, 2 * bins, bins - 1) + shift).softplus() + SPLINE_MIN_DERIVATIVE;
    let derivatives = Tensor::cat(&[&ones, &interior, &ones], 1);
    let edges = if inverse { &ys } else { &xs };
    let index = xc
        .unsqueeze(1)
        .ge_tensor(&edges.narrow(1, 1, bins - 1))
        .sum_dim_intlist(1, true, Kind::Int64);
    let next = &index + 1;
    let (x0, x1) = (gather(&xs, &index), gather(&xs, &next));
    let (y0, y1) = (gather(&ys, &index), gather(&ys, &next));
    let (d0, d1) = (gather(&derivatives, &index), gather(&derivatives, &next));
    let (w, h) = (&x1 - &x0, &y1 - &y0);
    let s = &h / &w;
    let curvature = &d0 + &d1 - &s * 2.0;
    let (out, xi) = if inverse {
        let dy = &xc - &y0;
        let a = &h * (&s - &d0) + &dy * &curvature;
        let b = &h * &d0 - &dy * &curvature;
        let c = -(&s * &dy);
        let discriminant = (&b * &b - &a * &c * 4.0).clamp_min(0.0);
        let xi = &c * 2.0 / (-&b - discriminant.sqrt());
        (&xi * &w + &x0, xi)
    } else {
        let xi = (&xc - &x0) / &w;
        let mix = &xi * (1.0 - &xi);
        let y = &y0 + &h * (&s * &xi * &xi + &d0 * &mix) / (&s + &curvature * &mix);
        (y, xi)
    };
    let one_minus = 1.0 - &xi;
    let mix = &xi * &one_minus;
    let denominator = &s + &curvature * &mix;
    let numerator = &s * &s * (&d1 * &xi * &xi + &s * &mix * 2.0 + &d0 * &one_minus * &one_minus);
    let log_derivative = numerator.log() - denominator.log() * 2.0;
    let log_derivative = if inverse {
        -log_derivative
    } else {
        log_derivative
    };
    let zero = Tensor::zeros_like(&log_derivative);
    (
        out.where_self(&inside, x),
        log_derivative.where_self(&inside, &zero),
    )
}
