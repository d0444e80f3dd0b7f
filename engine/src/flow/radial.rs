//! Radial contractions about points of the context (obstacle centres), applied to the
//! observation before the network: `f(z, c) = P_c⁻¹(f₀(z, c))`.
//!
//! For a centre `o`, strength `α ∈ (0, 1)` and width `w > 0`, one contraction is
//!
//! `P(y) = o + s(q) (y − o)`, `q = ‖y − o‖²`, `s(q) = 1 − α / (1 + t)`, `t = (q / w²)^m`.
//!
//! It pulls the space within about `w` of `o` towards `o` (`s(0) = 1 − α`) and leaves the
//! rest alone (`s → 1`). Distances from `o` map by `k(r) = r s(r²)`, whose slope
//!
//! `k'(r) = s + 2q s'(q) = 1 − α (1 − (2m − 1) t) / (1 + t)²`
//!
//! never falls below `1 − α > 0`; `s` is a polynomial in `q` over one, so `P` is a smooth
//! bijection of ℝᵈ with a smooth inverse for every weight value, with
//!
//! `log|det ∂P/∂y| = log k'(r) + (d − 1) log s`, `∂P/∂y = s I + 2 s'(q) (y − o)(y − o)ᵀ`.
//!
//! **Why.** `P_c` is the composition over `layers` of one contraction per centre of the
//! context set, so `f(·, c)` stays a diffeomorphism for every context and the latent
//! system's stability carries over untouched. A latent path that passes a contracted
//! centre at distance `ρ` passes the obstacle itself at `k⁻¹(ρ) ≫ ρ`: straight latent
//! paths bend around obstacles the way the demonstrations do, wherever the context puts
//! them, and only the thin bundle within `k(R)` of a centre comes closer than `R`. The
//! conditioners would otherwise have to learn from the context alone a deformation that
//! is local around each obstacle; a coupling layer deforms whole lines of its input.
//! `α` and `w` (in units of the configured `radius`) are learned per layer, shared by the
//! centres, which are interchangeable.
//!
//! **Order.** Each layer composes its centres' contractions in the order the context gives
//! them: continuous in every centre (no re-sorting, so no jump where two centres' keys
//! cross), but not invariant to the order of the centres, since contractions about
//! different points do not commute. Contractions about well-separated centres nearly
//! do; the set encoder and the couplings' local features ([`super::conditioner`]) are
//! exactly invariant.
//!
//! `P⁻¹` has no closed form: `q` solves `q s(q)² = ‖u − o‖²` (increasing in `q`, root
//! bracketed by `[ρ², ρ² / (1 − α)²]`), found by safeguarded Newton in `f64` and then
//! refined by two Newton steps in the caller's scalar type, which makes first and second
//! derivatives through the root exact (each step squares the error's order).

use serde::{Deserialize, Serialize};

use super::context_set::ContextSet;
use super::error::{FlowResult, invalid};
use super::scalar::Scalar;
use super::weights::Weights;

/// Which context points the observation is contracted about, and how.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContractionConfig {
    /// The centres: `count` points of `size = d` entries (raw units) in the context.
    pub centres: ContextSet,
    /// Contractions per centre, each with its own `α` and `w`.
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
                "contraction centres {set:?} need points of the state's dimension {state_dim} \
                 inside the {context_dim}-D context"
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
        [
            format!("contraction.{l}.strength"),
            format!("contraction.{l}.width"),
        ]
    }
}

/// One profile `s(q) = 1 − α / (1 + (q / w²)^m)`.
#[derive(Clone, Copy, Debug)]
struct Profile {
    alpha: f64,
    inverse_width_sq: f64,
    exponent: u32,
}

/// `s`, `k'` and `s'(q)` at one `q`.
struct Slopes<S> {
    scale: S,
    radial: S,
    scale_derivative: S,
}

impl Profile {
    fn slopes<S: Scalar>(&self, q: S) -> Slopes<S> {
        let x = q * self.inverse_width_sq;
        // `x^{m-1}` by repeated products: `m` is a small integer and `x` may be 0.
        let power_below = (1..self.exponent).fold(S::constant(1.0), |p, _| p * x);
        let t = power_below * x;
        let denominator = t + 1.0;
        let m = f64::from(self.exponent);
        Slopes {
            scale: S::constant(1.0) - S::constant(self.alpha) / denominator,
            radial: S::constant(1.0)
                - (S::constant(1.0) - t * (2.0 * m - 1.0)) * self.alpha
                    / (denominator * denominator),
            scale_derivative: power_below * (self.alpha * m * self.inverse_width_sq)
                / (denominator * denominator),
        }
    }

