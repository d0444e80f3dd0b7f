//! The latent dynamics' closed-form flows against a numerical integration of their own
//! field: for every latent kind with random parameters, `μ^k(z)` (the exact `k`-step map,
//! [`LatentDynamics::mean_steps`]) equals RK4 on `ż = v(z)` over `k dt`, and the saturated
//! go-to's log-domain branch for far starts joins its direct branch continuously. The
//! time-reversed dynamics (the stability check's negative control) undo the forward
//! steps and follow the negated field.

mod flow_common;

use ciflow_engine::flow::LatentKind;
use ciflow_engine::flow::latent::{LatentDynamics, settle};
use flow_common::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// RK4 substeps per latent step.
const SUBSTEPS: usize = 400;

/// `z` after `seconds` of `ż = v(z)`, by classical Runge–Kutta.
fn integrate(latent: &LatentDynamics, z: &[f64], seconds: f64) -> Vec<f64> {
    let (d, h) = (z.len(), seconds / SUBSTEPS as f64);
    let field = |z: &[f64]| {
        let mut v = vec![0.0; d];
        latent.velocity(z, &mut v);
        v
    };
    let shifted = |z: &[f64], k: &[f64], by: f64| -> Vec<f64> {
        z.iter().zip(k).map(|(a, b)| a + by * b).collect()
    };
    let mut z = z.to_vec();
    for _ in 0..SUBSTEPS {
        let k1 = field(&z);
        let k2 = field(&shifted(&z, &k1, h / 2.0));
        let k3 = field(&shifted(&z, &k2, h / 2.0));
        let k4 = field(&shifted(&z, &k3, h));
        for i in 0..d {
            z[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }
    z
}

#[test]
fn closed_form_steps_equal_the_integrated_field() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for latent_kind in [
        LatentKind::GoTo,
        LatentKind::SaturatedGoTo,
        LatentKind::LimitCycle,
    ] {
        for (seed, d) in [(0, 2), (1, 3), (2, 5)] {
            let config = config(d, 0, latent_kind, AFFINE);
            let policy = random_policy(&config, seed);
            let latent = policy.latent();
            for start in 0..4 {
                // Near the attractor and far outside the data (where the saturated go-to
                // moves at its constant far speed).
                let z = uniform(&mut rng, d, [0.05, 1.0, 5.0, 50.0][start]);
                for steps in [1, 3, 20] {
                    let mut exact = vec![0.0; d];
                    latent.mean_steps(&z, steps, &mut exact);
                    let integrated = integrate(latent, &z, steps as f64 * config.dt);
                    let scale = 1.0 + z.iter().map(|v| v.abs()).fold(0.0, f64::max);
                    assert!(
                        max_abs_diff(&exact, &integrated) < 1e-8 * scale,
                        "{latent_kind:?} d={d} start {start}, {steps} steps: {exact:?} vs \
                         {integrated:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn time_reversal_undoes_the_forward_steps_and_follows_the_negated_field() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    for latent_kind in [
        LatentKind::GoTo,
        LatentKind::SaturatedGoTo,
        LatentKind::LimitCycle,
    ] {
        for (seed, d) in [(0, 2), (1, 3)] {
            let config = config(d, 0, latent_kind, AFFINE);
            let policy = random_policy(&config, seed);
            let (forward, backward) = (policy.latent(), policy.latent().time_reversed());
            for scale in [0.05, 1.0, 5.0] {
                let z = uniform(&mut rng, d, scale);
                let (mut ahead, mut back) = (vec![0.0; d], vec![0.0; d]);
                forward.mean_step(&z, &mut ahead);
                backward.mean_step(&ahead, &mut back);
                assert!(
                    max_abs_diff(&back, &z) < 1e-10 * (1.0 + scale),
                    "{latent_kind:?} d={d}: {z:?} -> {back:?}"
                );
                let (mut v, mut v_back) = (vec![0.0; d], vec![0.0; d]);
                forward.velocity(&z, &mut v);
                backward.velocity(&z, &mut v_back);
                assert!(v.iter().zip(&v_back).all(|(a, b)| a == &-b));
                // Inside the cycle the reversed radius shrinks through the origin, where
                // the field is singular: the closed form and the field part there.
                let inside = forward.cycle().is_some_and(|c| z[0].hypot(z[1]) < c.radius);
                if !inside {
                    let mut exact = vec![0.0; d];
                    backward.mean_steps(&z, 3, &mut exact);
                    let integrated = integrate(&backward, &z, 3.0 * config.dt);
                    assert!(
                        max_abs_diff(&exact, &integrated) < 1e-8 * (1.0 + scale),
                        "{latent_kind:?} d={d}: {exact:?} vs {integrated:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn saturated_settling_is_continuous_where_it_changes_branch() {
    // `settle(u, τ) = asinh(sinh(u) e^{-τ})` switches to logarithms at u = 20 and at
    // u - ln 2 - τ = 20: both sides of each switch agree to rounding.
    for tau in [0.0, 0.3, 5.0] {
        for u in [20.0, 20.0 + std::f64::consts::LN_2 + tau + 20.0] {
            let (below, above) = (settle(u - 1e-9, tau), settle(u + 1e-9, tau));
            assert!(
                (below - above).abs() < 1e-8,
                "u={u} τ={tau}: {below} vs {above}"
            );
        }
        // And the direct branch is the definition.
        let u = 3.0_f64;
        let direct = (u.sinh() * (-tau).exp()).asinh();
        assert!((settle(u, tau) - direct).abs() < 1e-14);
    }
}
