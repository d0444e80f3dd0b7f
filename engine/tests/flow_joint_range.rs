//! A joint range as the flow's last layer (`ciflow_engine::flow::layers::joint_range`):
//! the noise-free policy stays inside the position limits from every start, its desired
//! velocity is the field slowed by a common factor into the speed bounds (with the exact
//! time derivative) and within braking distance of the limits, and its desired
//! acceleration is scaled into a share of its bounds (by the latent norm) along its own
//! direction. The same weights without the range are the negative control: they leave
//! the limits.

mod flow_common;

use ciflow_engine::flow::layers::joint_range::BRAKING_SHARE;
use ciflow_engine::flow::{FlowConfig, JointRange, Policy, PolicyWorkspace};
use flow_common::*;
use rand::RngExt;

fn without_range(config: &FlowConfig) -> FlowConfig {
    FlowConfig {
        joint_range: None,
        ..config.clone()
    }
}

fn inside(y: &[f64]) -> bool {
    y.iter()
        .zip(NARROW_MIN.iter().zip(&NARROW_MAX))
        .all(|(v, (lo, hi))| lo < v && v < hi)
}

/// Starts inside the limits, a third of them within 1e-9 of one.
fn start(r: &mut rand_chacha::ChaCha8Rng, k: usize) -> Vec<f64> {
    (0..3)
        .map(|i| match (k % 3, i) {
            (0, 0) => NARROW_MIN[0] + 1e-9,
            (1, 2) => NARROW_MAX[2] - 1e-9,
            _ => r.random_range(NARROW_MIN[i]..NARROW_MAX[i]),
        })
        .collect()
}

/// States in the middle 90 % of every range.
fn interior(r: &mut rand_chacha::ChaCha8Rng) -> Vec<f64> {
    (0..3)
        .map(|i| {
            let margin = 0.05 * (NARROW_MAX[i] - NARROW_MIN[i]);
            r.random_range(NARROW_MIN[i] + margin..NARROW_MAX[i] - margin)
        })
        .collect()
}

/// Mean-step rollouts from [`start`]s: (every state inside the limits, rollouts whose
/// last state is within 1e-6 of the attractor, rollouts).
fn roll_out(policy: &Policy, seed: u64) -> (bool, usize, usize) {
    let mut ws = policy.workspace();
    let mut r = rng(seed);
    let (mut all_inside, mut converged, rollouts) = (true, 0, 30);
    for k in 0..rollouts {
        let c = uniform(&mut r, 2, 1.0);
        let mut y = start(&mut r, k);
        let mut next = vec![0.0; 3];
        for _ in 0..3000 {
            policy.mean_next(&y, &c, &mut ws, &mut next).unwrap();
            std::mem::swap(&mut y, &mut next);
            all_inside &= inside(&y);
        }
        let mut distance = vec![0.0; 3];
        let d = policy
            .attractor_distance(&y, &c, &mut ws, &mut distance)
            .unwrap();
        converged += usize::from(d < 1e-6);
    }
    (all_inside, converged, rollouts)
}

#[test]
fn noise_free_motion_stays_inside_the_limits_and_the_same_weights_without_them_leave() {
    let mut left = 0;
    for (k, coupling) in [AFFINE, SPLINE].into_iter().enumerate() {
        let config = narrow(coupling, UNBOUNDED, UNBOUNDED);
        let weights = tame_weights(&config, 40 + k as u64);
        let ranged = Policy::new(&config, weights.clone()).unwrap();
        let (all_inside, converged, rollouts) = roll_out(&ranged, k as u64);
        assert!(all_inside, "coupling {k}: a state left the limits");
        assert_eq!(converged, rollouts, "coupling {k}");

        let free = Policy::new(&without_range(&config), weights).unwrap();
        let (free_inside, free_converged, _) = roll_out(&free, k as u64);
        assert_eq!(
            free_converged, rollouts,
            "coupling {k}: the control is stable too"
        );
        left += usize::from(!free_inside);
    }
    assert_eq!(
        left, 2,
        "without the range, both random flows leave the limits"
    );
}

