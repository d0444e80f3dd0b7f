//! The network is a bijection with the log-determinant and derivatives it claims.

mod flow_common;

use ciflow_engine::flow::{FlowConfig, LatentKind};
use ciflow_engine::nn::scalar::Dual;
use flow_common::*;
use nalgebra::DMatrix;

#[test]
fn inverse_round_trips_inside_and_far_outside_the_data() {
    for (k, config) in all_variants().iter().enumerate() {
        let policy = random_policy(config, k as u64);
        let mut ws = policy.workspace();
        let mut r = rng(100 + k as u64);
        let (d, m) = (config.state_dim, config.context_dim);
        for half_width in [0.5, 3.0, 50.0] {
            for _ in 0..20 {
                let y = uniform(&mut r, d, half_width);
                let c = uniform(&mut r, m, 1.0);
                let (mut z, mut back) = (vec![0.0; d], vec![0.0; d]);
                policy.latent_state(&y, &c, &mut ws, &mut z).unwrap();
                policy.observe(&z, &c, &mut ws, &mut back).unwrap();
                let scale = 1.0 + y.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                assert!(
                    max_abs_diff(&y, &back) < 1e-9 * scale,
                    "variant {k}: {y:?} -> {back:?}"
                );
            }
        }
    }
}

/// Central-difference Jacobian of `z ↦ f(z, c)`.
fn finite_difference_jacobian(
    policy: &ciflow_engine::flow::Policy,
    z: &[f64],
    c: &[f64],
) -> DMatrix<f64> {
    let d = z.len();
    let mut ws = policy.workspace();
    let h = 1e-6;
    let mut jacobian = DMatrix::zeros(d, d);
    let (mut plus, mut minus) = (vec![0.0; d], vec![0.0; d]);
    for j in 0..d {
        let mut zp = z.to_vec();
        zp[j] += h;
        let mut zm = z.to_vec();
        zm[j] -= h;
        policy.observe(&zp, c, &mut ws, &mut plus).unwrap();
        policy.observe(&zm, c, &mut ws, &mut minus).unwrap();
        for i in 0..d {
            jacobian[(i, j)] = (plus[i] - minus[i]) / (2.0 * h);
        }
    }
    jacobian
}

#[test]
fn log_determinant_matches_the_dual_number_jacobian() {
    for (k, config) in all_variants().iter().enumerate() {
        let policy = random_policy(config, k as u64);
        let mut ws = policy.workspace();
        let mut r = rng(200 + k as u64);
        let (d, m) = (config.state_dim, config.context_dim);
        for _ in 0..10 {
            let z = uniform(&mut r, d, 2.0);
            let c = uniform(&mut r, m, 1.0);
            let expected = dual_jacobian(&policy, &z, &c).determinant().abs().ln();
            // log p(y₀|c) - log N(z₀; 0, σ₀²) = log|det ∂f⁻¹/∂y| = -log|det ∂f/∂z|.
            let mut y = vec![0.0; d];
            policy.observe(&z, &c, &mut ws, &mut y).unwrap();
            let log_det_inverse =
                policy.log_initial(&y, &c, &mut ws).unwrap() - policy.latent().log_initial(&z);
            assert!(
                (-log_det_inverse - expected).abs() < 1e-5 * (1.0 + expected.abs()),
                "variant {k}: {} vs {expected}",
                -log_det_inverse
            );
        }
    }
}

