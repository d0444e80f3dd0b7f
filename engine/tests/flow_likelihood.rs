//! With identity couplings the flow is affine, so the model is a linear-Gaussian system
//! whose transition, k-step and initial densities have closed forms.

mod flow_common;

use ciflow_engine::flow::{FlowConfig, LatentKind, Policy, Tensor, Weights};
use flow_common::*;
use nalgebra::{DMatrix, DVector};

/// `log N(x; mean, covariance)` from scratch.
fn gaussian(x: &DVector<f64>, mean: &DVector<f64>, covariance: &DMatrix<f64>) -> f64 {
    let d = x.len() as f64;
    let r = x - mean;
    let quad = (r.transpose() * covariance.clone().try_inverse().unwrap() * &r)[(0, 0)];
    -0.5 * (quad + covariance.determinant().ln() + d * (2.0 * std::f64::consts::PI).ln())
}

fn matrix(weights: &Weights, name: &str, n: usize) -> DMatrix<f64> {
    DMatrix::from_row_slice(n, n, &weights.get(name).unwrap().data)
}

fn vector(weights: &Weights, name: &str) -> DVector<f64> {
    DVector::from_vec(weights.get(name).unwrap().data.clone())
}

/// Random weights with zeroed conditioner outputs: every coupling is the identity.
fn linear_gaussian(config: &FlowConfig, seed: u64) -> Weights {
    let mut weights = random_weights(config, seed);
    let last = config.hidden.len();
    for i in 0..config.layers {
        for part in ["weight", "bias"] {
            let name = format!("layers.{i}.conditioner.{last}.{part}");
            let shape = weights.get(&name).unwrap().shape.clone();
            let n = shape.iter().product();
            weights.insert(
                name,
                Tensor {
                    shape,
                    data: vec![0.0; n],
                },
            );
        }
    }
    weights
}

#[test]
fn transition_density_matches_the_linear_gaussian_closed_form() {
    for coupling in [AFFINE, SPLINE] {
        let mut config = config(3, 2, LatentKind::GoTo, coupling);
        config.normalisation.state_mean = vec![0.5, -1.0, 2.0];
        config.normalisation.state_std = vec![2.0, 0.3, 1.5];
        let weights = linear_gaussian(&config, 11);
        let d = 3;
        // y = μ + S (M z + b): compose the LU mixings by hand.
        let (mut m, mut b) = (DMatrix::<f64>::identity(d, d), DVector::<f64>::zeros(d));
        for i in 0..config.layers {
            let p = format!("layers.{i}.mixing");
            let lower = matrix(&weights, &format!("{p}.lower"), d).lower_triangle();
            let l = lower
                - DMatrix::from_diagonal(&matrix(&weights, &format!("{p}.lower"), d).diagonal())
                + DMatrix::identity(d, d);
            let mut u = matrix(&weights, &format!("{p}.upper"), d).upper_triangle();
            let log_diag = vector(&weights, &format!("{p}.log_diag"));
            for j in 0..d {
                u[(j, j)] = log_diag[j].exp();
            }
            let w = l * u;
            m = &w * m;
            b = &w * b + vector(&weights, &format!("{p}.bias"));
        }
        let s = DMatrix::from_diagonal(&DVector::from_vec(config.normalisation.state_std.clone()));
        let mu = DVector::from_vec(config.normalisation.state_mean.clone());
        let factor = matrix(&weights, "latent.factor", d);
        let skew = matrix(&weights, "latent.skew", d).lower_triangle()
            - DMatrix::from_diagonal(&matrix(&weights, "latent.skew", d).diagonal());
        let a = -(&factor * factor.transpose() + DMatrix::identity(d, d) * config.min_rate) + &skew
            - skew.transpose();
        let phi = (a * config.dt).exp();
        let sigma2 =
            DMatrix::from_diagonal(&vector(&weights, "latent.log_sigma").map(|v| (2.0 * v).exp()));
        let sigma02 =
            DMatrix::from_diagonal(&vector(&weights, "latent.log_sigma0").map(|v| (2.0 * v).exp()));
        let observe = |z: &DVector<f64>| &mu + &s * (&m * z + &b);
        let sm = &s * &m;

        let policy = Policy::new(&config, weights).unwrap();
        let mut ws = policy.workspace();
        let mut r = rng(12);
        for _ in 0..20 {
            let y_prev = DVector::from_vec(uniform(&mut r, d, 3.0));
            let y_next = DVector::from_vec(uniform(&mut r, d, 3.0));
            let c = uniform(&mut r, 2, 1.0);
            let z_prev = sm.clone().try_inverse().unwrap() * (&y_prev - &mu - &s * &b);
            // One step: N(f(Φ z), SM Σ (SM)ᵀ).
            let expected = gaussian(
                &y_next,
                &observe(&(&phi * &z_prev)),
                &(&sm * &sigma2 * sm.transpose()),
            );
            let got = policy
                .log_transition(y_prev.as_slice(), y_next.as_slice(), &c, &mut ws)
                .unwrap();
            assert!(
                (got - expected).abs() < 1e-8 * (1.0 + expected.abs()),
                "{got} vs {expected}"
            );
            // Three steps: Σ₃ by the recursion Σ_{j+1} = Φ Σ_j Φᵀ + Σ.
            let mut cov = sigma2.clone();
            for _ in 1..3 {
                cov = &phi * cov * phi.transpose() + &sigma2;
            }
            let mean3 = observe(&(&phi * &phi * &phi * &z_prev));
            let expected3 = gaussian(&y_next, &mean3, &(&sm * cov * sm.transpose()));
            let got3 = policy
                .log_transition_multi(y_prev.as_slice(), y_next.as_slice(), &c, 3, &mut ws)
                .unwrap();
            assert!(
                (got3 - expected3).abs() < 1e-8 * (1.0 + expected3.abs()),
                "{got3} vs {expected3}"
            );
            // Initial state: N(f(0), SM Σ₀ (SM)ᵀ).
            let expected0 = gaussian(
                &y_prev,
                &observe(&DVector::zeros(d)),
                &(&sm * &sigma02 * sm.transpose()),
            );
            let got0 = policy.log_initial(y_prev.as_slice(), &c, &mut ws).unwrap();
            assert!(
                (got0 - expected0).abs() < 1e-8 * (1.0 + expected0.abs()),
                "{got0} vs {expected0}"
            );
        }
    }
}

