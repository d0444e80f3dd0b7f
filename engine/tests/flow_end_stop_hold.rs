//! The end-stop hold (`ciflow_engine::flow::end_stop_hold`) on a robot that realises every
//! command exactly (a double integrator): from starts the barrier holds, where the field
//! points into a stop, the policy that follows its own latent state converges, never
//! reaching a stop, and lets go of the hold at the attractor. The memoryless policy on the
//! same starts is the negative control: it stands still short of the attractor on some.
//! Without a hold engaged the command is the memoryless one (without a joint range too: the
//! sampled-control guard leaves a field the period resolves alone).

mod flow_common;

use ciflow_engine::flow::layers::joint_range::BARRIER_MARGIN;
use ciflow_engine::flow::{EndStopHold, FlowConfig, Policy};
use flow_common::*;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Control period (s) and the robot's integration substeps within it.
const PERIOD: f64 = 0.01;
const SUBSTEPS: usize = 10;
const GAIN: f64 = 10.0;
/// 30 s of control.
const PERIODS: usize = 3000;

/// Distance of `y` from the nearest limit of the narrow box.
fn room(y: &[f64]) -> f64 {
    y.iter()
        .zip(NARROW_MIN.iter().zip(&NARROW_MAX))
        .map(|(v, (lo, hi))| (v - lo).min(hi - v))
        .fold(f64::INFINITY, f64::min)
}

/// The closest approach of the noise-free policy to a limit from `q0`.
fn closest_noise_free(policy: &Policy, q0: &[f64], c: &[f64]) -> f64 {
    let mut ws = policy.workspace();
    let (mut y, mut next, mut closest) = (q0.to_vec(), vec![0.0; 3], f64::INFINITY);
    for _ in 0..2000 {
        policy.mean_next(&y, c, &mut ws, &mut next).unwrap();
        std::mem::swap(&mut y, &mut next);
        closest = closest.min(room(&y));
    }
    closest
}

struct Rollout {
    /// Closest approach to a limit of what the policy read, and of the robot.
    closest_read: f64,
    closest_measured: f64,
    /// Distance to the attractor at the end.
    final_distance: f64,
}

/// [`PERIODS`] control periods from rest at `q0`, with `hold` or memoryless without it.
fn roll_out(policy: &Policy, q0: &[f64], c: &[f64], mut hold: Option<&mut EndStopHold>) -> Rollout {
    let mut ws = policy.workspace();
    let (mut q, mut qd) = (q0.to_vec(), vec![0.0; 3]);
    let (mut a, mut v) = (vec![0.0; 3], vec![0.0; 3]);
    let mut rollout = Rollout {
        closest_read: f64::INFINITY,
        closest_measured: f64::INFINITY,
        final_distance: 0.0,
    };
    for _ in 0..PERIODS {
        let read = match hold.as_deref_mut() {
            Some(hold) => {
                policy
                    .acceleration_held(&q, &qd, c, GAIN, hold, &mut ws, &mut a, &mut v)
                    .unwrap();
                room(hold.reading())
            }
            None => {
                policy
                    .acceleration(&q, &qd, c, GAIN, &mut ws, &mut a, &mut v)
                    .unwrap();
                room(&q)
            }
        };
        rollout.closest_read = rollout.closest_read.min(read);
        let h = PERIOD / SUBSTEPS as f64;
        for _ in 0..SUBSTEPS {
            for i in 0..3 {
                qd[i] += h * a[i];
                q[i] += h * qd[i];
            }
            rollout.closest_measured = rollout.closest_measured.min(room(&q));
        }
    }
    let mut scratch = vec![0.0; 3];
    rollout.final_distance = policy
        .attractor_distance(&q, c, &mut ws, &mut scratch)
        .unwrap();
    rollout
}

fn bounded() -> FlowConfig {
    narrow(AFFINE, 1.0, 10.0)
}

/// A start at rest where the barrier's spring holds it: one joint [`BARRIER_MARGIN`] off
/// a limit, the others anywhere inside.
fn start_at_the_barrier(r: &mut ChaCha8Rng) -> Vec<f64> {
    let mut q0: Vec<f64> = (0..3)
        .map(|i| r.random_range(NARROW_MIN[i] + 0.1..NARROW_MAX[i] - 0.1))
        .collect();
    let joint = r.random_range(0..3);
    q0[joint] = match r.random_bool(0.5) {
        true => NARROW_MAX[joint] - BARRIER_MARGIN,
        false => NARROW_MIN[joint] + BARRIER_MARGIN,
    };
    q0
}