#[test]
fn velocity_is_the_jacobian_times_the_latent_field() {
    for (k, config) in all_variants().iter().enumerate() {
        let policy = random_policy(config, k as u64);
        let mut ws = policy.workspace();
        let mut r = rng(300 + k as u64);
        let (d, m) = (config.state_dim, config.context_dim);
        for _ in 0..10 {
            let z = uniform(&mut r, d, 2.0);
            let c = uniform(&mut r, m, 1.0);
            let mut y = vec![0.0; d];
            policy.observe(&z, &c, &mut ws, &mut y).unwrap();
            let mut v = vec![0.0; d];
            policy.latent().velocity(&z, &mut v);
            let expected =
                finite_difference_jacobian(&policy, &z, &c) * nalgebra::DVector::from_vec(v);
            let mut velocity = vec![0.0; d];
            policy.velocity(&y, &c, &mut ws, &mut velocity).unwrap();
            let scale = 1.0 + expected.amax();
            assert!(
                max_abs_diff(&velocity, expected.as_slice()) < 1e-6 * scale,
                "variant {k}: {velocity:?} vs {expected:?}"
            );
        }
    }
}

#[test]
fn acceleration_feedforward_is_the_time_derivative_of_the_desired_velocity() {
    let (mut compared, mut capped) = (0, 0);
    for (k, config) in all_variants().iter().enumerate() {
        let policy = random_policy(config, k as u64);
        let mut ws = policy.workspace();
        let mut r = rng(400 + k as u64);
        let (d, m) = (config.state_dim, config.context_dim);
        let gain = 3.0;
        for _ in 0..10 {
            let q = uniform(&mut r, d, 2.0);
            let qd = uniform(&mut r, d, 1.0);
            let c = uniform(&mut r, m, 1.0);
            let (mut acc, mut v_des) = (vec![0.0; d], vec![0.0; d]);
            policy
                .acceleration(&q, &qd, &c, gain, &mut ws, &mut acc, &mut v_des)
                .unwrap();
            let mut velocity = vec![0.0; d];
            policy.velocity(&q, &c, &mut ws, &mut velocity).unwrap();
            assert!(
                max_abs_diff(&velocity, &v_des)
                    < 1e-9 * (1.0 + velocity.iter().fold(0.0f64, |a, v| a.max(v.abs())))
            );
            // Fourth-order central difference of v_des along q̇.
            // h⁴ truncation against ε/h rounding: 1e-4 left 2e-5 relative error on the
            // steepest random variants, 3e-5 brings every variant within 1e-5.
            let h = 3e-5;
            let shifted = |ws: &mut _, t: f64| {
                let qt: Vec<f64> = q.iter().zip(&qd).map(|(a, b)| a + t * b).collect();
                let mut v = vec![0.0; d];
                policy.velocity(&qt, &c, ws, &mut v).unwrap();
                v
            };
            let (vp, vm) = (shifted(&mut ws, h), shifted(&mut ws, -h));
            let (vp2, vm2) = (shifted(&mut ws, 2.0 * h), shifted(&mut ws, -2.0 * h));
            let derivative: Vec<f64> = (0..d)
                .map(|i| (8.0 * (vp[i] - vm[i]) - (vp2[i] - vm2[i])) / (12.0 * h))
                .collect();
            let expected: Vec<f64> = (0..d)
                .map(|i| derivative[i] + gain * (velocity[i] - qd[i]))
                .collect();
            let scale = 1.0 + expected.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            for i in 0..d {
                // Under a joint range the end-stop barrier's spring caps the acceleration
                // towards a limit (`joint_range`'s own tests); random fields reach past it.
                if barrier_binds(config, i, q[i], qd[i], expected[i]) {
                    capped += 1;
                    continue;
                }
                compared += 1;
                assert!(
                    (acc[i] - expected[i]).abs() < 1e-5 * scale,
                    "variant {k}, joint {i}: {acc:?} vs {expected:?}"
                );
            }
        }
    }
    assert!(
        compared > 10 * capped,
        "{compared} joints compared, {capped} capped"
    );
}

/// Whether the joint range's end-stop barrier caps acceleration `a` of joint `i` at
/// `(q, q̇)`.
fn barrier_binds(config: &FlowConfig, i: usize, q: f64, qd: f64, a: f64) -> bool {
    let Some(range) = &config.joint_range else {
        return false;
    };
    let (least, most) = range.barrier(i, q, qd);
    a >= most || a <= least
}

