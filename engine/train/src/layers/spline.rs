//! The rational-quadratic spline of `ciflow_engine::flow::layers::spline` in tch, with
//! the same minimum bin size and derivative.

use ciflow_engine::flow::checkpoint::config::{SPLINE_MIN_BIN, SPLINE_MIN_DERIVATIVE};
use tch::{Kind, Tensor};

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
