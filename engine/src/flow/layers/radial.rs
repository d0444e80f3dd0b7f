//! Radial contractions about the points of a context set (obstacle centres), applied to
//! the observation before the network: `f(z, c) = P_c⁻¹(f₀(z, c))`.
//!
//! One layer contracts about all `K` centres `o_i` at once, with strength `α ∈ (0, 1)`
//! shared by the centres and width `w > 0`:
//!
//! `P(y) = y − Σ_i (1 − s(q_i)) (y − o_i)`, `q_i = ‖y − o_i‖²`,
//! `s(q) = 1 − (α / K) / (1 + t)`, `t = (q / w²)^m`.
//!
//! About an isolated centre it pulls the space within about `w` towards the centre
//! (distances shrink by up to `1 − α / K`) and leaves the rest alone (`s → 1`).
//!
//! **A diffeomorphism for every context.** `P = ∇Φ` with `Φ(y) = ‖y‖²/2 − Σ_i G(q_i)`,
//! `G' = (1 − s) / 2`, and its Jacobian, the Hessian of `Φ`,
//!
//! `J = ∂P/∂y = I − Σ_i D_i`, `D_i = (1 − s_i) I − 2 s'(q_i) v_i v_iᵀ`, `v_i = y − o_i`,
//!
//! is symmetric. `D_i` has the eigenvalue `1 − s_i = (α/K) / (1 + t_i)` across `v_i` and
//! `1 − k'(r_i) = (α/K) (1 − (2m − 1) t_i) / (1 + t_i)²` along it (`k(r) = r s(r²)`, the
//! radial profile); both are at most `α / K`, so `J ⪰ (1 − α) I` wherever the centres
//! are, even all in one point. `Φ` is then strongly convex and `P`, its gradient, a
//! smooth bijection of ℝᵈ with a smooth inverse, with `log|det ∂P/∂y| = log det J`.
//! A stack of such layers is one too, so `f(·, c)` stays a diffeomorphism for every
//! context and the latent system's stability carries over untouched.
//!
//! **Invariant and continuous.** The centres enter through a sum: `P` does not depend on
//! their order, and it is smooth in every centre (no sorting, no order of application).
//!
//! **Why.** A latent path that passes a contracted centre at distance `ρ` passes the
//! obstacle itself at `k⁻¹(ρ) ≫ ρ`: straight latent paths bend around obstacles the way
//! the demonstrations do, wherever the context puts them. The conditioners would
//! otherwise have to learn from the context alone a deformation that is local around
//! each obstacle; a coupling layer deforms whole lines of its input. `α` and `w` (in
//! units of the configured `radius`) are learned per layer.
//!
//! `P⁻¹(u)` has no closed form: it minimises the strongly convex `Φ(y) − u·y`, found by
//! Newton's method on `P(y) − u` (its direction `−J⁻¹ r` always decreases `‖r‖`), with
//! backtracking, in `f64`, then refined by one step per dual level of the caller's scalar
//! type with `J` kept at the `f64` root, which makes first and second derivatives through
//! the root exact (each step raises the order of the error by one).

use serde::{Deserialize, Serialize};

use crate::flow::checkpoint::names::{self, RADIAL, STRENGTH, WIDTH};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::{FlowResult, invalid};
use crate::flow::layers::context_set::ContextSet;
use crate::nn::scalar::Scalar;

/// The largest point dimension `d` contracted about: `J` is factored in a `d × d` array on
/// the stack (obstacles are planar or spatial).
pub const MAX_CENTRE_DIM: usize = 3;

/// Which context points the observation is contracted about, and how.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContractionConfig {
    /// The centres: `count` points of `size = d` entries (raw units) in the context.
    pub centres: ContextSet,
    /// Layers, each contracting about every centre with its own `α` and `w`.
    pub layers: usize,
    /// `m` of the profile `t = (q / w²)^m`: the larger, the sharper its edge.
    pub exponent: u32,
    /// Unit of the widths, raw units (obstacles: their safety radius).
    pub radius: f64,
}

