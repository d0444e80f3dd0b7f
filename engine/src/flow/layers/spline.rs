//! Monotone rational-quadratic spline (Durkan et al. 2019, "Neural Spline Flows", §3.1),
//! identity outside `[-B, B]`.
//!
//! From `K` unnormalised widths, `K` heights and `K - 1` interior derivatives the knots
//! `(x_k, y_k, δ_k)` are built as in the paper's reference code: softmax with a minimum
//! bin size, cumulative sums rescaled to `[-B, B]`, derivatives `δ_min + softplus(·)`
//! shifted so that zero parameters give `δ = 1`; the outer derivatives are 1 so the
//! spline joins the identity tails with a continuous slope. In bin `k`, with
//! `ξ = (x - x_k)/w_k` and `s_k = h_k / w_k`,
//!
//! `y = y_k + h_k [s_k ξ² + δ_k ξ(1-ξ)] / [s_k + (δ_{k+1} + δ_k - 2 s_k) ξ(1-ξ)]`,
//!
//! `dy/dx = s_k² [δ_{k+1} ξ² + 2 s_k ξ(1-ξ) + δ_k (1-ξ)²] / [s_k + (δ_{k+1} + δ_k - 2 s_k) ξ(1-ξ)]²`,
//!
//! and the inverse solves the quadratic for `ξ` with the numerically stable root.

use crate::flow::checkpoint::config::{SPLINE_MIN_BIN, SPLINE_MIN_DERIVATIVE};
use crate::nn::scalar::Scalar;

#[derive(Clone, Copy, Debug)]
pub struct SplineTransform {
    pub bins: usize,
    pub tail_bound: f64,
    /// `ln(e^{1 - δ_min} - 1)`: the softplus argument that yields a unit knot derivative.
    derivative_shift: f64,
}

/// Knot positions `x_0..x_K`, `y_0..y_K` of one spline and its raw derivative parameters.
struct Knots<'a, S> {
    xs: &'a [S],
    ys: &'a [S],
    raw_derivatives: &'a [S],
    derivative_shift: f64,
}

impl<S: Scalar> Knots<'_, S> {
    /// `δ_k`; only the two knots of the active bin are ever evaluated.
    #[inline(always)]
    fn derivative(&self, k: usize) -> S {
        if k == 0 || k == self.xs.len() - 1 {
            S::constant(1.0)
        } else {
            (self.raw_derivatives[k - 1] + self.derivative_shift).softplus() + SPLINE_MIN_DERIVATIVE
        }
    }
}

impl SplineTransform {
    pub fn new(bins: usize, tail_bound: f64) -> Self {
        Self {
            bins,
            tail_bound,
            derivative_shift: (1.0 - SPLINE_MIN_DERIVATIVE).exp_m1().ln(),
        }
    }

    /// Scratch length [`forward`](Self::forward) and [`inverse`](Self::inverse) need.
    pub fn scratch_len(&self) -> usize {
        2 * (self.bins + 1)
    }

    /// Cumulative knot positions of softmax-normalised bin sizes on `[-B, B]`.
    #[inline(always)]
    fn cumulative<S: Scalar>(&self, raw: &[S], out: &mut [S]) {
        let k = self.bins;
        let max = raw
            .iter()
            .map(|v| v.value())
            .fold(f64::NEG_INFINITY, f64::max);
        for (o, r) in out[1..].iter_mut().zip(raw) {
            *o = (*r + (-max)).exp_non_positive();
        }
        let mut total = S::constant(0.0);
        for o in &out[1..=k] {
            total += *o;
        }
        let inv_total = S::constant(1.0) / total;
        let scale = 1.0 - SPLINE_MIN_BIN * k as f64;
        let (left, width) = (-self.tail_bound, 2.0 * self.tail_bound);
        let mut cum = S::constant(0.0);
        out[0] = S::constant(left);
        for o in out[1..].iter_mut() {
            cum += *o * inv_total * scale + SPLINE_MIN_BIN;
            *o = cum * width + left;
        }
        out[k] = S::constant(self.tail_bound);
    }