#[test]
fn goal_conditioned_attractor_sits_on_the_target_for_every_context() {
    for coupling in [AFFINE, SPLINE] {
        let mut config = config(2, 3, LatentKind::GoTo, coupling);
        config.goal_context_indices = Some(vec![1, 2]);
        let policy = random_policy(&config, 7);
        let mut ws = policy.workspace();
        let mut r = rng(8);
        for _ in 0..20 {
            let c = uniform(&mut r, 3, 5.0);
            let mut attractor = vec![0.0; 2];
            policy.attractor(&c, &mut ws, &mut attractor).unwrap();
            assert!(
                max_abs_diff(&attractor, &c[1..3]) < 1e-12 * (1.0 + c[1].abs().max(c[2].abs()))
            );
            // And it is a fixed point of the mean step.
            let mut next = vec![0.0; 2];
            policy
                .mean_next(&attractor, &c, &mut ws, &mut next)
                .unwrap();
            assert!(max_abs_diff(&attractor, &next) < 1e-9);
        }
    }
}

/// `Policy::acceleration` takes its forward pass's conditioner values from the inverse
/// pass's record; the plain nested-dual forward pass at the same point must give the
/// same `v_des` and `d/dt v_des`. The two meet the couplings at points that differ by
/// the inverse's round-trip error (1e-9 relative above), which the derivatives amplify
/// on the steepest random variants: 1e-8 relative. A wrong record or chain rule is off
/// by O(1).
#[test]
fn recorded_second_order_pass_is_the_nested_dual_forward_pass() {
    for (k, config) in all_variants().iter().enumerate() {
        if config.joint_range.is_some() {
            // Its speed and acceleration scaling act after the pass; covered above.
            continue;
        }
        let policy = random_policy(config, k as u64);
        let flow = policy.network();
        let mut ws = policy.workspace();
        let mut r = rng(500 + k as u64);
        let (d, m) = (config.state_dim, config.context_dim);
        let gain = 3.0;
        for _ in 0..5 {
            let (q, qd, c) = (
                uniform(&mut r, d, 2.0),
                uniform(&mut r, d, 1.0),
                uniform(&mut r, m, 1.0),
            );
            let mut conditioning = flow.conditioning();
            flow.condition(&c, &mut conditioning, &mut flow.scratch())
                .unwrap();
            let y: Vec<Dual<f64>> = q.iter().zip(&qd).map(|(a, b)| Dual::new(*a, *b)).collect();
            let mut z = vec![Dual::new(0.0, 0.0); d];
            flow.inverse(&y, &conditioning, &mut flow.scratch(), &mut z);
            let mut v = vec![Dual::new(0.0, 0.0); d];
            policy.latent().velocity(&z, &mut v);
            let nested: Vec<_> = z.iter().zip(&v).map(|(z, v)| Dual::new(*z, *v)).collect();
            let mut out = nested.clone();
            flow.forward(&nested, &conditioning, &mut flow.scratch(), &mut out);
            let expected: Vec<f64> = (0..d)
                .map(|i| out[i].du.du + gain * (out[i].du.re - qd[i]))
                .collect();
            let v_des: Vec<f64> = out.iter().map(|o| o.du.re).collect();

            let (mut acc, mut velocity) = (vec![0.0; d], vec![0.0; d]);
            policy
                .acceleration(&q, &qd, &c, gain, &mut ws, &mut acc, &mut velocity)
                .unwrap();
            let scale = |v: &[f64]| 1.0 + v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            assert!(
                max_abs_diff(&velocity, &v_des) < 1e-8 * scale(&v_des),
                "variant {k}: {velocity:?} vs {v_des:?}"
            );
            assert!(
                max_abs_diff(&acc, &expected) < 1e-8 * scale(&expected),
                "variant {k}: {acc:?} vs {expected:?}"
            );
        }
    }
}
