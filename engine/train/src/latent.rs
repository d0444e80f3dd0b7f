//! The latent dynamics of `ciflow_engine::flow::latent` in tch (same parameters, same
//! equations): exact linear step `exp(A dt)`, exact polar radius step, exact saturated
//! radial step, Gaussian noise in Cartesian latent coordinates.

use ciflow_engine::flow::checkpoint::names::{
    FACTOR, LOG_RADIUS, LOG_RATE, LOG_SIGMA, LOG_SIGMA0, LOG_SPEED, OMEGA, SKEW,
};
use ciflow_engine::flow::{FlowConfig, LatentKind};
use tch::nn;
use tch::{Kind, Tensor};

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Data-driven starting values of the latent parameters.
#[derive(Clone, Copy, Debug)]
pub struct LatentInit {
    /// Initial noise standard deviation `σ` (normalised units).
    pub sigma: f64,
    /// Initial angular velocity `ω` of a limit cycle, or turning rate of a saturated go-to
    /// (rad/s).
    pub omega: f64,
    /// Initial far speed `v` of a saturated go-to (normalised units per second).
    pub speed: f64,
}

/// Initial `λ - ε` of a saturated go-to (1/s): a settling time of a fraction of a second,
/// which the likelihood then sets from the demonstrations' final approach.
const INITIAL_SATURATED_RATE: f64 = 5.0;

#[derive(Debug)]
struct Cycle {
    log_radius: Tensor,
    log_rate: Tensor,
    omega: Tensor,
}

#[derive(Debug)]
struct Saturation {
    log_rate: Tensor,
    log_speed: Tensor,
    /// `W` of the rotation generator `Ω = W_l - W_lᵀ`.
    skew: Tensor,
}

#[derive(Debug)]
pub struct LatentModel {
    dt: f64,
    min_rate: f64,
    log_sigma: Tensor,
    log_sigma0: Tensor,
    /// `(F, W)` of `A = -(F Fᵀ + ε I) + (W_l - W_lᵀ)`, absent when the linear part is empty.
    linear: Option<(Tensor, Tensor)>,
    cycle: Option<Cycle>,
    saturation: Option<Saturation>,
}

impl LatentModel {
    pub fn new(path: &nn::Path, config: &FlowConfig, init: LatentInit) -> Self {
        let d = config.state_dim as i64;
        let r = config.linear_latent_dim() as i64;
        let linear = (r > 0).then(|| {
            let small = nn::Init::Randn {
                mean: 0.0,
                stdev: 0.1,
            };
            (
                path.var(FACTOR, &[r, r], small),
                path.var(SKEW, &[r, r], small),
            )
        });
        let saturation = (config.latent == LatentKind::SaturatedGoTo).then(|| Saturation {
            log_rate: path.var(LOG_RATE, &[1], nn::Init::Const(INITIAL_SATURATED_RATE.ln())),
            log_speed: path.var(LOG_SPEED, &[1], nn::Init::Const(init.speed.ln())),
            skew: {
                // Turning at `ω` in the first latent plane: `Ω₁₀ = W₁₀ = ω`.
                let skew = path.var(SKEW, &[d, d], nn::Init::Const(0.0));
                tch::no_grad(|| {
                    let _ = skew.get(1).get(0).fill_(init.omega);
                });
                skew
            },
        });
        let cycle = (config.latent == LatentKind::LimitCycle).then(|| Cycle {
            log_radius: path.var(LOG_RADIUS, &[1], nn::Init::Const(0.0)),
            log_rate: path.var(LOG_RATE, &[1], nn::Init::Const(0.0)),
            omega: path.var(OMEGA, &[1], nn::Init::Const(init.omega)),
        });
        Self {
            dt: config.dt,
            min_rate: config.min_rate,
            log_sigma: path.var(LOG_SIGMA, &[d], nn::Init::Const(init.sigma.ln())),
            log_sigma0: path.var(LOG_SIGMA0, &[d], nn::Init::Const(0.0)),
            linear,
            cycle,
            saturation,
        }
    }

    fn linear_start(&self) -> i64 {
        if self.cycle.is_some() { 2 } else { 0 }
    }