impl ContractionConfig {
    pub fn validate(&self, state_dim: usize, context_dim: usize) -> FlowResult<()> {
        let set = &self.centres;
        if set.size != state_dim || set.count == 0 || set.end() > context_dim {
            return Err(invalid(format!(
                "contraction centres ({set}) need points of the state's dimension {state_dim} \
                 inside the {context_dim}-D context"
            )));
        }
        if set.size > MAX_CENTRE_DIM {
            return Err(invalid(format!(
                "contractions work on points of at most {MAX_CENTRE_DIM} dimensions, \
                 not {}",
                set.size
            )));
        }
        if self.layers == 0 || self.exponent == 0 {
            return Err(invalid("contractions need layers and exponent >= 1".into()));
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(invalid("contraction radius must be finite and > 0".into()));
        }
        Ok(())
    }

    /// Parameter names and shapes of layer `l`: `α = sigmoid(strength)`,
    /// `w = radius · exp(width)`.
    pub fn parameter_names(l: usize) -> [String; 2] {
        [STRENGTH, WIDTH].map(|p| names::name(&[&RADIAL, &l, &p]))
    }
}

/// One layer's profile `s(q) = 1 − β / (1 + (q / w²)^m)`, `β = α / K` per centre.
#[derive(Clone, Copy, Debug)]
struct Profile {
    beta: f64,
    inverse_width_sq: f64,
    exponent: u32,
}

impl Profile {
    /// `(1 − s(q), s'(q))`.
    fn pull<S: Scalar>(&self, q: S) -> (S, S) {
        let x = q * self.inverse_width_sq;
        // `x^{m-1}` by repeated products: `m` is a small integer and `x` may be 0.
        let power_below = (1..self.exponent).fold(S::constant(1.0), |p, _| p * x);
        let denominator = power_below * x + 1.0;
        let m = f64::from(self.exponent);
        (
            S::constant(self.beta) / denominator,
            power_below * (self.beta * m * self.inverse_width_sq) / (denominator * denominator),
        )
    }
}

/// A symmetric `d × d` matrix factored as `L D Lᵀ` in place (`d ≤ MAX_CENTRE_DIM`).
struct Symmetric<S> {
    d: usize,
    a: [[S; MAX_CENTRE_DIM]; MAX_CENTRE_DIM],
}

impl<S: Scalar> Symmetric<S> {
    /// Factors `A = L D Lᵀ` (unit lower `L` below the diagonal, `D` on it). `A` is
    /// positive definite here (`J ⪰ (1 − α) I`), so no pivoting.
    fn factor(&mut self) {
        let d = self.d;
        for j in 0..d {
            for k in 0..j {
                let ljk_dk = self.a[j][k] * self.a[k][k];
                for i in j..d {
                    self.a[i][j] = self.a[i][j] - self.a[i][k] * ljk_dk;
                }
            }
            let pivot = self.a[j][j];
            for i in j + 1..d {
                self.a[i][j] = self.a[i][j] / pivot;
            }
        }
    }

    /// `log det A = log Π D_jj` after [`factor`](Self::factor): one logarithm, not one
    /// per pivot (the pivots lie in `[1 − α, 1 + …]`, so their product cannot overflow),
    /// and none where only a solve is wanted.
    fn log_det(&self) -> S {
        (1..self.d)
            .fold(self.a[0][0], |product, j| product * self.a[j][j])
            .ln()
    }
}

impl Symmetric<f64> {
    /// `b ← A⁻¹ b` after [`factor`](Self::factor), for a right-hand side in any scalar
    /// type (each of its components solved with the same factors).
    fn solve<T: Scalar>(&self, b: &mut [T]) {
        let d = self.d;
        for i in 0..d {
            for k in 0..i {
                b[i] = b[i] - b[k] * self.a[i][k];
            }
        }
        for (i, bi) in b.iter_mut().enumerate().take(d) {
            *bi = *bi * (1.0 / self.a[i][i]);
        }
        for i in (0..d).rev() {
            for k in i + 1..d {
                b[i] = b[i] - b[k] * self.a[k][i];
            }
        }
    }
}