    #[inline(always)]
    fn knots<'a, S: Scalar>(&self, params: &'a [S], scratch: &'a mut [S]) -> Knots<'a, S> {
        let k = self.bins;
        let (xs, ys) = scratch.split_at_mut(k + 1);
        self.cumulative(&params[..k], xs);
        self.cumulative(&params[k..2 * k], ys);
        Knots {
            xs,
            ys,
            raw_derivatives: &params[2 * k..3 * k - 1],
            derivative_shift: self.derivative_shift,
        }
    }

    #[inline(always)]
    fn inside(&self, v: f64) -> bool {
        (-self.tail_bound..=self.tail_bound).contains(&v)
    }

    /// `log(dy/dx)` at bin parameter `ξ` of bin `k`, or zero unless `wanted` (passes that
    /// only map points skip the logarithm).
    #[inline(always)]
    fn log_derivative<S: Scalar>(
        knots: &Knots<S>,
        k: usize,
        xi: S,
        (d0, d1): (S, S),
        wanted: bool,
    ) -> S {
        if !wanted {
            return S::constant(0.0);
        }
        let w = knots.xs[k + 1] - knots.xs[k];
        let h = knots.ys[k + 1] - knots.ys[k];
        let s = h / w;
        let one_minus = -xi + 1.0;
        let mix = xi * one_minus;
        let denominator = s + (d0 + d1 - s * 2.0) * mix;
        let numerator = s * s * (d1 * xi * xi + s * mix * 2.0 + d0 * one_minus * one_minus);
        (numerator / (denominator * denominator)).ln()
    }

    /// `params`: `K` widths, `K` heights, `K - 1` derivatives (unnormalised).
    /// Returns `(y, log|dy/dx|)`; the log-derivative is zero unless `log_det`.
    #[inline(always)]
    pub fn forward<S: Scalar>(
        &self,
        x: S,
        params: &[S],
        scratch: &mut [S],
        log_det: bool,
    ) -> (S, S) {
        if !self.inside(x.value()) {
            return (x, S::constant(0.0));
        }
        let knots = self.knots(params, scratch);
        let k = Self::bin_of(knots.xs, x.value());
        let w = knots.xs[k + 1] - knots.xs[k];
        let h = knots.ys[k + 1] - knots.ys[k];
        let s = h / w;
        let (d0, d1) = (knots.derivative(k), knots.derivative(k + 1));
        let xi = (x - knots.xs[k]) / w;
        let mix = xi * (-xi + 1.0);
        let y = knots.ys[k] + h * (s * xi * xi + d0 * mix) / (s + (d0 + d1 - s * 2.0) * mix);
        (y, Self::log_derivative(&knots, k, xi, (d0, d1), log_det))
    }

    /// Returns `(x, log|dx/dy|)`; the log-derivative is zero unless `log_det`.
    #[inline(always)]
    pub fn inverse<S: Scalar>(
        &self,
        y: S,
        params: &[S],
        scratch: &mut [S],
        log_det: bool,
    ) -> (S, S) {
        if !self.inside(y.value()) {
            return (y, S::constant(0.0));
        }
        let knots = self.knots(params, scratch);
        let k = Self::bin_of(knots.ys, y.value());
        let w = knots.xs[k + 1] - knots.xs[k];
        let h = knots.ys[k + 1] - knots.ys[k];
        let s = h / w;
        let (d0, d1) = (knots.derivative(k), knots.derivative(k + 1));
        let dy = y - knots.ys[k];
        let curvature = d0 + d1 - s * 2.0;
        let a = h * (s - d0) + dy * curvature;
        let b = h * d0 - dy * curvature;
        let c = -(s * dy);
        // Rounding can push a zero discriminant (a knot hit exactly) below zero.
        let discriminant = b * b - a * c * 4.0;
        let discriminant = if discriminant.value() < 0.0 {
            S::constant(0.0)
        } else {
            discriminant
        };
        let xi = c * 2.0 / (-b - discriminant.sqrt());
        let x = xi * w + knots.xs[k];
        (x, -Self::log_derivative(&knots, k, xi, (d0, d1), log_det))
    }

    /// Index of the bin holding `v` among the knots `edges` (the last bin includes its end).
    #[inline(always)]
    fn bin_of<S: Scalar>(edges: &[S], v: f64) -> usize {
        let k = edges.len() - 1;
        edges[1..k].iter().take_while(|e| v >= e.value()).count()
    }
}
