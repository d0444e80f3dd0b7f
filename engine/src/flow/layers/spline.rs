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
//!
//! A coupling transforms all its coordinates in two steps, as the affine transform does:
//! [`primal_knots`](SplineTransform::primal_knots) takes every transcendental function on
//! the primal values (the softmax's `e^θ`, the two active knots' softplus) and finds each
//! coordinate's bin; [`apply_all`](SplineTransform::apply_all) then builds only the four
//! knots of that bin in the coordinate's scalar type, applying the chain rule to the
//! recorded values ([`Scalar::compose`]). The forward passes through a point an inverse
//! pass recorded reuse its primal knots, so the nested dual numbers of the acceleration
//! take no transcendental function at all.

use crate::flow::checkpoint::config::{SPLINE_MIN_BIN, SPLINE_MIN_DERIVATIVE};
use crate::nn::scalar::{Scalar, exp_non_positive_with, softplus_and_sigmoid};

#[derive(Clone, Copy, Debug)]
pub struct SplineTransform {
    pub bins: usize,
    pub tail_bound: f64,
    /// `ln(e^{1 - δ_min} - 1)`: the softplus argument that yields a unit knot derivative.
    derivative_shift: f64,
}

/// A coordinate's primal knots, `[bin, e^{θ_w − max θ_w}…, e^{θ_h − max θ_h}…, δ_k, δ_k',
/// δ_k'', δ_{k+1}, …]` (`K` of each exponential, the active knots' derivatives with their
/// first two derivatives in their raw parameter); `bin` is [`OUTSIDE`] in the identity
/// tails.
struct PrimalKnots<'a> {
    bin: f64,
    widths: &'a [f64],
    heights: &'a [f64],
    lower_derivative: &'a [f64],
    upper_derivative: &'a [f64],
}

/// The bin of a coordinate in the identity tails.
const OUTSIDE: f64 = -1.0;

impl SplineTransform {
    pub fn new(bins: usize, tail_bound: f64) -> Self {
        Self {
            bins,
            tail_bound,
            derivative_shift: (1.0 - SPLINE_MIN_DERIVATIVE).exp_m1().ln(),
        }
    }

    /// `f64` values [`primal_knots`](Self::primal_knots) records per coordinate.
    pub fn primal_len(&self) -> usize {
        2 * self.bins + 7
    }

    #[inline(always)]
    fn inside(&self, v: f64) -> bool {
        (-self.tail_bound..=self.tail_bound).contains(&v)
    }

