//! Affine coupling transform (Dinh et al. 2017, "Real NVP") with a bounded log-scale:
//! `y = x·e^s + t`, `s = B·tanh(ŝ/B)`. Because `|s| < B` the layer can neither overflow
//! nor collapse far from the data, and `log|dy/dx| = s`.
//!
//! A coupling transforms all its coordinates at once: their `tanh` and `e^{±s}` are
//! taken first, on the primal values in one loop the compiler vectorises
//! ([`primal_scales`](AffineTransform::primal_scales)), then each coordinate applies the
//! chain rule in its own scalar type ([`apply_all`](AffineTransform::apply_all)). A
//! forward pass through a point an inverse pass recorded reuses that pass's primal
//! scales. Transformed one coordinate at a time, with libm's `exp` in every pass, the
//! affine transforms were about a quarter of a policy action; now the pouring action
//! takes 6.8–6.9 µs instead of 8.2–8.8 (`cargo bench --bench flow`,
//! `bench/README.md`).

use crate::nn::scalar::{Scalar, exp_non_positive_with, tanh_with};

/// Bounds `B` up to which `e^{±s}` is taken from the branch-free `e^x, x ≤ 0` as
/// `e^{±s − B} e^B`. Rounding `±s − B` costs up to `B ε` relative, so beyond a few units
/// libm's `exp` is the accurate one.
const BRANCH_FREE_EXP_BOUND: f64 = 16.0;

#[derive(Clone, Copy, Debug)]
pub struct AffineTransform {
    scale_bound: f64,
    /// `e^B`.
    exp_bound: f64,
}

impl AffineTransform {
    /// The transform with log-scale bound `B = scale_bound` (finite, > 0).
    pub fn new(scale_bound: f64) -> Self {
        Self {
            scale_bound,
            exp_bound: scale_bound.exp(),
        }
    }

    /// `e^x` for `|x| < B`, relative error below `(2B + 3) ε` (libm's: `ε / 2`).
    #[inline(always)]
    fn exp<const FUSED: bool>(&self, x: f64) -> f64 {
        if self.scale_bound <= BRANCH_FREE_EXP_BOUND {
            exp_non_positive_with::<FUSED>(x - self.scale_bound) * self.exp_bound
        } else {
            x.exp()
        }
    }

    /// The primal `tanh(ŝ_i / B)` and `e^{±s_i}` (`−` when `inverse`) of the coordinates
    /// whose parameters `[ŝ_i, t_i]` follow one another in `params`, into
    /// `scales = [tanh…, e^{±s}…]` (two per coordinate). `FUSED` as for
    /// [`tanh_with`]: only code compiled for FMA instructions should set it.
    #[inline(always)]
    pub fn primal_scales<S: Scalar, const FUSED: bool>(
        &self,
        params: &[S],
        inverse: bool,
        scales: &mut [f64],
    ) {
        let n = params.len() / 2;
        let (tanh, exp) = scales[..2 * n].split_at_mut(n);
        let inverse_bound = 1.0 / self.scale_bound;
        for (t, theta) in tanh.iter_mut().zip(params.chunks_exact(2)) {
            *t = theta[0].value() * inverse_bound;
        }
        let signed_bound = if inverse {
            -self.scale_bound
        } else {
            self.scale_bound
        };
        for (t, e) in tanh.iter_mut().zip(exp.iter_mut()) {
            *t = tanh_with::<FUSED>(*t);
            *e = self.exp::<FUSED>(signed_bound * *t);
        }
    }

    /// `x_i ← x_i e^{s_i} + t_i` (or `(x_i − t_i) e^{−s_i}` when `inverse`) for every
    /// coordinate, `params = [ŝ_0, t_0, ŝ_1, t_1, …]`, with `scales` the
    /// [`primal_scales`](Self::primal_scales) of the same primal `ŝ` and direction;
    /// returns `Σ log|dx_i'/dx_i| = ±Σ s_i`.
    #[inline(always)]
    pub fn apply_all<S: Scalar>(
        &self,
        xs: &mut [S],
        params: &[S],
        inverse: bool,
        scales: &[f64],
    ) -> S {
        let n = xs.len();
        let (tanh, exp) = scales[..2 * n].split_at(n);
        let mut log_det = S::constant(0.0);
        let inverse_bound = 1.0 / self.scale_bound;
        for (((x, theta), t), e) in xs.iter_mut().zip(params.chunks_exact(2)).zip(tanh).zip(exp) {
            let slope = 1.0 - t * t;
            let s = (theta[0] * inverse_bound).compose(&[*t, slope, -2.0 * t * slope])
                * self.scale_bound;
            if inverse {
                *x = (*x - theta[1]) * (-s).compose(&[*e; 3]);
                log_det += -s;
            } else {
                *x = *x * s.compose(&[*e; 3]) + theta[1];
                log_det += s;
            }
        }
        log_det
    }
}

#[cfg(test)]
mod tests {
    use super::AffineTransform;
    use crate::nn::scalar::{Dual, Scalar};

    fn transform<S: Scalar>(
        affine: &AffineTransform,
        x: &mut [S],
        params: &[S],
        inverse: bool,
    ) -> S {
        let mut scales = vec![0.0; 2 * x.len()];
        affine.primal_scales::<S, false>(params, inverse, &mut scales);
        affine.apply_all(x, params, inverse, &scales)
    }

    /// Against the formula in libm's `tanh` and `exp` and nested dual numbers of their
    /// own (value, both tangents and the mixed second derivative), and the inverse undoing
    /// the forward transform, for bounds on both sides of the branch-free range.
    #[test]
    fn matches_the_formula_and_inverts() {
        let nested = |a: f64, b: f64, c: f64, d: f64| Dual::new(Dual::new(a, b), Dual::new(c, d));
        for bound in [0.5, 2.0, 10.0, 16.0, 17.0, 400.0] {
            let affine = AffineTransform::new(bound);
            let tolerance = 1e-14 * (1.0 + bound);
            let mut xs = vec![nested(1.3, -0.2, 0.7, 0.1), nested(-0.4, 0.3, 0.2, -0.5)];
            let params = vec![
                nested(0.7 * bound, 0.3, -0.2, 0.4),
                nested(-0.4, 1.0, 0.5, 0.2),
                nested(-0.8, 0.1, 0.3, -0.3),
                nested(0.9, -0.6, 0.0, 0.7),
            ];
            let reference: Vec<_> = xs
                .iter()
                .zip(params.chunks_exact(2))
                .map(|(x, theta)| {
                    let s = (theta[0] * (1.0 / bound)).tanh() * bound;
                    *x * s.exp() + theta[1]
                })
                .collect();
            let original = xs.clone();
            let log_det = transform(&affine, &mut xs, &params, false);
            for (y, expected) in xs.iter().zip(&reference) {
                for lane in 0..4 {
                    let (got, want) = (y.lane(lane), expected.lane(lane));
                    assert!(
                        (got - want).abs() <= tolerance * (1.0 + want.abs()),
                        "B {bound}"
                    );
                }
            }
            let inverse_log_det = transform(&affine, &mut xs, &params, true);
            for (x, expected) in xs.iter().zip(&original) {
                for lane in 0..4 {
                    assert!(
                        (x.lane(lane) - expected.lane(lane)).abs() < tolerance,
                        "B {bound}"
                    );
                }
            }
            assert!((log_det + inverse_log_det).value().abs() < tolerance);
        }
    }
}