/// Newton steps of the inverse in `f64` (each at least halves `‖P(y) − u‖` once Newton's
/// quadratic phase begins; backtracking keeps every step a decrease).
const INVERSE_STEPS: usize = 100;

/// `P(y)` of one layer about `centres` (the points back to back) into `out`, and its
/// Jacobian `J`.
fn layer<S: Scalar>(profile: &Profile, centres: &[f64], y: &[S], out: &mut [S]) -> Symmetric<S> {
    let d = y.len();
    let mut jacobian = Symmetric {
        d,
        a: [[S::constant(0.0); MAX_CENTRE_DIM]; MAX_CENTRE_DIM],
    };
    out.copy_from_slice(y);
    let mut diagonal = S::constant(1.0);
    for centre in centres.chunks_exact(d) {
        let (v, q) = offset(y, centre);
        let (pull, slope) = profile.pull(q);
        diagonal = diagonal - pull;
        let twice_slope = slope * 2.0;
        for i in 0..d {
            out[i] = out[i] - pull * v[i];
            for k in 0..d {
                jacobian.a[i][k] += twice_slope * v[i] * v[k];
            }
        }
    }
    for i in 0..d {
        jacobian.a[i][i] += diagonal;
    }
    jacobian
}

/// `P(y)` of one layer into `out`, without the Jacobian [`layer`] also forms.
fn image<S: Scalar>(profile: &Profile, centres: &[f64], y: &[S], out: &mut [S]) {
    out.copy_from_slice(y);
    for centre in centres.chunks_exact(y.len()) {
        let (v, q) = offset(y, centre);
        let (pull, _) = profile.pull(q);
        for (o, &vi) in out.iter_mut().zip(&v) {
            *o = *o - pull * vi;
        }
    }
}

/// `v = y − o` and `q = ‖v‖²` for the centre `o`.
#[inline(always)]
fn offset<S: Scalar>(y: &[S], centre: &[f64]) -> ([S; MAX_CENTRE_DIM], S) {
    let mut v = [S::constant(0.0); MAX_CENTRE_DIM];
    for (vi, (&yi, &o)) in v.iter_mut().zip(y.iter().zip(centre)) {
        *vi = yi + (-o);
    }
    let q = v[..y.len()]
        .iter()
        .fold(S::constant(0.0), |acc, &vi| acc + vi * vi);
    (v, q)
}

/// `P_c` of a trained flow (see the module docs).
#[derive(Clone, Debug)]
pub struct RadialContractions {
    config: ContractionConfig,
    profiles: Vec<Profile>,
}

/// The centres and the input `y` of every layer of an [`apply_recorded`](
/// RadialContractions::apply_recorded) pass, in order: what `∂P/∂y` needs.
#[derive(Clone, Debug, Default)]
pub struct ContractionTape {
    centres: Vec<f64>,
    inputs: Vec<f64>,
}

impl RadialContractions {
    pub fn from_weights(config: &ContractionConfig, weights: &mut Weights) -> FlowResult<Self> {
        let profiles = (0..config.layers)
            .map(|l| {
                let [strength, width] = ContractionConfig::parameter_names(l);
                let strength = weights.take(&strength, &[1])?[0];
                let width = config.radius * weights.take(&width, &[1])?[0].exp();
                Ok(Profile {
                    beta: 1.0 / (1.0 + (-strength).exp()) / config.centres.count as f64,
                    inverse_width_sq: 1.0 / (width * width),
                    exponent: config.exponent,
                })
            })
            .collect::<FlowResult<Vec<_>>>()?;
        let count = config.centres.count as f64;
        if profiles
            .iter()
            .any(|p| !(p.beta * count < 1.0 && p.inverse_width_sq.is_finite()))
        {
            return Err(invalid(
                "contraction strength or width out of range (α must stay below 1)".into(),
            ));
        }
        Ok(Self {
            config: *config,
            profiles,
        })
    }

    pub fn config(&self) -> &ContractionConfig {
        &self.config
    }