#[test]
fn limit_cycle_transition_is_the_cartesian_gaussian_around_the_polar_step() {
    let config = config(3, 0, LatentKind::LimitCycle, SPLINE);
    let weights = linear_gaussian(&config, 5);
    let policy = Policy::new(&config, weights).unwrap();
    let cycle = policy.latent().cycle().unwrap();
    let mut r = rng(6);
    for _ in 0..20 {
        let z = uniform(&mut r, 3, 2.0);
        let mut mean = vec![0.0; 3];
        policy.latent().mean_step(&z, &mut mean);
        let (rho, psi) = (z[0].hypot(z[1]), z[1].atan2(z[0]));
        let rho_next = cycle.radius + (rho - cycle.radius) * (cycle.rate * config.dt).exp();
        let psi_next = psi + cycle.omega * config.dt;
        assert!((mean[0] - rho_next * psi_next.cos()).abs() < 1e-12);
        assert!((mean[1] - rho_next * psi_next.sin()).abs() < 1e-12);
        assert!(rho_next > 0.0 && cycle.rate < 0.0);
    }
}

#[test]
fn samples_follow_the_transition_density() {
    let config = config(3, 1, LatentKind::LimitCycle, SPLINE);
    let policy = random_policy(&config, 31);
    let mut ws = policy.workspace();
    let mut r = rng(32);
    let (y, c) = (vec![0.4, -0.2, 0.7], vec![0.3]);
    let mut z = vec![0.0; 3];
    policy.latent_state(&y, &c, &mut ws, &mut z).unwrap();
    let mut mean = vec![0.0; 3];
    policy.latent().mean_step(&z, &mut mean);
    let sigma = policy.latent().sigma().to_vec();
    let n = 20_000;
    let (mut sum, mut sum_sq) = (vec![0.0; 3], vec![0.0; 3]);
    let (mut sample, mut z_sample) = (vec![0.0; 3], vec![0.0; 3]);
    for _ in 0..n {
        policy
            .sample_next(&y, &c, &mut r, &mut ws, &mut sample)
            .unwrap();
        policy
            .latent_state(&sample, &c, &mut ws, &mut z_sample)
            .unwrap();
        for i in 0..3 {
            let w = (z_sample[i] - mean[i]) / sigma[i];
            sum[i] += w;
            sum_sq[i] += w * w;
        }
    }
    // Whitened latent residuals are standard normal: mean within 4 standard errors,
    // variance within 5%.
    for i in 0..3 {
        let m = sum[i] / n as f64;
        assert!(m.abs() < 4.0 / (n as f64).sqrt(), "dim {i}: mean {m}");
        let v = sum_sq[i] / n as f64 - m * m;
        assert!((v - 1.0).abs() < 0.05, "dim {i}: variance {v}");
    }
}
