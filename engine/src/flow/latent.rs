//! Latent stochastic dynamics whose noise-free part is globally asymptotically stable in
//! discrete time for every parameter value.
//!
//! **Linear attractor** (go-to, and the non-cycle dimensions of a limit cycle):
//! `A = -(F Fᵀ + ε I) + (W_l - W_lᵀ)` with `W_l` the strictly lower part of `W`. The
//! symmetric part of `A` is `≤ -ε I`, so `‖exp(A t)‖₂ ≤ e^{-ε t}`: the exact step
//! `z_{k+1} = Φ z_k`, `Φ = exp(A dt)`, is a contraction in the Euclidean norm — unlike an
//! Euler step `I + A dt`, which a Hurwitz `A` does not keep stable.
//!
//! **Limit cycle** in `(z₀, z₁)` with polar coordinates `(ρ, ψ)`: the exact flow of
//! `ρ̇ = α (ρ - ρ*)`, `ψ̇ = ω` over `dt`,
//! `ρ_{k+1} = ρ* + (ρ_k - ρ*) e^{α dt}`, `ψ_{k+1} = ψ_k + ω dt`, with `α = -e^{a} < 0` and
//! `ρ* = e^{r} > 0`. Every start (the origin included: it is mapped to `ρ = ρ*(1 - e^{α dt})`)
//! converges to the circle `ρ = ρ*`.
//!
//! **Saturated go-to**: the origin approached at nearly constant speed, then
//! exponentially, while turning about it: `ż = -g(ρ) z + Ω z`, `ρ = ‖z‖`, `Ω = W_l - W_lᵀ`,
//! with the radius following `ρ̇ = -v cosh(u/κ) tanh(u)`, `u = κ asinh(ερ/v)`,
//! `κ = λ/ε`, `v = e^{b}`, `λ = ε + e^{a}`. Three regimes: near the origin (`u ≪ 1`)
//! `ρ̇ ≈ -λρ`; in between (`u ≫ 1`, `ερ ≪ v`) `ρ̇ ≈ -v`, the constant pace of a drawn stroke
//! (ImitationFlow's tanh dynamics, made isotropic); far out (`ερ ≫ v`) `ρ̇ ≈ -ερ`. Since
//! `tanh(u) ≥ tanh(u/κ)` for `κ ≥ 1`, `ρ̇ ≤ -v sinh(u/κ) = -ερ` everywhere: the same
//! guaranteed exponential rate `ε` as the linear attractor, so a start far outside the
//! data returns in a time logarithmic in its distance. (Without the `asinh` the far speed
//! would stay `v`, and that time would be linear.) The skew `Ω` turns the approach about
//! the origin without changing `ρ`, so strokes that wind around their end need no twist of
//! the network. The radial part commutes with the rotation, so the exact flow over `t` is
//! `z(t) = (ρ(t)/ρ) e^{Ω t} z` with `sinh(u(t)) = sinh(u) e^{-λt}` ([`settle`]).
//!
//! **Noise** is Gaussian in Cartesian latent coordinates around the mean next state,
//! `z_{k+1} ~ N(μ(z_k), diag σ²)`, so `p(z_{k+1} | z_k)` is an exact density. The
//! `k`-step density is `N(μ^k(z), Σ_k)` with `μ^k` the exact noise-free `k`-step map and,
//! on the linear part, the exact `Σ_k = Σ_{j<k} Φ^j Σ Φ^{jᵀ}`; on the cycle plane and for
//! the saturated go-to `Σ_k = k σ²` (random-walk accumulation — a model choice, since the
//! `k`-fold composition of a nonlinear step has no closed-form density). The initial state has `z₀ ~ N(0, diag σ₀²)`.

use nalgebra::{Cholesky, DMatrix, DVector};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::flow::checkpoint::config::{FlowConfig, LatentKind};
use crate::flow::checkpoint::names::{
    self, FACTOR, LATENT, LOG_RADIUS, LOG_RATE, LOG_SIGMA, LOG_SIGMA0, LOG_SPEED, OMEGA, SKEW,
};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::{FlowError, FlowResult};
use crate::math::MatrixExp;
use crate::nn::scalar::Scalar;

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Parameters of the polar limit cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cycle {
    /// `ρ* > 0`.
    pub radius: f64,
    /// `α < 0`.
    pub rate: f64,
    /// `ω` (rad/s).
    pub omega: f64,
}

/// Parameters of the saturated go-to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Saturation {
    /// `λ ≥ ε`, the rate near the origin (1/s).
    pub rate: f64,
    /// `v > 0`, the pace between the near and far regimes (latent units per second).
    pub speed: f64,
    /// `ε > 0`, the rate guaranteed everywhere and reached far out (1/s).
    pub floor: f64,
}