    fn knots_of<'a>(&self, primal: &'a [f64]) -> PrimalKnots<'a> {
        let k = self.bins;
        let (exps, derivatives) = primal[1..].split_at(2 * k);
        let (widths, heights) = exps.split_at(k);
        let (lower_derivative, upper_derivative) = derivatives.split_at(3);
        PrimalKnots {
            bin: primal[0],
            widths,
            heights,
            lower_derivative,
            upper_derivative,
        }
    }

    /// Knot `j` of `0..=K` of the softmax-normalised bin sizes on `[-B, B]`, from the
    /// partial sum `partial = Σ_{i<j} e_i` and `1 / Σ_i e_i`. The primal pass and
    /// [`apply_all`](Self::apply_all) both take their knots from here, so a bin found on
    /// the primal values holds the coordinate in every scalar type.
    #[inline(always)]
    fn knot<S: Scalar>(&self, j: usize, partial: S, inverse_total: S) -> S {
        if j == self.bins {
            return S::constant(self.tail_bound);
        }
        let scale = 1.0 - SPLINE_MIN_BIN * self.bins as f64;
        let (left, width) = (-self.tail_bound, 2.0 * self.tail_bound);
        (partial * inverse_total * scale + SPLINE_MIN_BIN * j as f64) * width + left
    }

    /// The bin holding `v` among the knots [`knot`](Self::knot) builds from the primal
    /// exponentials `exps`: the last bin includes its end, and `v` is inside `[-B, B]`.
    #[inline(always)]
    fn bin_of(&self, exps: &[f64], v: f64) -> usize {
        let inverse_total = 1.0 / exps.iter().sum::<f64>();
        let mut partial = 0.0;
        for (j, e) in exps[..self.bins - 1].iter().enumerate() {
            partial += e;
            if v < self.knot(j + 1, partial, inverse_total) {
                return j;
            }
        }
        self.bins - 1
    }

    /// The raw parameter of knot `j`'s derivative among the `K − 1` interior ones, or
    /// `None` for the outer knots, whose derivative is the constant 1.
    #[inline(always)]
    fn raw_derivative<T>(&self, j: usize, raw: &[T]) -> Option<T>
    where
        T: Copy,
    {
        (j > 0 && j < self.bins).then(|| raw[j - 1])
    }

    /// `[δ, δ', δ'']` of knot `j`'s derivative `δ_min + softplus(θ + shift)` in its raw
    /// parameter `θ` (the outer knots': the constant 1).
    #[inline(always)]
    fn derivative_at<S: Scalar>(&self, j: usize, raw: &[S]) -> [f64; 3] {
        let Some(theta) = self.raw_derivative(j, raw) else {
            return [1.0, 0.0, 0.0];
        };
        let (softplus, sigmoid) = softplus_and_sigmoid(theta.value() + self.derivative_shift);
        [
            softplus + SPLINE_MIN_DERIVATIVE,
            sigmoid,
            sigmoid * (1.0 - sigmoid),
        ]
    }

    /// The primal knots of every coordinate `xs` (their inputs: `x` forward, `y` when
    /// `inverse`; parameters `params`, `3K − 1` per coordinate) into `primal`
    /// ([`primal_len`](Self::primal_len) per coordinate). `FUSED` as for
    /// [`exp_non_positive_with`]: only code compiled for FMA instructions should set it.
    #[inline(always)]
    pub fn primal_knots<S: Scalar, const FUSED: bool>(
        &self,
        xs: &[S],
        params: &[S],
        inverse: bool,
        primal: &mut [f64],
    ) {
        let k = self.bins;
        let records = primal.chunks_exact_mut(self.primal_len());
        for ((x, theta), record) in xs.iter().zip(params.chunks_exact(3 * k - 1)).zip(records) {
            if !self.inside(x.value()) {
                record[0] = OUTSIDE;
                continue;
            }
            let (bin_slot, rest) = record.split_first_mut().expect("primal_len > 0");
            let (exps, derivatives) = rest.split_at_mut(2 * k);
            let (widths, heights) = exps.split_at_mut(k);
            let sides = [(&theta[..k], widths), (&theta[k..2 * k], heights)];
            for (sizes, e) in sides {
                // The primal values gathered first, so the exponentials' loop reads
                // contiguous values and vectorises.
                for (e, s) in e.iter_mut().zip(sizes) {
                    *e = s.value();
                }
                // Softmax is shift-invariant: `e^{θ − max θ} ≤ 1` cannot overflow.
                let max = e.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                for e in e.iter_mut() {
                    *e = exp_non_positive_with::<FUSED>(*e - max);
                }
            }
            let (widths, heights) = exps.split_at(k);
            let bin = self.bin_of(if inverse { heights } else { widths }, x.value());
            *bin_slot = bin as f64;
            let raw = &theta[2 * k..];
            let (lower, upper) = derivatives.split_at_mut(3);
            lower.copy_from_slice(&self.derivative_at(bin, raw));
            upper.copy_from_slice(&self.derivative_at(bin + 1, raw));
        }
    }

    /// `x_i ← h(x_i; θ_i)` (or `h⁻¹` when `inverse`) for every coordinate, `params`
    /// holding `3K − 1` parameters per coordinate and `primal` the
    /// [`primal_knots`](Self::primal_knots) of the same primal parameters and inputs (or,
    /// for a forward pass, of the inverse pass that returned these inputs); returns
    /// `Σ log|h'|`, or zero unless `log_det` (passes that only map points skip the
    /// logarithm).
    #[inline(always)]
    pub fn apply_all<S: Scalar>(
        &self,
        xs: &mut [S],
        params: &[S],
        inverse: bool,
        primal: &[f64],
        log_det: bool,
    ) -> S {
        let k = self.bins;
        let mut sum = S::constant(0.0);
        let records = primal.chunks_exact(self.primal_len());
        for ((x, theta), record) in xs
            .iter_mut()
            .zip(params.chunks_exact(3 * k - 1))
            .zip(records)
        {
            let knots = self.knots_of(record);
            if knots.bin == OUTSIDE {
                continue;
            }
            let bin = knots.bin as usize;
            let (x_lo, x_hi) = self.bin_edges(&theta[..k], knots.widths, bin);
            let (y_lo, y_hi) = self.bin_edges(&theta[k..2 * k], knots.heights, bin);
            let raw = &theta[2 * k..];
            let derivative = |j: usize, values: &[f64]| {
                self.raw_derivative(j, raw)
                    .map_or(S::constant(1.0), |theta| theta.compose(values))
            };
            let d0 = derivative(bin, knots.lower_derivative);
            let d1 = derivative(bin + 1, knots.upper_derivative);
            let (value, ld) = if inverse {
                Self::inverse_in_bin(*x, (x_lo, x_hi), (y_lo, y_hi), (d0, d1), log_det)
            } else {
                Self::forward_in_bin(*x, (x_lo, x_hi), (y_lo, y_hi), (d0, d1), log_det)
            };
            *x = value;
            sum += ld;
        }
        sum
    }

    /// Knots `bin` and `bin + 1` in `S`, from the bin sizes' parameters `sizes` and their
    /// primal exponentials `exps`.
    #[inline(always)]
    fn bin_edges<S: Scalar>(&self, sizes: &[S], exps: &[f64], bin: usize) -> (S, S) {
        let mut total = S::constant(0.0);
        let mut partial = [S::constant(0.0); 2];
        for (j, (s, e)) in sizes.iter().zip(exps).enumerate() {
            if j == bin {
                partial[0] = total;
            }
            total += s.compose(&[*e; 3]);
            if j == bin {
                partial[1] = total;
            }
        }
        let inverse_total = S::constant(1.0) / total;
        (
            self.knot(bin, partial[0], inverse_total),
            self.knot(bin + 1, partial[1], inverse_total),
        )
    }

    /// `log(dy/dx)` at bin parameter `ξ` of a bin of slope `s = h / w` between knot
    /// derivatives `δ_k = d0`, `δ_{k+1} = d1`.
    #[inline(always)]
    fn log_derivative<S: Scalar>(s: S, xi: S, (d0, d1): (S, S)) -> S {
        let one_minus = -xi + 1.0;
        let mix = xi * one_minus;
        let denominator = s + (d0 + d1 - s * 2.0) * mix;
        let numerator = s * s * (d1 * xi * xi + s * mix * 2.0 + d0 * one_minus * one_minus);
        (numerator / (denominator * denominator)).ln()
    }

    /// `(y, log|dy/dx|)` in the bin between knots `(x_lo, y_lo)` and `(x_hi, y_hi)` with
    /// derivatives `(d0, d1)`; the log-derivative is zero unless `log_det`.
    #[inline(always)]
    fn forward_in_bin<S: Scalar>(
        x: S,
        (x_lo, x_hi): (S, S),
        (y_lo, y_hi): (S, S),
        (d0, d1): (S, S),
        log_det: bool,
    ) -> (S, S) {
        let (w, h) = (x_hi - x_lo, y_hi - y_lo);
        let s = h / w;
        let xi = (x - x_lo) / w;
        let mix = xi * (-xi + 1.0);
        let y = y_lo + h * (s * xi * xi + d0 * mix) / (s + (d0 + d1 - s * 2.0) * mix);
        let log_derivative = if log_det {
            Self::log_derivative(s, xi, (d0, d1))
        } else {
            S::constant(0.0)
        };
        (y, log_derivative)
    }

    /// `(x, log|dx/dy|)`, the inverse of [`forward_in_bin`](Self::forward_in_bin).
    #[inline(always)]
    fn inverse_in_bin<S: Scalar>(
        y: S,
        (x_lo, x_hi): (S, S),
        (y_lo, y_hi): (S, S),
        (d0, d1): (S, S),
        log_det: bool,
    ) -> (S, S) {
        let (w, h) = (x_hi - x_lo, y_hi - y_lo);
        let s = h / w;
        let dy = y - y_lo;
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
        let x = xi * w + x_lo;
        let log_derivative = if log_det {
            -Self::log_derivative(s, xi, (d0, d1))
        } else {
            S::constant(0.0)
        };
        (x, log_derivative)
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::SplineTransform;
    use crate::flow::checkpoint::config::{SPLINE_MIN_BIN, SPLINE_MIN_DERIVATIVE};
    use crate::nn::scalar::{Dual, Scalar};

    type Nested = Dual<Dual<f64>>;

    /// The spline of one coordinate the direct way, every knot built in `S` with its own
    /// `exp` and `softplus`: `(y, log|dy/dx|)`, or the inverse's.
    fn reference<S: Scalar>(spline: &SplineTransform, v: S, theta: &[S], inverse: bool) -> (S, S) {
        let (k, bound) = (spline.bins, spline.tail_bound);
        if v.value().abs() > bound {
            return (v, S::constant(0.0));
        }
        let knots = |sizes: &[S]| {
            let max = sizes
                .iter()
                .map(|s| s.value())
                .fold(f64::NEG_INFINITY, f64::max);
            let exps: Vec<S> = sizes.iter().map(|s| (*s + (-max)).exp()).collect();
            let mut total = S::constant(0.0);
            for e in &exps {
                total += *e;
            }
            let mut knots = vec![S::constant(-bound)];
            let mut cumulative = S::constant(0.0);
            for e in &exps {
                cumulative += *e / total * (1.0 - SPLINE_MIN_BIN * k as f64) + SPLINE_MIN_BIN;
                knots.push(cumulative * (2.0 * bound) + (-bound));
            }
            knots[k] = S::constant(bound);
            knots
        };
        let (xs, ys) = (knots(&theta[..k]), knots(&theta[k..2 * k]));
        let shift = (1.0 - SPLINE_MIN_DERIVATIVE).exp_m1().ln();
        let derivative = |j: usize| {
            if j == 0 || j == k {
                S::constant(1.0)
            } else {
                (theta[2 * k + j - 1] + shift).softplus() + SPLINE_MIN_DERIVATIVE
            }
        };
        let edges = if inverse { &ys } else { &xs };
        let bin = edges[1..k]
            .iter()
            .take_while(|e| v.value() >= e.value())
            .count();
        let (w, h) = (xs[bin + 1] - xs[bin], ys[bin + 1] - ys[bin]);
        let (s, d0, d1) = (h / w, derivative(bin), derivative(bin + 1));
        let xi = if inverse {
            // `a ξ² + b ξ + c = 0`, the root in [0, 1].
            let dy = v - ys[bin];
            let curvature = d0 + d1 - s * 2.0;
            let a = h * (s - d0) + dy * curvature;
            let b = h * d0 - dy * curvature;
            let c = -(s * dy);
            (-b + (b * b - a * c * 4.0).sqrt()) / (a * 2.0)
        } else {
            (v - xs[bin]) / w
        };
        let mix = xi * (-xi + 1.0);
        let denominator = s + (d0 + d1 - s * 2.0) * mix;
        let slope = s * s * (d1 * xi * xi + s * mix * 2.0 + d0 * (-xi + 1.0) * (-xi + 1.0))
            / (denominator * denominator);
        if inverse {
            (xi * w + xs[bin], -slope.ln())
        } else {
            (
                ys[bin] + h * (s * xi * xi + d0 * mix) / denominator,
                slope.ln(),
            )
        }
    }

    fn nested(rng: &mut ChaCha8Rng, value: f64) -> Nested {
        let mut r = || rng.random_range(-1.0..1.0);
        Dual::new(Dual::new(value, r()), Dual::new(r(), r()))
    }

    fn assert_lanes_close(got: Nested, want: Nested, what: &str) {
        for lane in 0..4 {
            let (g, w) = (got.lane(lane), want.lane(lane));
            assert!(
                (g - w).abs() <= 1e-10 * (1.0 + w.abs()),
                "{what}, lane {lane}: {g} vs {w}"
            );
        }
    }

    /// Both directions in nested dual numbers (values, both tangents, the mixed second
    /// derivative) against the direct construction, for coordinates in every bin, on a
    /// knot, in the tails; a forward pass reading the inverse pass's primal knots as the
    /// one computing its own; and the log-derivative against the tangent `dy/dx`.
    #[test]
    fn matches_the_direct_construction_in_every_lane() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (bins, bound) in [(8, 3.0), (3, 1.5), (24, 4.0)] {
            let spline = SplineTransform::new(bins, bound);
            let n = 40;
            let params: Vec<Nested> = (0..n * (3 * bins - 1))
                .map(|_| {
                    let v = rng.random_range(-2.5..2.5);
                    nested(&mut rng, v)
                })
                .collect();
            let mut points: Vec<f64> = (0..n - 2)
                .map(|i| -1.1 * bound + 2.2 * bound * i as f64 / (n - 3) as f64)
                .collect();
            points.extend([-bound, bound]);
            let ys: Vec<Nested> = points.iter().map(|v| nested(&mut rng, *v)).collect();
            let per = 3 * bins - 1;

            let mut primal = vec![0.0; n * spline.primal_len()];
            let mut xs = ys.clone();
            spline.primal_knots::<_, false>(&xs, &params, true, &mut primal);
            let log_det = spline.apply_all(&mut xs, &params, true, &primal, true);
            let mut expected_log_det = Nested::constant(0.0);
            for i in 0..n {
                let theta = &params[i * per..(i + 1) * per];
                let (x, ld) = reference(&spline, ys[i], theta, true);
                assert_lanes_close(xs[i], x, &format!("inverse, {bins} bins, y {}", points[i]));
                expected_log_det += ld;
            }
            assert_lanes_close(log_det, expected_log_det, "inverse log-determinant");

            // Forward from the recorded inverse (the acceleration's pass), and on its own.
            // The inverse of `y = ±B` may round to just outside `[-B, B]`, where the direct
            // construction and a pass of its own take the identity tail: the same value,
            // but the spline is not C² at its ends, so only the round trip is compared.
            let mut recorded = xs.clone();
            spline.apply_all(&mut recorded, &params, false, &primal, false);
            let interior = n - 2;
            let mut own = xs[..interior].to_vec();
            let mut own_primal = vec![0.0; interior * spline.primal_len()];
            spline.primal_knots::<_, false>(&own, &params, false, &mut own_primal);
            let log_det = spline.apply_all(&mut own, &params, false, &own_primal, true);
            let mut expected_log_det = Nested::constant(0.0);
            for i in 0..n {
                let theta = &params[i * per..(i + 1) * per];
                assert_lanes_close(recorded[i], ys[i], "round trip");
                if i < interior {
                    let (y, ld) = reference(&spline, xs[i], theta, false);
                    assert_lanes_close(recorded[i], y, "forward from the record");
                    assert_lanes_close(own[i], y, "forward");
                    expected_log_det += ld;
                }
            }
            assert_lanes_close(log_det, expected_log_det, "forward log-determinant");

            // `log|dy/dx|` against the tangent of `y` in `x` alone.
            let plain: Vec<f64> = params.iter().map(|p| p.value()).collect();
            let mut x: Vec<Dual<f64>> = points.iter().map(|v| Dual::new(*v, 1.0)).collect();
            let dual_params: Vec<Dual<f64>> = plain.iter().map(|p| Dual::constant(*p)).collect();
            let mut dual_primal = vec![0.0; n * spline.primal_len()];
            spline.primal_knots::<_, false>(&x, &dual_params, false, &mut dual_primal);
            let log_det = spline.apply_all(&mut x, &dual_params, false, &dual_primal, true);
            let from_tangents: f64 = x.iter().map(|y| y.du.ln()).sum();
            assert!(
                (log_det.re - from_tangents).abs() < 1e-10 * (1.0 + from_tangents.abs()),
                "{bins} bins: log-determinant {} vs Σ ln(dy/dx) {from_tangents}",
                log_det.re
            );
        }
    }
}