#[test]
fn following_its_own_latent_state_the_policy_converges_where_the_memoryless_one_stands_still() {
    // Random flows and starts at the barrier from which the noise-free path runs closer to
    // a limit than a tenth of the barrier's margin.
    let config = bounded();
    let mut r = rng(90);
    let (mut starts, mut standstills, mut closest_read) = (0, 0, f64::INFINITY);
    for k in 0..400 {
        let policy = Policy::new(&config, tame_weights(&config, 900 + k)).unwrap();
        let c = uniform(&mut r, 2, 1.0);
        let q0 = start_at_the_barrier(&mut r);
        if closest_noise_free(&policy, &q0, &c) > 0.1 * BARRIER_MARGIN {
            continue;
        }
        starts += 1;
        let mut hold = EndStopHold::new(3, PERIOD).unwrap();
        let held = roll_out(&policy, &q0, &c, Some(&mut hold));
        let case = format!("flow {k} from {q0:?}");
        assert!(
            held.final_distance < 1e-3,
            "{case}: {}",
            held.final_distance
        );
        assert!(held.closest_measured > 0.0, "{case}: reached a stop");
        assert!(!hold.is_engaged(), "{case}: still held at the attractor");
        closest_read = closest_read.min(held.closest_read);
        let memoryless = roll_out(&policy, &q0, &c, None);
        standstills += usize::from(memoryless.final_distance > 1e-2);
    }
    assert!(starts >= 5, "only {starts} starts graze a limit");
    assert!(
        standstills >= 1,
        "the memoryless policy converged from all {starts} starts"
    );
    // The reference ran where the barrier kept the robot from going.
    assert!(closest_read < 0.01 * BARRIER_MARGIN, "{closest_read}");
}

#[test]
fn without_a_hold_engaged_the_command_is_the_memoryless_one() {
    let config = bounded();
    let free_config = FlowConfig {
        joint_range: None,
        ..config.clone()
    };
    let ranged = Policy::new(&config, tame_weights(&config, 95)).unwrap();
    let free = Policy::new(&free_config, tame_weights(&config, 95)).unwrap();
    let mut r = rng(96);
    let mut ws = ranged.workspace();
    for policy in [&ranged, &free] {
        let mut hold = EndStopHold::new(3, PERIOD).unwrap();
        for _ in 0..20 {
            let q: Vec<f64> = (0..3)
                .map(|i| r.random_range(NARROW_MIN[i] + 0.1..NARROW_MAX[i] - 0.1))
                .collect();
            let (qd, c) = (uniform(&mut r, 3, 0.5), uniform(&mut r, 2, 1.0));
            let (mut a, mut v) = ([0.0; 3], [0.0; 3]);
            let (mut a_held, mut v_held) = ([0.0; 3], [0.0; 3]);
            policy
                .acceleration(&q, &qd, &c, GAIN, &mut ws, &mut a, &mut v)
                .unwrap();
            policy
                .acceleration_held(
                    &q,
                    &qd,
                    &c,
                    GAIN,
                    &mut hold,
                    &mut ws,
                    &mut a_held,
                    &mut v_held,
                )
                .unwrap();
            assert_eq!((a, v), (a_held, v_held));
            assert!(!hold.is_engaged());
        }
    }
}

#[test]
fn a_hold_refuses_a_bad_period_and_the_wrong_robot() {
    assert!(EndStopHold::new(3, 0.0).is_err());
    assert!(EndStopHold::new(3, f64::NAN).is_err());
    let config = bounded();
    let policy = Policy::new(&config, tame_weights(&config, 97)).unwrap();
    let mut hold = EndStopHold::new(2, PERIOD).unwrap();
    let (mut a, mut v) = ([0.0; 3], [0.0; 3]);
    let result = policy.acceleration_held(
        &[0.0; 3],
        &[0.0; 3],
        &[0.0; 2],
        GAIN,
        &mut hold,
        &mut policy.workspace(),
        &mut a,
        &mut v,
    );
    assert!(result.is_err());
}