    /// `q s(q)² − ρ²` and its derivative `s k'` in `q`.
    fn residual<S: Scalar>(&self, q: S, rho_sq: S) -> (S, S) {
        let Slopes { scale, radial, .. } = self.slopes(q);
        (q * scale * scale - rho_sq, scale * radial)
    }

    /// The `q` with `q s(q)² = ρ²`.
    fn solve(&self, rho_sq: f64) -> f64 {
        if rho_sq == 0.0 {
            return 0.0;
        }
        let (mut low, mut high) = (rho_sq, rho_sq / ((1.0 - self.alpha) * (1.0 - self.alpha)));
        let mut q = low;
        for _ in 0..200 {
            let (h, slope) = self.residual(q, rho_sq);
            if h.abs() <= 4.0 * f64::EPSILON * rho_sq {
                break;
            }
            if h < 0.0 {
                low = q;
            } else {
                high = q;
            }
            let newton = q - h / slope;
            q = if newton > low && newton < high {
                newton
            } else {
                0.5 * (low + high)
            };
        }
        q
    }
}

/// `P_c` of a trained flow (see the module docs).
#[derive(Clone, Debug)]
pub struct RadialContractions {
    config: ContractionConfig,
    profiles: Vec<Profile>,
}

/// The offsets `y − o` each contraction of an [`apply_recorded`](RadialContractions::
/// apply_recorded) pass met, in order: what `∂P/∂y` needs.
#[derive(Clone, Debug, Default)]
pub struct ContractionTape {
    offsets: Vec<f64>,
}

impl RadialContractions {
    pub fn from_weights(config: &ContractionConfig, weights: &mut Weights) -> FlowResult<Self> {
        let profiles = (0..config.layers)
            .map(|l| {
                let [strength, width] = ContractionConfig::parameter_names(l);
                let strength = weights.take(&strength, &[1])?[0];
                let width = config.radius * weights.take(&width, &[1])?[0].exp();
                Ok(Profile {
                    alpha: 1.0 / (1.0 + (-strength).exp()),
                    inverse_width_sq: 1.0 / (width * width),
                    exponent: config.exponent,
                })
            })
            .collect::<FlowResult<Vec<_>>>()?;
        if profiles
            .iter()
            .any(|p| !(p.alpha < 1.0 && p.inverse_width_sq.is_finite()))
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

    /// The contractions in order of application, each with its centre from `centres`
    /// (the points back to back).
    fn applications<'a>(
        &'a self,
        centres: &'a [f64],
    ) -> impl DoubleEndedIterator<Item = (&'a Profile, &'a [f64])> + 'a {
        let d = self.config.centres.size;
        self.profiles
            .iter()
            .flat_map(move |p| centres.chunks_exact(d).map(move |o| (p, o)))
    }

    /// `y ← P(y)`; returns `log|det ∂P/∂y|`.
    pub fn apply<S: Scalar>(&self, centres: &[f64], y: &mut [S]) -> S {
        let mut log_det = S::constant(0.0);
        for (profile, centre) in self.applications(centres) {
            log_det += contract(profile, centre, y);
        }
        log_det
    }

    /// `y ← P(y)`, recording the offsets into `tape`.
    pub fn apply_recorded(&self, centres: &[f64], y: &mut [f64], tape: &mut ContractionTape) {
        tape.offsets.clear();
        for (profile, centre) in self.applications(centres) {
            tape.offsets
                .extend(y.iter().zip(centre).map(|(yi, o)| yi - o));
            contract(profile, centre, y);
        }
    }

    /// `u ← P⁻¹(u)`; returns `log|det ∂P⁻¹/∂u|`.
    pub fn invert<S: Scalar>(&self, centres: &[f64], u: &mut [S]) -> S {
        let mut log_det = S::constant(0.0);
        let d = u.len() as f64;
        for (profile, centre) in self.applications(centres).rev() {
            let rho_sq = distance_sq(u, centre);
            let mut q = S::constant(profile.solve(rho_sq.value()));
            for _ in 0..2 {
                let (h, slope) = profile.residual(q, rho_sq);
                q = q - h / slope;
            }
            let Slopes { scale, radial, .. } = profile.slopes(q);
            for (ui, &o) in u.iter_mut().zip(centre) {
                *ui = (*ui + (-o)) / scale + o;
            }
            log_det = log_det - radial.ln() - scale.ln() * (d - 1.0);
        }
        log_det
    }

    /// `du ← (∂P/∂y)⁻¹ du` at the recorded `y`: through each contraction in reverse
    /// order, `(s I + β v vᵀ)⁻¹ = (I − β v vᵀ / k') / s` with `v = y − o`, `β = 2 s'(q)`.
    pub fn tangent(&self, tape: &ContractionTape, du: &mut [f64]) {
        let d = du.len();
        for (a, v) in tape.offsets.chunks_exact(d).enumerate().rev() {
            let profile = &self.profiles[a / self.config.centres.count];
            let q: f64 = v.iter().map(|x| x * x).sum();
            let slopes = profile.slopes(q);
            let v_dot_du: f64 = v.iter().zip(&*du).map(|(a, b)| a * b).sum();
            let along = 2.0 * slopes.scale_derivative * v_dot_du / slopes.radial;
            for (x, vi) in du.iter_mut().zip(v) {
                *x = (*x - along * vi) / slopes.scale;
            }
        }
    }
}