    /// `y ← P(y)`; returns `log|det ∂P/∂y|`.
    pub fn apply<S: Scalar>(&self, centres: &[f64], y: &mut [S]) -> S {
        let mut log_det = S::constant(0.0);
        let mut out = [S::constant(0.0); MAX_CENTRE_DIM];
        let out = &mut out[..y.len()];
        for profile in &self.profiles {
            let mut jacobian = layer(profile, centres, y, out);
            jacobian.factor();
            log_det += jacobian.log_det();
            y.copy_from_slice(out);
        }
        log_det
    }

    /// `y ← P(y)`, recording every layer's input (its value, for dual numbers) into `tape`.
    pub fn apply_recorded<S: Scalar>(
        &self,
        centres: &[f64],
        y: &mut [S],
        tape: &mut ContractionTape,
    ) {
        tape.centres.clear();
        tape.centres.extend_from_slice(centres);
        tape.inputs.clear();
        let mut out = [S::constant(0.0); MAX_CENTRE_DIM];
        let out = &mut out[..y.len()];
        for profile in &self.profiles {
            tape.inputs.extend(y.iter().map(|x| x.value()));
            layer(profile, centres, y, out);
            y.copy_from_slice(out);
        }
    }

    /// `u ← P⁻¹(u)`; returns `log|det ∂P⁻¹/∂u|`.
    pub fn invert<S: Scalar>(&self, centres: &[f64], u: &mut [S]) -> S {
        let mut log_det = S::constant(0.0);
        let mut image = [S::constant(0.0); MAX_CENTRE_DIM];
        let image = &mut image[..u.len()];
        for profile in self.profiles.iter().rev() {
            invert_layer(profile, centres, u, None);
            let mut jacobian = layer(profile, centres, u, image);
            jacobian.factor();
            log_det = log_det - jacobian.log_det();
        }
        log_det
    }

    /// `u ← P⁻¹(u)` without the log-determinant, which costs each layer another
    /// evaluation of `P` and `J` in `S`: the policy's actions never use it. With `near`, a
    /// [`apply_recorded`](Self::apply_recorded) pass whose output `u` is close to, each
    /// layer's root search starts from that layer's recorded input instead of from `u`:
    /// a pass back through the recorded point converges at once.
    pub fn invert_point<S: Scalar>(
        &self,
        centres: &[f64],
        u: &mut [S],
        near: Option<&ContractionTape>,
    ) {
        let d = u.len();
        for (l, profile) in self.profiles.iter().enumerate().rev() {
            // A tape of another flow (or none yet) falls back to starting from `u`.
            let start = near.and_then(|tape| tape.inputs.get(l * d..(l + 1) * d));
            invert_layer(profile, centres, u, start);
        }
    }

    /// `du ← (∂P/∂y)⁻¹ du` at the recorded `y`: through each layer in reverse order,
    /// `J⁻¹ du` with `J` at that layer's input.
    pub fn tangent(&self, tape: &ContractionTape, du: &mut [f64]) {
        let d = du.len();
        let mut image = [0.0; MAX_CENTRE_DIM];
        let image = &mut image[..d];
        let layers = self.profiles.iter().zip(tape.inputs.chunks_exact(d));
        for (profile, y) in layers.rev() {
            let mut jacobian = layer(profile, &tape.centres, y, image);
            jacobian.factor();
            jacobian.solve(du);
        }
    }
}

