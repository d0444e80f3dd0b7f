//! Scalars the network is generic over: `f64` for plain evaluation and forward-mode dual
//! numbers `a + b·ε` (ε² = 0) for exact directional derivatives.
//!
//! One dual level gives a Jacobian-vector product `J_f(z)·v` at the cost of one pass;
//! nesting (`Dual<Dual<f64>>`) gives the second directional derivative needed for the
//! acceleration feed-forward `d/dt (J_f v)`. The network code is written once over
//! [`Scalar`], so values and derivatives can never disagree.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

/// A real number type the flow can be evaluated in.
pub trait Scalar:
    Copy
    + Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + Mul<f64, Output = Self>
    + Add<f64, Output = Self>
{
    /// Number of `f64` components: 1 for `f64`, twice the inner count per dual level,
    /// `re`'s components first (`Dual<Dual<f64>>`: `re.re, re.du, du.re, du.du`).
    ///
    /// A linear map with `f64` coefficients acts on every component independently, so
    /// the MLPs evaluate `W x` for all components as one matrix product sharing the loads
    /// of `W`; their activations rely on this order for one, two and four lanes.
    const LANES: usize;
    /// Component `lane` (`0` is the primal value, `1..` the derivative parts).
    fn lane(self, lane: usize) -> f64;
    /// The value whose component `l` is `component(l)`.
    fn from_lanes(component: impl Fn(usize) -> f64) -> Self;
    /// A constant (zero derivative).
    fn constant(value: f64) -> Self;
    /// The primal value; branches (spline bins, tails) are decided on it.
    fn value(self) -> f64;
    fn exp(self) -> Self;
    /// `e^x` for `x <= 0` (see [`exp_non_positive`]); faster than [`exp`](Self::exp).
    fn exp_non_positive(self) -> Self;
    fn ln(self) -> Self;
    fn tanh(self) -> Self;
    fn sqrt(self) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    /// `atan2(self, x)`, the polar angle of `(x, self)`.
    fn atan2(self, x: Self) -> Self;
    /// The logistic sigmoid `1 / (1 + e^{-x})`.
    fn sigmoid(self) -> Self;
    /// `ln(1 + e^x)`, evaluated without overflow.
    fn softplus(self) -> Self;
    /// `g(self)` for a smooth `g` given by its value and derivatives at the primal value,
    /// `derivatives = [g, g', g'', ...]`, as many as the dual levels plus one (three for
    /// `Dual<Dual<f64>>`). Lets a caller evaluate `g` for many numbers at once (vectorised
    /// `f64` loops) and only apply the chain rule per number.
    fn compose(self, derivatives: &[f64]) -> Self;
}

/// `e^x` for `x <= 0`, branch-free so loops vectorise; relative error ~2e-16, inputs
/// below -700 are treated as -700 (`e^-700 ≈ 1e-304`).
///
/// Cody–Waite reduction `x = k ln 2 + r`, `|r| ≤ ln 2 / 2`, Taylor polynomial of degree 13
/// for `e^r` (truncation < 2e-16), and `2^k` applied by adding `k` to the exponent bits.
/// `k` is read from the low mantissa bits of `x / ln 2 + 1.5·2^52`, which avoids a
/// float-to-integer conversion AVX2 lacks. The polynomial is evaluated with Estrin's
/// scheme (pairs of terms combined with `r²`, `r⁴`, `r⁸`): a dependency chain of four
/// multiply-adds instead of Horner's thirteen, so consecutive evaluations overlap.
#[inline(always)]
pub fn exp_non_positive(x: f64) -> f64 {
    exp_non_positive_with::<false>(x)
}