impl Saturation {
    /// `κ = λ/ε ≥ 1`.
    fn ratio(&self) -> f64 {
        self.rate / self.floor
    }

    /// The factor `ρ(t)/ρ` by which the flow over `t` shrinks a latent point at radius `ρ`.
    pub fn shrink(&self, rho: f64, t: f64) -> f64 {
        let (kappa, x) = (self.ratio(), self.floor * rho / self.speed);
        let u = kappa * x.asinh();
        if u < 1e-6 {
            // ρ(t)/ρ = e^{-λt} (1 + O(u²)).
            return (-self.rate * t).exp();
        }
        (settle(u, self.rate * t) / kappa).sinh() / x
    }

    /// `g(ρ) = -ρ̇/ρ = ε √(1 + x²) tanh(κ asinh x) / x` with `x = ερ/v`, so that
    /// `ż = -g(ρ) z` on the radius; on `ρ² = z·z` near the origin, where the square root
    /// has no derivative.
    fn gain<S: Scalar>(&self, rho_squared: S) -> S {
        let kappa = self.ratio();
        let scale = self.floor / self.speed;
        let x_squared = rho_squared * (scale * scale);
        if x_squared.value() * kappa * kappa < 1e-8 {
            // λ (1 + x² (1 - κ²)/3 + O(κ⁴x⁴)): relative error below 1e-16 here.
            return (x_squared * ((1.0 - kappa * kappa) / 3.0) + 1.0) * self.rate;
        }
        let x = x_squared.sqrt();
        let root = (x_squared + 1.0).sqrt();
        let asinh = (x + root).ln();
        (asinh * kappa).tanh() * root * self.floor / x
    }
}

/// `asinh(sinh(u) e^{-τ})` for `u, τ ≥ 0`: where the scaled radius `u = βρ` of the saturated
/// go-to is after a time `τ/λ`. Evaluated in the log domain once `sinh u` would overflow
/// (`u` beyond 20), so starts far outside the data stay finite and exact.
pub fn settle(u: f64, tau: f64) -> f64 {
    const DIRECT: f64 = 20.0;
    if u < DIRECT {
        return (u.sinh() * (-tau).exp()).asinh();
    }
    // ln sinh u = u - ln 2 + ln(1 - e^{-2u}), the last term below 1e-17 here.
    let a = u - std::f64::consts::LN_2 - tau;
    if a < DIRECT {
        a.exp().asinh()
    } else {
        // asinh(e^a) = a + ln 2 + O(e^{-2a}).
        a + std::f64::consts::LN_2
    }
}

/// `e^{A t}` and `e^{Ω t}` of [`LatentDynamics::mean_after`], with their workspaces.
#[derive(Clone, Debug)]
pub struct LatentFlowScratch {
    linear: MatrixExp,
    turning: MatrixExp,
    transition: DMatrix<f64>,
    turn: DMatrix<f64>,
}

#[derive(Clone, Debug)]
pub struct LatentDynamics {
    kind: LatentKind,
    dt: f64,
    /// `A` of the linear part (`r × r`).
    rate_matrix: DMatrix<f64>,
    /// `Φ = exp(A dt)`.
    transition: DMatrix<f64>,
    sigma: Vec<f64>,
    sigma0: Vec<f64>,
    cycle: Option<Cycle>,
    saturation: Option<Saturation>,
    /// The saturated go-to's `Ω` and `e^{Ω dt}` (`d × d`; empty for the other kinds).
    rotation: DMatrix<f64>,
    turn: DMatrix<f64>,
    /// `+1`, or `−1` for the dynamics run backwards in time ([`Self::time_reversed`]).
    direction: f64,
}

/// `A = -(F Fᵀ + ε I) + (W_l - W_lᵀ)`.
pub fn stable_rate_matrix(
    factor: &DMatrix<f64>,
    skew: &DMatrix<f64>,
    min_rate: f64,
) -> DMatrix<f64> {
    let r = factor.nrows();
    let lower = skew.lower_triangle() - DMatrix::from_diagonal(&skew.diagonal());
    -(factor * factor.transpose() + DMatrix::identity(r, r) * min_rate) + &lower - lower.transpose()
}