/// `u ← P⁻¹(u)` for one layer: the root `y₀` in `f64` ([`solve_layer`], from `start`, or
/// from `u` itself), then one step `y ← y − J(y₀)⁻¹ (P(y) − u)` in `S` per dual level of
/// `S` (none for plain `f64`, whose lanes are 2^levels). Each step makes one more order
/// of the derivatives carried by `S` exact: the error after the first has no part below
/// second order, and `J(y) − J(y₀)`, of first order, only meets it in orders above what
/// `S` carries. So `J` is formed and factored once, in `f64`, and the steps need `P` alone.
fn invert_layer<S: Scalar>(profile: &Profile, centres: &[f64], u: &mut [S], start: Option<&[f64]>) {
    let d = u.len();
    let mut target = [0.0; MAX_CENTRE_DIM];
    for (t, x) in target.iter_mut().zip(u.iter()) {
        *t = x.value();
    }
    let target = &target[..d];
    let (root, mut jacobian) = solve_layer(profile, centres, target, start.unwrap_or(target));
    jacobian.factor();
    let mut y = [S::constant(0.0); MAX_CENTRE_DIM];
    let y = &mut y[..d];
    for (yi, &x) in y.iter_mut().zip(&root) {
        *yi = S::constant(x);
    }
    let mut residual = [S::constant(0.0); MAX_CENTRE_DIM];
    let residual = &mut residual[..d];
    for _ in 0..S::LANES.trailing_zeros() {
        image(profile, centres, y, residual);
        for (r, &x) in residual.iter_mut().zip(u.iter()) {
            *r = *r - x;
        }
        jacobian.solve(residual);
        for (yi, &step) in y.iter_mut().zip(residual.iter()) {
            *yi = *yi - step;
        }
    }
    u.copy_from_slice(y);
}