/// [`exp_non_positive`], with fused multiply-adds when `FUSED`. Only code compiled for a
/// target with FMA instructions should set it: elsewhere `mul_add` is a library call.
#[inline(always)]
pub fn exp_non_positive_with<const FUSED: bool>(x: f64) -> f64 {
    const ROUND: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    const LN2_HI: f64 = 6.931_471_803_691_238e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    /// `1 / k!`, `k = 0..=13`.
    const TAYLOR: [f64; 14] = [
        1.0,
        1.0,
        1.0 / 2.0,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5_040.0,
        1.0 / 40_320.0,
        1.0 / 362_880.0,
        1.0 / 3_628_800.0,
        1.0 / 39_916_800.0,
        1.0 / 479_001_600.0,
        1.0 / 6_227_020_800.0,
    ];
    let fma = |a: f64, b: f64, c: f64| if FUSED { a.mul_add(b, c) } else { a * b + c };
    let x = x.max(-700.0);
    let shifted = fma(x, std::f64::consts::LOG2_E, ROUND);
    let k = shifted - ROUND;
    let r = fma(-k, LN2_LO, fma(-k, LN2_HI, x));
    let pairs: [f64; 7] = std::array::from_fn(|i| fma(TAYLOR[2 * i + 1], r, TAYLOR[2 * i]));
    let r2 = r * r;
    let quads = [
        fma(pairs[1], r2, pairs[0]),
        fma(pairs[3], r2, pairs[2]),
        fma(pairs[5], r2, pairs[4]),
    ];
    let r4 = r2 * r2;
    let low = fma(quads[1], r4, quads[0]);
    let high = fma(pairs[6], r4, quads[2]);
    let p = fma(high, r4 * r4, low);
    f64::from_bits(p.to_bits().wrapping_add(shifted.to_bits() << 52))
}

/// `tanh(x) = sign(x) (1 - e^{-2|x|}) / (1 + e^{-2|x|})` with the branch-free
/// [`exp_non_positive_with`], so a loop of them vectorises (the MLPs' hot spot); absolute
/// error ~1e-16. `FUSED` as for [`exp_non_positive_with`].
#[inline(always)]
pub fn tanh_with<const FUSED: bool>(x: f64) -> f64 {
    let e = exp_non_positive_with::<FUSED>(-2.0 * x.abs());
    ((1.0 - e) / (1.0 + e)).copysign(x)
}

/// `(softplus(x), σ(x))` from one exponential, for callers that need both.
#[inline]
pub fn softplus_and_sigmoid(x: f64) -> (f64, f64) {
    let e = exp_non_positive(-x.abs());
    (softplus_from(x, e), sigmoid_from(x, e))
}

/// `σ(x) = 1 / (1 + e^{-x})` from `e = e^{-|x|}`, so neither side overflows:
/// `1 / (1 + e)` for `x ≥ 0`, `e / (1 + e)` otherwise.
#[inline(always)]
fn sigmoid_from(x: f64, e: f64) -> f64 {
    let s = 1.0 / (1.0 + e);
    if x >= 0.0 { s } else { e * s }
}

/// `softplus(x) = ln(1 + e^x) = max(x, 0) + ln(1 + e)` from `e = e^{-|x|}`, without
/// overflow.
#[inline(always)]
fn softplus_from(x: f64, e: f64) -> f64 {
    x.max(0.0) + f64::ln_1p(e)
}

/// A forward-mode dual number `re + du·ε` with `ε² = 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<S> {
    pub re: S,
    pub du: S,
}

impl<S: Scalar> Dual<S> {
    pub fn new(re: S, du: S) -> Self {
        Self { re, du }
    }

    /// Applies a function with value `value` and derivative `derivative` at `self.re`.
    #[inline]
    fn chain(self, value: S, derivative: S) -> Self {
        Self::new(value, self.du * derivative)
    }
}

impl Scalar for f64 {
    const LANES: usize = 1;
    #[inline(always)]
    fn lane(self, _lane: usize) -> f64 {
        self
    }
    #[inline(always)]
    fn from_lanes(component: impl Fn(usize) -> f64) -> Self {
        component(0)
    }
    #[inline]
    fn constant(value: f64) -> Self {
        value
    }
    #[inline]
    fn value(self) -> f64 {
        self
    }
    #[inline]
    fn exp(self) -> Self {
        f64::exp(self)
    }
    #[inline(always)]
    fn exp_non_positive(self) -> Self {
        exp_non_positive(self)
    }
    #[inline]
    fn ln(self) -> Self {
        f64::ln(self)
    }
    /// See [`tanh_with`].
    #[inline(always)]
    fn tanh(self) -> Self {
        tanh_with::<false>(self)
    }
    #[inline]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline]
    fn sin(self) -> Self {
        f64::sin(self)
    }
    #[inline]
    fn cos(self) -> Self {
        f64::cos(self)
    }
    #[inline]
    fn atan2(self, x: Self) -> Self {
        f64::atan2(self, x)
    }
    #[inline]
    fn sigmoid(self) -> Self {
        sigmoid_from(self, exp_non_positive(-self.abs()))
    }
    #[inline]
    fn softplus(self) -> Self {
        softplus_from(self, exp_non_positive(-self.abs()))
    }
    #[inline(always)]
    fn compose(self, derivatives: &[f64]) -> Self {
        derivatives[0]
    }
}

