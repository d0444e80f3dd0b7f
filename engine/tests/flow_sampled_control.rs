//! The sampled-control guard (`ciflow_engine::flow::sampled_control`) on a robot that
//! realises every command exactly over its control period (a double integrator, the
//! command held for the period). A policy whose field contracts at ≥ 300 /s, three times
//! what a 100 Hz loop resolves: the guarded command of `acceleration_held` arrives, the
//! continuous-time command of `acceleration` held the same way (the negative control)
//! oscillates with growing amplitude. The guard moves the command only along the motion;
//! where the period resolves the field it leaves the command bit for bit alone
//! (`flow_end_stop_hold.rs`, the policy without a joint range).

mod flow_common;

use ciflow_engine::flow::{EndStopHold, FlowConfig, LatentKind, Policy};
use flow_common::*;

/// Control period (s) and the robot's integration substeps within it.
const PERIOD: f64 = 0.01;
const SUBSTEPS: usize = 10;
const GAIN: f64 = 10.0;
/// 5 s of control.
const PERIODS: usize = 500;

/// A 2-D go-to policy with a 1-D context whose latent contracts at `rate` /s at least.
fn policy(rate: f64, seed: u64) -> Policy {
    let mut config: FlowConfig = config(2, 1, LatentKind::GoTo, AFFINE);
    config.min_rate = rate;
    Policy::new(&config, tame_weights(&config, seed)).unwrap()
}

/// Distance to the attractor after [`PERIODS`] periods from rest at `q0`, each command
/// from `acceleration_held` (guarded) or `acceleration` held for the period.
fn final_distance(policy: &Policy, q0: &[f64], c: &[f64], guarded: bool) -> f64 {
    let mut ws = policy.workspace();
    let mut hold = EndStopHold::new(2, PERIOD).unwrap();
    let (mut q, mut qd) = (q0.to_vec(), vec![0.0; 2]);
    let (mut a, mut v) = (vec![0.0; 2], vec![0.0; 2]);
    for _ in 0..PERIODS {
        if guarded {
            policy
                .acceleration_held(&q, &qd, c, GAIN, &mut hold, &mut ws, &mut a, &mut v)
                .unwrap();
        } else {
            policy
                .acceleration(&q, &qd, c, GAIN, &mut ws, &mut a, &mut v)
                .unwrap();
        }
        let h = PERIOD / SUBSTEPS as f64;
        for _ in 0..SUBSTEPS {
            for i in 0..2 {
                q[i] += h * qd[i] + 0.5 * h * h * a[i];
                qd[i] += h * a[i];
            }
        }
        if !q.iter().chain(&qd).all(|x| x.is_finite() && x.abs() < 1e6) {
            return f64::INFINITY;
        }
    }
    let mut scratch = vec![0.0; 2];
    policy
        .attractor_distance(&q, c, &mut ws, &mut scratch)
        .unwrap()
}

#[test]
fn a_field_faster_than_the_control_rate_arrives_guarded_and_oscillates_unguarded() {
    let mut r = rng(31);
    for seed in 0..5 {
        let policy = policy(300.0, 310 + seed);
        let (q0, c) = (uniform(&mut r, 2, 1.5), uniform(&mut r, 1, 1.0));
        let guarded = final_distance(&policy, &q0, &c, true);
        assert!(
            guarded < 1e-6,
            "flow {seed} from {q0:?}: ended {guarded} away"
        );
        let unguarded = final_distance(&policy, &q0, &c, false);
        assert!(
            unguarded > 1.0,
            "flow {seed} from {q0:?}: the unguarded loop ended {unguarded} away"
        );
    }
}

#[test]
fn the_guard_moves_the_command_only_along_the_motion() {
    let policy = policy(300.0, 320);
    let mut ws = policy.workspace();
    let mut hold = EndStopHold::new(2, PERIOD).unwrap();
    let mut r = rng(32);
    let mut engaged = 0;
    for _ in 0..50 {
        let (q, qd, c) = (
            uniform(&mut r, 2, 1.5),
            uniform(&mut r, 2, 2.0),
            uniform(&mut r, 1, 1.0),
        );
        let (mut a, mut a_held, mut v) = ([0.0; 2], [0.0; 2], [0.0; 2]);
        policy
            .acceleration(&q, &qd, &c, GAIN, &mut ws, &mut a, &mut v)
            .unwrap();
        policy
            .acceleration_held(&q, &qd, &c, GAIN, &mut hold, &mut ws, &mut a_held, &mut v)
            .unwrap();
        let change = [a_held[0] - a[0], a_held[1] - a[1]];
        let across = (change[0] * qd[1] - change[1] * qd[0]).abs();
        assert!(
            across <= 1e-9 * (a[0].hypot(a[1]) * qd[0].hypot(qd[1])),
            "the guard turned the command: {a:?} -> {a_held:?} at q̇ = {qd:?}"
        );
        engaged += usize::from(change != [0.0; 2]);
    }
    assert!(engaged >= 10, "the guard engaged at only {engaged} of 50");
}