impl LatentDynamics {
    pub fn from_weights(config: &FlowConfig, weights: &mut Weights) -> FlowResult<Self> {
        let d = config.state_dim;
        let sigma = exp_all(weights.take(&names::name(&[&LATENT, &LOG_SIGMA]), &[d])?);
        let sigma0 = exp_all(weights.take(&names::name(&[&LATENT, &LOG_SIGMA0]), &[d])?);
        let r = config.linear_latent_dim();
        let rate_matrix = if r > 0 {
            let factor = DMatrix::from_row_slice(
                r,
                r,
                &weights.take(&names::name(&[&LATENT, &FACTOR]), &[r, r])?,
            );
            let skew = DMatrix::from_row_slice(
                r,
                r,
                &weights.take(&names::name(&[&LATENT, &SKEW]), &[r, r])?,
            );
            stable_rate_matrix(&factor, &skew, config.min_rate)
        } else {
            DMatrix::zeros(0, 0)
        };
        let rotation = match config.latent {
            LatentKind::SaturatedGoTo => {
                let skew = DMatrix::from_row_slice(
                    d,
                    d,
                    &weights.take(&names::name(&[&LATENT, &SKEW]), &[d, d])?,
                );
                let lower = skew.lower_triangle() - DMatrix::from_diagonal(&skew.diagonal());
                &lower - lower.transpose()
            }
            _ => DMatrix::zeros(0, 0),
        };
        // The one-step matrices, made once per model with nalgebra's `exp`: every recorded
        // rollout was computed with them. `MatrixExp` (`mean_after`) agrees to about 1e-14
        // and exists for the steps a control loop takes without allocating.
        let turn = match rotation.is_empty() {
            true => DMatrix::zeros(0, 0),
            false => (&rotation * config.dt).exp(),
        };
        let mut scalar = |name: &str| {
            weights
                .take(&names::name(&[&LATENT, &name]), &[1])
                .map(|v| v[0])
        };
        let (mut cycle, mut saturation) = (None, None);
        match config.latent {
            LatentKind::GoTo => {}
            LatentKind::SaturatedGoTo => {
                saturation = Some(Saturation {
                    rate: config.min_rate + scalar(LOG_RATE)?.exp(),
                    speed: scalar(LOG_SPEED)?.exp(),
                    floor: config.min_rate,
                });
            }
            LatentKind::LimitCycle => {
                cycle = Some(Cycle {
                    radius: scalar(LOG_RADIUS)?.exp(),
                    rate: -scalar(LOG_RATE)?.exp(),
                    omega: scalar(OMEGA)?,
                });
            }
        }
        if let Some(saturation) = saturation
            && !(saturation.rate.is_finite()
                && saturation.speed.is_finite()
                && saturation.speed > 0.0)
        {
            return Err(FlowError::NonFinite {
                what: "latent rate and speed",
            });
        }
        let transition = if r > 0 {
            (&rate_matrix * config.dt).exp()
        } else {
            DMatrix::zeros(0, 0)
        };
        if transition.iter().chain(turn.iter()).any(|v| !v.is_finite()) {
            return Err(FlowError::NonFinite {
                what: "latent transition matrix",
            });
        }
        Ok(Self {
            kind: config.latent,
            dt: config.dt,
            rate_matrix,
            transition,
            sigma,
            sigma0,
            cycle,
            saturation,
            rotation,
            turn,
            direction: 1.0,
        })
    }

    /// The same dynamics run backwards in time, `t → −t`: the attractor repels and every
    /// mode that converged diverges (the linear part's eigenvalues flip sign, the cycle
    /// and the saturated radius are left at the rates they were approached; inside the
    /// cycle the radius shrinks to the origin, where the field is singular). A flow with
    /// this latent is a trained model of the same class with its stability removed: the
    /// stability check's negative control. Nothing trains or saves it.
    pub fn time_reversed(&self) -> Self {
        let exp = |generator: &DMatrix<f64>| match generator.is_empty() {
            true => DMatrix::zeros(0, 0),
            false => (generator * -self.dt).exp(),
        };
        Self {
            transition: exp(&self.rate_matrix),
            turn: exp(&self.rotation),
            direction: -self.direction,
            ..self.clone()
        }
    }

    pub fn kind(&self) -> LatentKind {
        self.kind
    }

    pub fn cycle(&self) -> Option<Cycle> {
        self.cycle
    }

    pub fn saturation(&self) -> Option<Saturation> {
        self.saturation
    }

    /// `Φ = exp(A dt)` of the linear part.
    pub fn transition_matrix(&self) -> &DMatrix<f64> {
        &self.transition
    }

    /// `A` of the linear part.
    pub fn rate_matrix(&self) -> &DMatrix<f64> {
        &self.rate_matrix
    }

    /// Noise standard deviations `σ`.
    pub fn sigma(&self) -> &[f64] {
        &self.sigma
    }