impl<S: Scalar> Scalar for Dual<S> {
    /// `re`'s components, then `du`'s.
    const LANES: usize = 2 * S::LANES;
    #[inline(always)]
    fn lane(self, lane: usize) -> f64 {
        if lane < S::LANES {
            self.re.lane(lane)
        } else {
            self.du.lane(lane - S::LANES)
        }
    }
    #[inline(always)]
    fn from_lanes(component: impl Fn(usize) -> f64) -> Self {
        Self::new(
            S::from_lanes(&component),
            S::from_lanes(|l| component(l + S::LANES)),
        )
    }
    #[inline]
    fn constant(value: f64) -> Self {
        Self::new(S::constant(value), S::constant(0.0))
    }
    #[inline]
    fn value(self) -> f64 {
        self.re.value()
    }
    #[inline]
    fn exp(self) -> Self {
        let e = self.re.exp();
        self.chain(e, e)
    }
    #[inline]
    fn exp_non_positive(self) -> Self {
        let e = self.re.exp_non_positive();
        self.chain(e, e)
    }
    #[inline]
    fn ln(self) -> Self {
        self.chain(self.re.ln(), S::constant(1.0) / self.re)
    }
    #[inline]
    fn tanh(self) -> Self {
        let t = self.re.tanh();
        self.chain(t, -(t * t) + 1.0)
    }
    #[inline]
    fn sqrt(self) -> Self {
        let s = self.re.sqrt();
        self.chain(s, S::constant(0.5) / s)
    }
    #[inline]
    fn sin(self) -> Self {
        self.chain(self.re.sin(), self.re.cos())
    }
    #[inline]
    fn cos(self) -> Self {
        self.chain(self.re.cos(), -self.re.sin())
    }
    #[inline]
    fn atan2(self, x: Self) -> Self {
        let r2 = x.re * x.re + self.re * self.re;
        Self::new(self.re.atan2(x.re), (x.re * self.du - self.re * x.du) / r2)
    }
    #[inline]
    fn sigmoid(self) -> Self {
        let s = self.re.sigmoid();
        self.chain(s, s * (-s + 1.0))
    }
    #[inline]
    fn softplus(self) -> Self {
        self.chain(self.re.softplus(), self.re.sigmoid())
    }
    /// `g(re + du ε) = g(re) + g'(re) du ε`, with `g'`'s derivatives the tail of `g`'s.
    #[inline(always)]
    fn compose(self, derivatives: &[f64]) -> Self {
        self.chain(
            self.re.compose(derivatives),
            self.re.compose(&derivatives[1..]),
        )
    }
}