    /// `A`.
    pub fn rate_matrix(&self) -> Option<Tensor> {
        self.linear.as_ref().map(|(factor, skew)| {
            let r = factor.size()[0];
            let eye = Tensor::eye(r, (Kind::Double, factor.device()));
            let lower = skew.tril(-1);
            -(factor.matmul(&factor.tr()) + eye * self.min_rate) + &lower - lower.tr()
        })
    }

    /// `ρ(t)/ρ` of the saturated go-to per row, `t` per row (`[B]`)
    /// (`ciflow_engine::flow::latent::Saturation::shrink`, branch for branch).
    fn shrink(&self, saturation: &Saturation, rho: &Tensor, t: &Tensor) -> Tensor {
        const DIRECT: f64 = 20.0;
        const LN_2: f64 = std::f64::consts::LN_2;
        let rate = saturation.log_rate.exp() + self.min_rate;
        let kappa = &rate / self.min_rate;
        let x = rho * (self.min_rate / saturation.log_speed.exp());
        let u = x.asinh() * &kappa;
        let tau = t * &rate;
        // Every branch is evaluated; clamps keep the unused ones (and their gradients) finite.
        let direct = (u.clamp_max(DIRECT).sinh() * (-&tau).exp()).asinh();
        let a = &u - LN_2 - &tau;
        let far = a
            .clamp_max(DIRECT)
            .exp()
            .asinh()
            .where_self(&a.lt(DIRECT), &(&a + LN_2));
        let settled = direct.where_self(&u.lt(DIRECT), &far);
        let small = u.lt(1e-6);
        let safe_x = x.where_self(&small.logical_not(), &x.ones_like());
        ((settled / kappa).sinh() / safe_x).where_self(&small.logical_not(), &(-tau).exp())
    }

    /// `exp(G j dt)` for `j = 1..=max_steps` (`[K, n, n]`), in one batched exponential.
    fn powers(&self, generator: &Tensor, max_steps: usize) -> Tensor {
        let j = Tensor::arange_start(1, max_steps as i64 + 1, (Kind::Double, generator.device()));
        (j.reshape([-1, 1, 1]) * (generator * self.dt).unsqueeze(0)).linalg_matrix_exp()
    }

    /// The saturated go-to's flow over `k = steps[i]` steps per row:
    /// `(ρ(k dt)/ρ) e^{Ω k dt} z`, one exponential per row (spans may reach a whole
    /// demonstration, so a table of every power up to the longest would cost more).
    fn saturated_flow(&self, saturation: &Saturation, z: &Tensor, steps: &Tensor) -> Tensor {
        let lower = saturation.skew.tril(-1);
        let seconds = steps.to_kind(Kind::Double) * self.dt;
        let turns =
            (seconds.reshape([-1, 1, 1]) * (&lower - lower.tr()).unsqueeze(0)).linalg_matrix_exp();
        let turned = turns.matmul(&z.unsqueeze(2)).squeeze_dim(2);
        let rho = z.square().sum_dim_intlist(1, false, Kind::Double).sqrt();
        turned * self.shrink(saturation, &rho, &seconds).unsqueeze(1)
    }

    /// Noise-free step `μ(z)` of a batch `[B, d]`.
    pub fn mean_step(&self, z: &Tensor) -> Tensor {
        let one = Tensor::ones([z.size()[0]], tch::kind::INT64_CPU);
        self.mean_steps(z, &one, 1)
    }

    /// The exact noise-free flow `μ^k(z)` over `k = steps[i]` steps per row
    /// (`1 ≤ steps[i] ≤ max_steps`).
    fn mean_steps(&self, z: &Tensor, steps: &Tensor, max_steps: usize) -> Tensor {
        if let Some(saturation) = &self.saturation {
            return self.saturated_flow(saturation, z, steps);
        }
        let s = self.linear_start();
        let mut parts = Vec::new();
        if let Some(cycle) = &self.cycle {
            let seconds = steps.to_kind(Kind::Double) * self.dt;
            let (z0, z1) = (z.select(1, 0), z.select(1, 1));
            let rho = (&z0 * &z0 + &z1 * &z1).sqrt();
            let psi = z1.atan2(&z0);
            let radius = cycle.log_radius.exp();
            let contraction = (-cycle.log_rate.exp() * &seconds).exp();
            let rho_k = &radius + (rho - &radius) * contraction;
            let psi_k = psi + &cycle.omega * &seconds;
            parts.push(Tensor::stack(
                &[&rho_k * psi_k.cos(), rho_k * psi_k.sin()],
                1,
            ));
        }
        if let Some(a) = self.rate_matrix() {
            let r = a.size()[0];
            let phi = self.powers(&a, max_steps).index_select(0, &(steps - 1));
            let linear = z.narrow(1, s, r).unsqueeze(2);
            parts.push(phi.matmul(&linear).squeeze_dim(2));
        }
        Tensor::cat(&parts, 1)
    }