    /// First latent dimension of the linear part.
    fn linear_start(&self) -> usize {
        if self.cycle.is_some() { 2 } else { 0 }
    }

    /// Noise-free step `out = μ(z)`, with the matrices precomputed for `dt`.
    pub fn mean_step(&self, z: &[f64], out: &mut [f64]) {
        self.flow(
            z,
            self.direction * self.dt,
            &self.transition,
            &self.turn,
            out,
        );
    }

    /// The exact noise-free `k`-step map `out = μ^k(z)`. Allocates its
    /// [`flow_scratch`](Self::flow_scratch) past one step.
    pub fn mean_steps(&self, z: &[f64], steps: usize, out: &mut [f64]) {
        match steps {
            1 => self.mean_step(z, out),
            _ => self.mean_after(z, steps as f64 * self.dt, &mut self.flow_scratch(), out),
        }
    }

    /// Buffers of [`mean_after`](Self::mean_after) for these dynamics.
    pub fn flow_scratch(&self) -> LatentFlowScratch {
        let (r, d) = (self.rate_matrix.nrows(), self.rotation.nrows());
        LatentFlowScratch {
            linear: MatrixExp::new(r),
            turning: MatrixExp::new(d),
            transition: DMatrix::zeros(r, r),
            turn: DMatrix::zeros(d, d),
        }
    }

    /// The exact noise-free flow over `seconds` (any duration, not only whole steps):
    /// `μ^k = ` this at `k dt`. Takes its matrix exponentials in `scratch`
    /// ([`flow_scratch`](Self::flow_scratch)), without allocating: a policy under an
    /// end-stop hold steps its latent state this way every control period.
    pub fn mean_after(
        &self,
        z: &[f64],
        seconds: f64,
        scratch: &mut LatentFlowScratch,
        out: &mut [f64],
    ) {
        let seconds = self.direction * seconds;
        let LatentFlowScratch {
            linear,
            turning,
            transition,
            turn,
        } = scratch;
        linear.exp_into(&self.rate_matrix, seconds, transition);
        turning.exp_into(&self.rotation, seconds, turn);
        self.flow(z, seconds, transition, turn, out);
    }

    /// The flow over `t`, given `exp(A t)` and `exp(Ω t)`.
    fn flow(
        &self,
        z: &[f64],
        t: f64,
        transition: &DMatrix<f64>,
        turn: &DMatrix<f64>,
        out: &mut [f64],
    ) {
        if let Some(saturation) = self.saturation {
            let rho = z.iter().map(|v| v * v).sum::<f64>().sqrt();
            let shrink = saturation.shrink(rho, t);
            for (i, o) in out.iter_mut().enumerate() {
                *o = shrink * (0..z.len()).map(|j| turn[(i, j)] * z[j]).sum::<f64>();
            }
            return;
        }
        let s = self.linear_start();
        if let Some(cycle) = self.cycle {
            let (rho, psi) = (z[0].hypot(z[1]), z[1].atan2(z[0]));
            let rho_next = cycle.radius + (rho - cycle.radius) * (cycle.rate * t).exp();
            let psi_next = psi + cycle.omega * t;
            out[0] = rho_next * psi_next.cos();
            out[1] = rho_next * psi_next.sin();
        }
        let r = transition.nrows();
        for i in 0..r {
            out[s + i] = (0..r).map(|j| transition[(i, j)] * z[s + j]).sum();
        }
    }

    /// Sample `z_{k+1} ~ N(μ(z_k), diag σ²)`.
    pub fn sample_step(&self, z: &[f64], rng: &mut impl Rng, out: &mut [f64]) {
        self.mean_step(z, out);
        for (o, s) in out.iter_mut().zip(&self.sigma) {
            *o += s * Distribution::<f64>::sample(&StandardNormal, rng);
        }
    }

    /// The continuous-time field `ż = v(z)` whose time-`dt` flow is [`mean_step`](Self::mean_step).
    pub fn velocity<S: Scalar>(&self, z: &[S], out: &mut [S]) {
        if let Some(saturation) = self.saturation {
            let rho_squared = z.iter().fold(S::constant(0.0), |acc, &v| acc + v * v);
            let gain = saturation.gain(rho_squared);
            for (i, o) in out.iter_mut().enumerate() {
                let mut turning = S::constant(0.0);
                for (j, &v) in z.iter().enumerate() {
                    turning += v * self.rotation[(i, j)];
                }
                *o = (turning - z[i] * gain) * self.direction;
            }
            return;
        }
        let s = self.linear_start();
        if let Some(cycle) = self.cycle {
            let rho = (z[0] * z[0] + z[1] * z[1]).sqrt();
            let psi = z[1].atan2(z[0]);
            let rho_dot = (rho + (-cycle.radius)) * cycle.rate;
            out[0] = (rho_dot * psi.cos() - z[1] * cycle.omega) * self.direction;
            out[1] = (rho_dot * psi.sin() + z[0] * cycle.omega) * self.direction;
        }
        let r = self.rate_matrix.nrows();
        for i in 0..r {
            let mut acc = S::constant(0.0);
            for j in 0..r {
                acc += z[s + j] * self.rate_matrix[(i, j)];
            }
            out[s + i] = acc * self.direction;
        }
    }