impl<S: Scalar> Add for Dual<S> {
    type Output = Self;
    #[inline]
    fn add(self, rhs: Self) -> Self {
        Self::new(self.re + rhs.re, self.du + rhs.du)
    }
}
impl<S: Scalar> Sub for Dual<S> {
    type Output = Self;
    #[inline]
    fn sub(self, rhs: Self) -> Self {
        Self::new(self.re - rhs.re, self.du - rhs.du)
    }
}
impl<S: Scalar> Mul for Dual<S> {
    type Output = Self;
    #[inline]
    fn mul(self, rhs: Self) -> Self {
        Self::new(self.re * rhs.re, self.re * rhs.du + self.du * rhs.re)
    }
}
impl<S: Scalar> Div for Dual<S> {
    type Output = Self;
    #[inline]
    fn div(self, rhs: Self) -> Self {
        let inv = S::constant(1.0) / rhs.re;
        let q = self.re * inv;
        Self::new(q, (self.du - q * rhs.du) * inv)
    }
}
impl<S: Scalar> Neg for Dual<S> {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        Self::new(-self.re, -self.du)
    }
}
impl<S: Scalar> AddAssign for Dual<S> {
    #[inline]
    fn add_assign(&mut self, rhs: Self) {
        self.re += rhs.re;
        self.du += rhs.du;
    }
}
impl<S: Scalar> Mul<f64> for Dual<S> {
    type Output = Self;
    #[inline]
    fn mul(self, rhs: f64) -> Self {
        Self::new(self.re * rhs, self.du * rhs)
    }
}
impl<S: Scalar> Add<f64> for Dual<S> {
    type Output = Self;
    #[inline]
    fn add(self, rhs: f64) -> Self {
        Self::new(self.re + rhs, self.du)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(f: impl Fn(Dual<f64>) -> Dual<f64>, g: impl Fn(f64) -> f64, x: f64) {
        let h = 1e-6;
        let fd = (g(x + h) - g(x - h)) / (2.0 * h);
        let d = f(Dual::new(x, 1.0));
        assert!((d.re - g(x)).abs() < 1e-14 * (1.0 + g(x).abs()));
        assert!(
            (d.du - fd).abs() < 1e-7 * (1.0 + fd.abs()),
            "{} vs {}",
            d.du,
            fd
        );
    }

    #[test]
    fn dual_derivatives_match_finite_differences() {
        for &x in &[-2.3, -0.4, 0.7, 1.9] {
            check(|d| d.tanh(), f64::tanh, x);
            check(|d| d.exp(), f64::exp, x);
            check(|d| d.sin() * d.cos(), |v| v.sin() * v.cos(), x);
            check(|d| d.softplus(), |v| v.softplus(), x);
            check(
                |d| d.sigmoid() / (d * d + 1.0),
                |v| v.sigmoid() / (v * v + 1.0),
                x,
            );
            check(
                |d| (d * d + 1.0).sqrt().ln(),
                |v| (v * v + 1.0).sqrt().ln(),
                x,
            );
            check(
                |d| d.atan2(Dual::constant(0.3) - d),
                |v| v.atan2(0.3 - v),
                x,
            );
        }
    }

    #[test]
    fn branch_free_exp_matches_libm() {
        let mut worst: f64 = 0.0;
        for i in 0..200_000 {
            let x = -(i as f64) * 7e-4 - 1e-9 * i as f64;
            let (fast, libm) = (exp_non_positive(x), x.exp());
            worst = worst.max(((fast - libm) / libm).abs());
        }
        assert!(worst < 1e-15, "worst relative error {worst:e}");
        assert_eq!(exp_non_positive(0.0), 1.0);
        for x in [1e-3, 0.3, -2.0, 7.5, -19.0, 40.0] {
            assert!((Scalar::tanh(x) - f64::tanh(x)).abs() < 1e-15, "{x}");
            assert!((tanh_with::<true>(x) - f64::tanh(x)).abs() < 1e-15, "{x}");
        }
    }

    #[test]
    fn nested_duals_give_second_derivatives() {
        // d²/dx² tanh(x) = -2 tanh(x) (1 - tanh²(x)).
        let x = 0.37;
        let d = Dual::new(Dual::new(x, 1.0), Dual::new(1.0, 0.0)).tanh();
        let t = x.tanh();
        assert!((d.du.du - (-2.0 * t * (1.0 - t * t))).abs() < 1e-14);
    }

    /// `compose` with `sin`'s derivatives gives what the dual numbers' own `sin` gives, at
    /// every level and in every component of a nested dual with all parts non-zero.
    #[test]
    fn compose_applies_the_chain_rule_at_every_level() {
        let x = Dual::new(Dual::new(0.37, -1.3), Dual::new(0.8, 2.1));
        let a = x.value();
        let sin = [a.sin(), a.cos(), -a.sin()];
        let (composed, direct) = (x.compose(&sin), x.sin());
        for lane in 0..4 {
            assert!(
                (composed.lane(lane) - direct.lane(lane)).abs() < 1e-15,
                "component {lane}"
            );
        }
        let once = x.re.compose(&sin);
        assert_eq!((once.re, once.du), (direct.re.re, direct.re.du));
        assert_eq!(0.37.compose(&sin), sin[0]);
    }
}