/// The `y` with `P(y) = u` for one layer, in `f64`, searched from `start` (see the module
/// docs): Newton's method converges from anywhere, and from a root in no step at all.
/// Also returns `J(y)`, not yet factored.
fn solve_layer(
    profile: &Profile,
    centres: &[f64],
    u: &[f64],
    start: &[f64],
) -> ([f64; MAX_CENTRE_DIM], Symmetric<f64>) {
    let d = u.len();
    let residual = |y: &[f64], image: &mut [f64]| -> (Symmetric<f64>, f64) {
        let jacobian = layer(profile, centres, y, image);
        let mut norm = 0.0;
        for (p, &x) in image.iter_mut().zip(u) {
            *p -= x;
            norm += *p * *p;
        }
        (jacobian, norm)
    };
    let scale: f64 = u.iter().map(|x| x * x).sum::<f64>() + 1.0;
    let mut y = [0.0; MAX_CENTRE_DIM];
    y[..d].copy_from_slice(start);
    let mut r = [0.0; MAX_CENTRE_DIM];
    let (mut jacobian, mut norm) = residual(&y[..d], &mut r[..d]);
    for _ in 0..INVERSE_STEPS {
        if norm <= (4.0 * f64::EPSILON).powi(2) * scale {
            break;
        }
        jacobian.factor();
        let mut step = r;
        jacobian.solve(&mut step[..d]);
        let mut length = 1.0;
        loop {
            let mut trial = y;
            for (t, s) in trial[..d].iter_mut().zip(&step[..d]) {
                *t -= length * s;
            }
            let mut trial_r = [0.0; MAX_CENTRE_DIM];
            let (trial_jacobian, trial_norm) = residual(&trial[..d], &mut trial_r[..d]);
            // Newton's direction decreases ‖r‖² at the rate 2‖r‖²: accept any decrease,
            // halving until there is one (or the step no longer moves `y`).
            if trial_norm < norm || length < 1e-12 {
                (y, r, jacobian, norm) = (trial, trial_r, trial_jacobian, trial_norm);
                break;
            }
            length *= 0.5;
        }
    }
    (y, jacobian)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::scalar::Dual;

    /// Two layers about two centres in the plane, the first strongly contracting; the
    /// centres `far` apart.
    fn contractions(far: f64) -> (RadialContractions, Vec<f64>) {
        let config = ContractionConfig {
            centres: ContextSet {
                start: 0,
                count: 2,
                size: 2,
            },
            layers: 2,
            exponent: 3,
            radius: 0.2,
        };
        let mut weights = Weights::default();
        for (l, (strength, width)) in [(5.0, 0.3), (-1.0, -0.5)].into_iter().enumerate() {
            for (name, value) in ContractionConfig::parameter_names(l)
                .into_iter()
                .zip([strength, width])
            {
                weights.insert(
                    name,
                    crate::flow::Tensor {
                        shape: vec![1],
                        data: vec![value],
                    },
                );
            }
        }
        let contractions = RadialContractions::from_weights(&config, &mut weights).unwrap();
        weights.finish().unwrap();
        (contractions, vec![0.1, -0.2, 0.1 + far, 0.1])
    }

    /// Points near, on and far from the first centre.
    fn points() -> Vec<[f64; 2]> {
        let mut points = vec![[0.1, -0.2], [0.1 + 1e-7, -0.2], [0.45, 0.1], [3.0, -4.0]];
        for i in 0..40 {
            let angle = 0.7 * i as f64;
            let r = 0.005 * (i as f64).powf(1.5);
            points.push([0.1 + r * angle.cos(), -0.2 + r * angle.sin()]);
        }
        points
    }

    fn apply(p: &RadialContractions, centres: &[f64], y: [f64; 2]) -> [f64; 2] {
        let mut u = y;
        p.apply(centres, &mut u);
        u
    }

    #[test]
    fn a_strong_layer_contracts_the_disc_about_an_isolated_centre() {
        let (p, centres) = contractions(50.0);
        let centre = [centres[0], centres[1]];
        let profile = p.profiles[0];
        let mut out = [0.0; 2];
        let mut distance = |r: f64| {
            layer(&profile, &centres, &[centre[0] + r, centre[1]], &mut out);
            (out[0] - centre[0]).hypot(out[1] - centre[1])
        };
        // Within the width distances to the centre shrink by up to `1 − α / K`, `K = 2`.
        let ratio = distance(0.01) / 0.01;
        assert!((ratio - (1.0 - profile.beta)).abs() < 1e-6, "{ratio}");
        assert!(profile.beta > 0.49, "{}", profile.beta);
        // Far from both centres it is nearly the identity.
        assert!((distance(2.0) - 2.0).abs() < 1e-3);
    }

    #[test]
    fn invert_undoes_apply_even_with_the_centres_on_top_of_each_other() {
        for far in [0.35, 1e-9, 0.0] {
            let (p, centres) = contractions(far);
            for y in points() {
                let mut back = apply(&p, &centres, y);
                let log_det_inverse = p.invert(&centres, &mut back);
                let mut u = y;
                let log_det = p.apply(&centres, &mut u);
                assert!(log_det.is_finite(), "{far} {y:?}");
                assert!(
                    (back[0] - y[0]).abs() < 1e-12 && (back[1] - y[1]).abs() < 1e-12,
                    "{far}: {y:?} -> {back:?}"
                );
                assert!(
                    (log_det + log_det_inverse).abs() < 1e-9,
                    "{log_det} {log_det_inverse}"
                );
            }
        }
    }

    #[test]
    fn the_order_of_the_centres_does_not_matter() {
        let (p, centres) = contractions(0.3);
        let swapped = [centres[2], centres[3], centres[0], centres[1]];
        for y in points() {
            let (mut a, mut b) = (y, y);
            let (log_a, log_b) = (p.apply(&centres, &mut a), p.apply(&swapped, &mut b));
            assert!((a[0] - b[0]).abs() < 1e-15 && (a[1] - b[1]).abs() < 1e-15);
            assert!((log_a - log_b).abs() < 1e-13);
            // Not because the second centre is ignored.
            let mut alone = y;
            p.apply(&[centres[0], centres[1], 40.0, 40.0], &mut alone);
            if (y[0] - 0.4).hypot(y[1] - 0.1) < 0.3 {
                assert!(
                    (alone[0] - a[0]).abs() + (alone[1] - a[1]).abs() > 1e-4,
                    "{y:?}"
                );
            }
        }
    }

    #[test]
    fn log_determinant_and_inverse_tangent_match_finite_differences() {
        let (p, centres) = contractions(0.3);
        let h = 1e-6;
        for y in points().into_iter().skip(1) {
            let mut jacobian = nalgebra::Matrix2::zeros();
            for j in 0..2 {
                let (mut plus, mut minus) = (y, y);
                plus[j] += h;
                minus[j] -= h;
                let (up, um) = (apply(&p, &centres, plus), apply(&p, &centres, minus));
                for i in 0..2 {
                    jacobian[(i, j)] = (up[i] - um[i]) / (2.0 * h);
                }
            }
            let mut u = y;
            let log_det = p.apply(&centres, &mut u);
            let expected = jacobian.determinant().ln();
            assert!(
                (log_det - expected).abs() < 1e-5 * (1.0 + expected.abs()),
                "{y:?}"
            );

            let mut tape = ContractionTape::default();
            let mut recorded = y;
            p.apply_recorded(&centres, &mut recorded, &mut tape);
            assert_eq!(recorded, u);
            let du = [0.3, -0.8];
            let mut dy = du;
            p.tangent(&tape, &mut dy);
            let expected = jacobian.try_inverse().unwrap() * nalgebra::Vector2::from(du);
            let scale = 1.0 + expected.norm();
            for i in 0..2 {
                assert!(
                    (dy[i] - expected[i]).abs() < 1e-5 * scale,
                    "{dy:?} {expected:?}"
                );
            }

            // The inverse in dual numbers carries the same derivative.
            let mut dual = [Dual::new(u[0], du[0]), Dual::new(u[1], du[1])];
            p.invert(&centres, &mut dual);
            assert!((dual[0].du - dy[0]).abs() < 1e-9 * scale);
            assert!((dual[1].du - dy[1]).abs() < 1e-9 * scale);
        }
    }

    /// `P⁻¹(u + t du)` in second-order dual numbers: the `t²` part (the Newton steps with
    /// `J` frozen at the `f64` root) against central differences of the first-order one,
    /// and the same from every start of the root search: the recorded pass's points,
    /// another point's (a stale tape only costs iterations) or none (an empty tape).
    #[test]
    fn second_order_inverse_matches_finite_differences_from_any_start() {
        let (p, centres) = contractions(0.3);
        let du = [0.3, -0.8];
        let first = |u: [f64; 2]| {
            let mut x = [Dual::new(u[0], du[0]), Dual::new(u[1], du[1])];
            p.invert(&centres, &mut x);
            [x[0].du, x[1].du]
        };
        let (mut elsewhere, empty) = (ContractionTape::default(), ContractionTape::default());
        p.apply_recorded(&centres, &mut [2.0, 3.0][..], &mut elsewhere);
        let h = 1e-5;
        for y in points().into_iter().skip(1) {
            let mut tape = ContractionTape::default();
            let mut u = y;
            p.apply_recorded(&centres, &mut u, &mut tape);
            let (plus, minus) = (
                first([u[0] + h * du[0], u[1] + h * du[1]]),
                first([u[0] - h * du[0], u[1] - h * du[1]]),
            );
            let seeded = |i: usize| Dual::new(Dual::new(u[i], du[i]), Dual::new(du[i], 0.0));
            let mut reference = [seeded(0), seeded(1)];
            p.invert(&centres, &mut reference);
            for i in 0..2 {
                let expected = (plus[i] - minus[i]) / (2.0 * h);
                let second = reference[i].du.du;
                assert!(
                    (second - expected).abs() < 1e-5 * (1.0 + expected.abs()),
                    "{y:?}: {second} vs {expected}"
                );
            }
            for near in [None, Some(&tape), Some(&elsewhere), Some(&empty)] {
                let mut x = [seeded(0), seeded(1)];
                p.invert_point(&centres, &mut x, near);
                for (a, b) in x.iter().zip(&reference) {
                    let parts = [a.re.re - b.re.re, a.re.du - b.re.du, a.du.re - b.du.re];
                    assert!(
                        parts.iter().all(|e| e.abs() < 1e-12) && (a.du.du - b.du.du).abs() < 1e-9,
                        "{y:?} from {near:?}: {a:?} vs {b:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_strength_that_rounds_to_one_is_refused() {
        let (p, _) = contractions(0.3);
        let mut weights = Weights::default();
        for l in 0..2 {
            for (name, value) in ContractionConfig::parameter_names(l)
                .into_iter()
                .zip([40.0, 0.0])
            {
                weights.insert(
                    name,
                    crate::flow::Tensor {
                        shape: vec![1],
                        data: vec![value],
                    },
                );
            }
        }
        assert!(RadialContractions::from_weights(p.config(), &mut weights).is_err());
    }
}
