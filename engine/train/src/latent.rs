//! The latent dynamics of `ciflow_engine::flow::latent` in tch (same parameters, same
//! equations): exact linear step `exp(A dt)`, exact polar radius step, Gaussian noise in
//! Cartesian latent coordinates.

use ciflow_engine::flow::{FlowConfig, LatentKind};
use tch::nn;
use tch::{Kind, Tensor};

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Data-driven starting values of the latent parameters.
#[derive(Clone, Copy, Debug)]
pub struct LatentInit {
    /// Initial noise standard deviation `σ` (normalised units).
    pub sigma: f64,
    /// Initial angular velocity `ω` of a limit cycle (rad/s).
    pub omega: f64,
}

#[derive(Debug)]
struct Cycle {
    log_radius: Tensor,
    log_rate: Tensor,
    omega: Tensor,
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
                path.var("factor", &[r, r], small),
                path.var("skew", &[r, r], small),
            )
        });
        let cycle = (config.latent == LatentKind::LimitCycle).then(|| Cycle {
            log_radius: path.var("log_radius", &[1], nn::Init::Const(0.0)),
            log_rate: path.var("log_rate", &[1], nn::Init::Const(0.0)),
            omega: path.var("omega", &[1], nn::Init::Const(init.omega)),
        });
        Self {
            dt: config.dt,
            min_rate: config.min_rate,
            log_sigma: path.var("log_sigma", &[d], nn::Init::Const(init.sigma.ln())),
            log_sigma0: path.var("log_sigma0", &[d], nn::Init::Const(0.0)),
            linear,
            cycle,
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

    /// `Φ = exp(A dt)`.
    pub fn transition(&self) -> Option<Tensor> {
        self.rate_matrix().map(|a| (a * self.dt).matrix_exp())
    }

    /// Noise-free step `μ(z)` of a batch `[B, d]`.
    pub fn mean_step(&self, z: &Tensor) -> Tensor {
        let s = self.linear_start();
        let mut parts = Vec::new();
        if let Some(cycle) = &self.cycle {
            let (z0, z1) = (z.select(1, 0), z.select(1, 1));
            let rho = (&z0 * &z0 + &z1 * &z1).sqrt();
            let psi = z1.atan2(&z0);
            let radius = cycle.log_radius.exp();
            let contraction = (-cycle.log_rate.exp() * self.dt).exp();
            let rho_next = &radius + (rho - &radius) * contraction;
            let psi_next = psi + &cycle.omega * self.dt;
            parts.push(Tensor::stack(
                &[&rho_next * psi_next.cos(), rho_next * psi_next.sin()],
                1,
            ));
        }
        if let Some(phi) = self.transition() {
            let r = phi.size()[0];
            parts.push(z.narrow(1, s, r).matmul(&phi.tr()));
        }
        Tensor::cat(&parts, 1)
    }

    /// `log p(z_next | z)` of the `horizon`-step model, per row.
    pub fn log_transition(&self, z: &Tensor, z_next: &Tensor, horizon: usize) -> Tensor {
        let mut mean = z.shallow_clone();
        for _ in 0..horizon {
            mean = self.mean_step(&mean);
        }
        let residual = z_next - mean;
        if horizon == 1 {
            return diagonal_gaussian(&residual, &self.log_sigma);
        }
        let s = self.linear_start();
        let variance = (&self.log_sigma * 2.0).exp();
        let mut log_p = Tensor::zeros([z.size()[0]], (Kind::Double, z.device()));
        if s > 0 {
            let plane = variance.narrow(0, 0, s) * horizon as f64;
            log_p += diagonal_gaussian(&residual.narrow(1, 0, s), &(plane.log() * 0.5));
        }
        if let Some(phi) = self.transition() {
            let r = phi.size()[0];
            let noise = variance.narrow(0, s, r).diag_embed(0, -2, -1);
            let mut power = Tensor::eye(r, (Kind::Double, phi.device()));
            let mut covariance = Tensor::zeros([r, r], (Kind::Double, phi.device()));
            for _ in 0..horizon {
                covariance += power.matmul(&noise).matmul(&power.tr());
                power = phi.matmul(&power);
            }
            let cholesky = covariance.linalg_cholesky(false);
            let x = residual.narrow(1, s, r);
            let whitened = cholesky.linalg_solve_triangular(&x.tr(), false, true, false);
            let quad = whitened.square().sum_dim_intlist(0, false, Kind::Double);
            let log_det = cholesky.diagonal(0, 0, 1).log().sum(Kind::Double) * 2.0;
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