#[test]
fn desired_velocity_is_the_field_slowed_into_its_bounds_with_the_exact_derivative() {
    let speed_max = 0.05;
    for (k, coupling) in [AFFINE, SPLINE].into_iter().enumerate() {
        let config = narrow(coupling, speed_max, UNBOUNDED);
        let weights = tame_weights(&config, 50 + k as u64);
        let bounded = Policy::new(&config, weights.clone()).unwrap();
        let unscaled = Policy::new(
            &narrow(config.coupling.clone(), UNBOUNDED, UNBOUNDED),
            weights,
        )
        .unwrap();
        let (mut ws, mut ws_unscaled) = (bounded.workspace(), unscaled.workspace());
        let mut r = rng(60 + k as u64);
        let (mut scaled_somewhere, gain) = (false, 3.0);
        for _ in 0..40 {
            let q = interior(&mut r);
            let qd = uniform(&mut r, 3, 0.05);
            let c = uniform(&mut r, 2, 1.0);
            let (mut v, mut v_free) = (vec![0.0; 3], vec![0.0; 3]);
            bounded.velocity(&q, &c, &mut ws, &mut v).unwrap();
            unscaled
                .velocity(&q, &c, &mut ws_unscaled, &mut v_free)
                .unwrap();
            assert!(v.iter().all(|x| x.abs() < speed_max), "{v:?}");
            // One positive factor s ≤ 1 for every joint: the same direction.
            let s = v[0] / v_free[0];
            assert!(s > 0.0 && s <= 1.0 + 1e-12, "{s}");
            assert!(max_abs_diff(&v, &v_free.iter().map(|x| s * x).collect::<Vec<_>>()) < 1e-12);
            scaled_somewhere |= s < 0.9;

            let (mut acc, mut v_des) = (vec![0.0; 3], vec![0.0; 3]);
            bounded
                .acceleration(&q, &qd, &c, gain, &mut ws, &mut acc, &mut v_des)
                .unwrap();
            assert!(max_abs_diff(&v, &v_des) < 1e-12 * (1.0 + largest(&v)));
            let expected = feedforward_by_differences(&bounded, &mut ws, &q, &qd, &c, gain);
            assert!(
                max_abs_diff(&acc, &expected) < 1e-6 * (1.0 + largest(&expected)),
                "coupling {k}: {acc:?} vs {expected:?}"
            );
        }
        assert!(scaled_somewhere, "coupling {k}: the bound never acted");
    }
}

#[test]
fn near_limits_speed_leaves_braking_room_and_acceleration_keeps_its_direction() {
    let acceleration_max = 0.02;
    let policy = Policy::new(
        &narrow(AFFINE, UNBOUNDED, acceleration_max),
        tame_weights(&narrow(AFFINE, UNBOUNDED, acceleration_max), 70),
    )
    .unwrap();
    let mut ws = policy.workspace();
    let mut r = rng(71);
    let (mut scaled, gain) = (0, 2.0);
    for _ in 0..40 {
        let q = interior(&mut r);
        // At rest, more than the barrier's margin inside the limits, the end-stop barrier
        // is inactive (it has its own tests beside the layer): the scaling alone acts.
        let qd = vec![0.0; 3];
        let c = uniform(&mut r, 2, 1.0);
        let mut v = vec![0.0; 3];
        policy.velocity(&q, &c, &mut ws, &mut v).unwrap();
        for i in 0..3 {
            let limit = if v[i] >= 0.0 {
                NARROW_MAX[i]
            } else {
                NARROW_MIN[i]
            };
            let braking = (2.0 * BRAKING_SHARE * acceleration_max * (limit - q[i]).abs()).sqrt();
            assert!(v[i].abs() < braking, "joint {i}: {} at {q:?}", v[i]);
        }
        let (mut a, mut v_des) = (vec![0.0; 3], vec![0.0; 3]);
        policy
            .acceleration(&q, &qd, &c, gain, &mut ws, &mut a, &mut v_des)
            .unwrap();
        let unbounded = feedforward_by_differences(&policy, &mut ws, &q, &qd, &c, gain);
        let mut z = vec![0.0; 3];
        policy.latent_state(&q, &c, &mut ws, &mut z).unwrap();
        let share = JointRange::acceleration_share(z.iter().map(|x| x * x).sum::<f64>().sqrt());
        let excess = (largest(&unbounded) / (share * acceleration_max)).max(1.0);
        let expected: Vec<f64> = unbounded.iter().map(|x| x / excess).collect();
        assert!(max_abs_diff(&a, &expected) < 1e-6 * (1.0 + largest(&unbounded)));
        assert!(
            a.iter()
                .all(|x| x.abs() <= share * acceleration_max * (1.0 + 1e-12))
        );
        scaled += usize::from(excess > 1.0);
    }
    assert!(scaled > 10, "the bound acted on {scaled} of 40 states");
}

fn largest(values: &[f64]) -> f64 {
    values.iter().fold(0.0f64, |a, x| a.max(x.abs()))
}

/// `d/dt v_des + K_v (v_des − q̇)` with the derivative along `q̇` by a fourth-order central
/// difference of [`Policy::velocity`], before any acceleration bound.
fn feedforward_by_differences(
    policy: &Policy,
    ws: &mut PolicyWorkspace,
    q: &[f64],
    qd: &[f64],
    c: &[f64],
    gain: f64,
) -> Vec<f64> {
    let h = 1e-4;
    let mut at = |t: f64| {
        let qt: Vec<f64> = q.iter().zip(qd).map(|(a, b)| a + t * b).collect();
        let mut out = vec![0.0; q.len()];
        policy.velocity(&qt, c, ws, &mut out).unwrap();
        out
    };
    let (v, p1, m1, p2, m2) = (at(0.0), at(h), at(-h), at(2.0 * h), at(-2.0 * h));
    (0..q.len())
        .map(|i| (8.0 * (p1[i] - m1[i]) - (p2[i] - m2[i])) / (12.0 * h) + gain * (v[i] - qd[i]))
        .collect()
}