/// `‖x − o‖²`.
fn distance_sq<S: Scalar>(x: &[S], centre: &[f64]) -> S {
    x.iter()
        .zip(centre)
        .fold(S::constant(0.0), |acc, (&xi, &o)| {
            let v = xi + (-o);
            acc + v * v
        })
}

/// One contraction about `centre`, in place; returns `log|det ∂P/∂y|`.
fn contract<S: Scalar>(profile: &Profile, centre: &[f64], y: &mut [S]) -> S {
    let q = distance_sq(y, centre);
    let Slopes { scale, radial, .. } = profile.slopes(q);
    for (yi, &o) in y.iter_mut().zip(centre) {
        *yi = (*yi + (-o)) * scale + o;
    }
    radial.ln() + scale.ln() * (y.len() as f64 - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::scalar::Dual;

    /// Two layers about two centres in the plane; the first strongly contracting.
    fn contractions() -> (RadialContractions, Vec<f64>) {
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
            let [s, w] = ContractionConfig::parameter_names(l);
            weights.insert(
                s,
                crate::flow::Tensor {
                    shape: vec![1],
                    data: vec![strength],
                },
            );
            weights.insert(
                w,
                crate::flow::Tensor {
                    shape: vec![1],
                    data: vec![width],
                },
            );
        }
        let contractions = RadialContractions::from_weights(&config, &mut weights).unwrap();
        weights.finish().unwrap();
        (contractions, vec![0.1, -0.2, 0.45, 0.1])
    }

    /// Points near, on and far from the centres.
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
    fn the_strong_layer_contracts_the_disc_about_its_centre() {
        let (p, centres) = contractions();
        let alpha = p.profiles[0].alpha;
        assert!(alpha > 0.99, "{alpha}");
        let profile = p.profiles[0];
        let distance = |r: f64| r * profile.slopes(r * r).scale;
        // Within the width the layer shrinks distances to the centre many times.
        assert!(distance(0.1) < 0.1 * 0.1, "{}", distance(0.1));
        // Far away it is nearly the identity.
        assert!((distance(2.0) - 2.0).abs() < 1e-3);
        // A contraction fixes its own centre.
        let mut centre = [centres[0], centres[1]];
        contract(&profile, &centres[..2], &mut centre);
        assert_eq!(centre, [centres[0], centres[1]]);
    }

    #[test]
    fn invert_undoes_apply() {
        let (p, centres) = contractions();
        for y in points() {
            let mut back = apply(&p, &centres, y);
            let log_det_inverse = p.invert(&centres, &mut back);
            let mut u = y;
            let log_det = p.apply(&centres, &mut u);
            assert!(
                (back[0] - y[0]).abs() < 1e-12 && (back[1] - y[1]).abs() < 1e-12,
                "{y:?} -> {back:?}"
            );
            assert!(
                (log_det + log_det_inverse).abs() < 1e-9,
                "{log_det} {log_det_inverse}"
            );
        }
    }

    #[test]
    fn log_determinant_and_inverse_tangent_match_finite_differences() {
        let (p, centres) = contractions();
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
            assert!(
                (dy[0] - expected[0]).abs() < 1e-5 * scale,
                "{dy:?} {expected:?}"
            );
            assert!(
                (dy[1] - expected[1]).abs() < 1e-5 * scale,
                "{dy:?} {expected:?}"
            );

            // The inverse in dual numbers carries the same derivative.
            let mut dual = [Dual::new(u[0], du[0]), Dual::new(u[1], du[1])];
            p.invert(&centres, &mut dual);
            assert!((dual[0].du - dy[0]).abs() < 1e-9 * scale);
            assert!((dual[1].du - dy[1]).abs() < 1e-9 * scale);
        }
    }

    #[test]
    fn a_strength_that_rounds_to_one_is_refused() {
        let (p, _) = contractions();
        let mut weights = Weights::default();
        for l in 0..2 {
            let [s, w] = ContractionConfig::parameter_names(l);
            weights.insert(
                s,
                crate::flow::Tensor {
                    shape: vec![1],
                    data: vec![40.0],
                },
            );
            weights.insert(
                w,
                crate::flow::Tensor {
                    shape: vec![1],
                    data: vec![0.0],
                },
            );
        }
        assert!(RadialContractions::from_weights(p.config(), &mut weights).is_err());
    }
}