    /// The point of the attractor `z` is heading to: the origin, or on the cycle
    /// `(ρ* cos ψ, ρ* sin ψ, 0, …)`.
    pub fn project_onto_attractor(&self, z: &[f64], out: &mut [f64]) {
        out.fill(0.0);
        if let Some(cycle) = self.cycle {
            let psi = z[1].atan2(z[0]);
            out[0] = cycle.radius * psi.cos();
            out[1] = cycle.radius * psi.sin();
        }
    }

    /// `log N(z_next; μ(z), diag σ²)`, allocation-free.
    pub fn log_transition(&self, z: &[f64], z_next: &[f64], mean: &mut [f64]) -> f64 {
        self.mean_step(z, mean);
        diagonal_gaussian_log_density(z_next, mean, &self.sigma)
    }

    /// `log N(z_k; μ^k(z), Σ_k)` of the `horizon`-step transition (see the module docs).
    pub fn log_transition_multi(
        &self,
        z: &[f64],
        z_next: &[f64],
        horizon: usize,
    ) -> FlowResult<f64> {
        if horizon == 0 {
            return Err(FlowError::InvalidConfig(
                "transition horizon must be >= 1".into(),
            ));
        }
        let d = z.len();
        let mut mean = vec![0.0; d];
        self.mean_steps(z, horizon, &mut mean);
        let covariance = self.multi_step_covariance(horizon);
        let cholesky = Cholesky::new(covariance).ok_or_else(|| {
            FlowError::InvalidConfig("k-step covariance is not positive definite".into())
        })?;
        let residual = DVector::from_iterator(d, z_next.iter().zip(&mean).map(|(a, b)| a - b));
        let whitened = cholesky
            .l()
            .solve_lower_triangular(&residual)
            .expect("positive diagonal");
        let log_det: f64 = cholesky.l().diagonal().iter().map(|v| v.ln()).sum::<f64>() * 2.0;
        Ok(-0.5 * (whitened.norm_squared() + log_det + d as f64 * LN_2PI))
    }

    /// `Σ_k`: exact on the linear part, `k σ²` on the cycle plane and for the saturated
    /// go-to.
    pub fn multi_step_covariance(&self, horizon: usize) -> DMatrix<f64> {
        let d = self.sigma.len();
        let s = match self.saturation {
            Some(_) => d,
            None => self.linear_start(),
        };
        let mut covariance = DMatrix::zeros(d, d);
        for i in 0..s {
            covariance[(i, i)] = horizon as f64 * self.sigma[i] * self.sigma[i];
        }
        let r = d - s;
        let noise = DMatrix::from_diagonal(&DVector::from_iterator(
            r,
            self.sigma[s..].iter().map(|v| v * v),
        ));
        let mut power = DMatrix::identity(r, r);
        let mut linear = DMatrix::zeros(r, r);
        for _ in 0..horizon {
            linear += &power * &noise * power.transpose();
            power = &self.transition * power;
        }
        covariance.view_mut((s, s), (r, r)).copy_from(&linear);
        covariance
    }

    /// `log N(z₀; 0, diag σ₀²)`.
    pub fn log_initial(&self, z0: &[f64]) -> f64 {
        z0.iter()
            .zip(&self.sigma0)
            .map(|(z, s)| gaussian_log_density(*z, 0.0, *s))
            .sum()
    }
}

/// `log N(x; μ, diag σ²)`.
pub fn diagonal_gaussian_log_density(x: &[f64], mean: &[f64], sigma: &[f64]) -> f64 {
    x.iter()
        .zip(mean)
        .zip(sigma)
        .map(|((x, m), s)| gaussian_log_density(*x, *m, *s))
        .sum()
}

fn gaussian_log_density(x: f64, mean: f64, sigma: f64) -> f64 {
    -0.5 * (((x - mean) / sigma).powi(2) + LN_2PI) - sigma.ln()
}

fn exp_all(values: Vec<f64>) -> Vec<f64> {
    values.into_iter().map(f64::exp).collect()
}