    /// `log p(z_next | z)` per row, row `i` a transition over `k = steps[i]` steps
    /// (`1 ≤ k ≤ max_steps`): `N(μ^k(z), Σ_k)` with the exact noise-free `k`-step map and,
    /// on the linear part, the exact `Σ_k = Σ_{j<k} Φ^j Σ Φ^{jᵀ}`; `k σ²` on the cycle
    /// plane and for the saturated go-to (as `ciflow_engine::flow::latent`).
    pub fn log_transition(
        &self,
        z: &Tensor,
        z_next: &Tensor,
        steps: &Tensor,
        max_steps: usize,
    ) -> Tensor {
        let residual = z_next - self.mean_steps(z, steps, max_steps);
        if max_steps == 1 {
            return diagonal_gaussian(&residual, &self.log_sigma);
        }
        // `k σ²` where the step is nonlinear: log σ_k = log σ + ½ log k.
        let log_sigma_k = |log_sigma: Tensor| {
            let scale = (steps.to_kind(Kind::Double).log() * 0.5).unsqueeze(1);
            log_sigma.unsqueeze(0) + scale
        };
        let s = self.linear_start();
        let nonlinear = match self.saturation {
            Some(_) => z.size()[1],
            None => s,
        };
        let mut log_p = Tensor::zeros([z.size()[0]], (Kind::Double, z.device()));
        if nonlinear > 0 {
            let sigma = log_sigma_k(self.log_sigma.narrow(0, 0, nonlinear));
            log_p += diagonal_gaussian(&residual.narrow(1, 0, nonlinear), &sigma);
        }
        if let Some(a) = self.rate_matrix() {
            let r = a.size()[0];
            // Σ_k = Σ_{j<k} Φ^j Σ Φ^{jᵀ} for k = 1..=K: a cumulative sum over Φ^0..Φ^{K-1}.
            let earlier = Tensor::cat(
                &[
                    Tensor::eye(r, (Kind::Double, a.device())).unsqueeze(0),
                    self.powers(&a, max_steps - 1),
                ],
                0,
            );
            let noise = (&self.log_sigma * 2.0)
                .exp()
                .narrow(0, s, r)
                .reshape([1, 1, r]);
            let covariances = (&earlier * noise)
                .matmul(&earlier.transpose(1, 2))
                .cumsum(0, Kind::Double);
            let cholesky = covariances
                .linalg_cholesky(false)
                .index_select(0, &(steps - 1));
            let x = residual.narrow(1, s, r).unsqueeze(2);
            let whitened = cholesky.linalg_solve_triangular(&x, false, true, false);
            let quad = whitened
                .square()
                .sum_dim_intlist(&[1i64, 2][..], false, Kind::Double);
            let log_det =
                cholesky
                    .diagonal(0, -2, -1)
                    .log()
                    .sum_dim_intlist(1, false, Kind::Double)
                    * 2.0;
            log_p -= (quad + log_det + r as f64 * LN_2PI) * 0.5;
        }
        log_p
    }

    /// `log N(z₀; 0, diag σ₀²)` per row.
    pub fn log_initial(&self, z0: &Tensor) -> Tensor {
        diagonal_gaussian(z0, &self.log_sigma0)
    }
}

/// `log N(x; 0, diag e^{2 log σ})` summed over columns.
fn diagonal_gaussian(x: &Tensor, log_sigma: &Tensor) -> Tensor {
    let whitened = x * (-log_sigma).exp();
    ((whitened.square() + LN_2PI) * -0.5 - log_sigma).sum_dim_intlist(1, false, Kind::Double)
}
