//! Taper of an affine coupling's parameters: `θ = w(x_kept) · θ̂` with
//!
//! `w(x) = 1 / (1 + (‖x‖² / R²)²)`, `x` the `k` kept coordinates (normalised units),
//!
//! so `w = 1 − O(‖x‖⁴/R⁴)` near the data and `w → 0` as `‖x‖/R → ∞`, where `θ = 0`
//! makes the affine transform the identity (`s = 0`, `t = 0`).
//!
//! Why: a conditioner's `tanh` saturates far from the data, leaving every affine coupling
//! a fixed scaling and shift there, and ten of them compose to a far-field map of large
//! condition number. A latent path that turns about its attractor (the saturated go-to's
//! skew, a linear latent's non-normal part) then swings out by that condition number
//! before it comes in: LASA's affine flows sent paths from 100× outside the
//! demonstrations to 500–14 000× (README "LASA"). Tapered, every coupling whose kept
//! coordinates are far out is close to the identity, so far from the data `f` tends to
//! its linear mixings alone.
//!
//! `w` depends only on the kept coordinates, which the coupling does not change, so the
//! inverse reads the same `w` and the layer stays a bijection with
//! `log|det| = Σ_i s_i` for every weight and `R > 0`.

use crate::nn::scalar::Scalar;

/// `w(x) = 1 / (1 + (‖x‖²/R²)²)` of radius `R`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Taper {
    /// `1 / R²`.
    inverse_radius_squared: f64,
}

impl Taper {
    /// The taper of radius `radius` (finite, > 0: the config's validation checks it).
    pub fn new(radius: f64) -> Self {
        Self {
            inverse_radius_squared: 1.0 / (radius * radius),
        }
    }

    /// `w(x)` in the scalar type of `kept`, so dual numbers carry its derivatives.
    #[inline(always)]
    pub fn weight<S: Scalar>(&self, kept: &[S]) -> S {
        let mut squared = S::constant(0.0);
        for &x in kept {
            squared += x * x;
        }
        let q = squared * self.inverse_radius_squared;
        S::constant(1.0) / (q * q + 1.0)
    }

    /// `θ ← w(x) θ` for the conditioner outputs `params` of a coupling keeping `kept`.
    #[inline(always)]
    pub fn apply<S: Scalar>(&self, kept: &[S], params: &mut [S]) {
        let w = self.weight(kept);
        for p in params {
            *p = *p * w;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::scalar::Dual;

    #[test]
    fn weight_is_one_at_the_origin_a_half_at_the_radius_and_fades_beyond() {
        let taper = Taper::new(2.0);
        assert_eq!(taper.weight(&[0.0, 0.0]), 1.0);
        assert!((taper.weight(&[2.0_f64.sqrt(), 2.0_f64.sqrt()]) - 0.5).abs() < 1e-15);
        let far = taper.weight(&[200.0]);
        assert!(far > 0.0 && far < 1e-7, "{far}");
    }

    /// The dual part is `∂w/∂x · dx` (checked against central differences).
    #[test]
    fn dual_numbers_carry_the_gradient() {
        let taper = Taper::new(1.5);
        let (x, dx) = ([0.7, -1.3], [0.4, 0.9]);
        let dual: Vec<Dual<f64>> = x.iter().zip(&dx).map(|(&a, &b)| Dual::new(a, b)).collect();
        let h = 1e-6;
        let at = |t: f64| taper.weight(&[x[0] + t * dx[0], x[1] + t * dx[1]]);
        let central = (at(h) - at(-h)) / (2.0 * h);
        let w = taper.weight(&dual);
        assert_eq!(w.re, taper.weight(&x));
        assert!((w.du - central).abs() < 1e-8, "{} vs {central}", w.du);
    }
}
