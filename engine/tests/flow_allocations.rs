//! A policy action allocates nothing once its workspace is made: a robot asks for one every
//! control period (every millisecond for a real arm's loop), and a heap allocation there
//! can wait on a lock for as long as another thread holds it. Every architecture the flow
//! tests sweep ([`all_variants`]), each first-order and second-order action, and the
//! second-order action with an end-stop hold engaged, which steps its own latent state.
//!
//! The heap allocations of this thread are counted by this test binary's global allocator
//! ([`ciflow_engine::allocations`]), so other tests' threads do not disturb the count.

mod flow_common;

use ciflow_engine::allocations::{CountingAllocator, count_allocations};
use ciflow_engine::flow::layers::joint_range::BARRIER_MARGIN;
use ciflow_engine::flow::{EndStopHold, Policy};
use flow_common::*;

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// Control period (s) of the held actions.
const PERIOD: f64 = 0.01;
const GAIN: f64 = 10.0;

#[test]
fn every_action_of_every_architecture_allocates_nothing() {
    for (k, config) in all_variants().iter().enumerate() {
        let policy = random_policy(config, 4000 + k as u64);
        let mut r = rng(k as u64);
        let (d, m) = (config.state_dim, config.context_dim);
        let (y, qd, c) = (
            uniform(&mut r, d, 0.5),
            uniform(&mut r, d, 0.3),
            uniform(&mut r, m, 1.0),
        );
        let mut ws = policy.workspace();
        let mut hold = EndStopHold::new(d, PERIOD).unwrap();
        let (mut next, mut velocity) = (vec![0.0; d], vec![0.0; d]);
        let mut act = |ws: &mut _, hold: &mut EndStopHold| {
            policy.mean_next(&y, &c, ws, &mut next).unwrap();
            policy.velocity(&y, &c, ws, &mut velocity).unwrap();
            policy.act(&y, &c, ws, &mut next, &mut velocity).unwrap();
            policy
                .acceleration(&y, &qd, &c, GAIN, ws, &mut next, &mut velocity)
                .unwrap();
            policy
                .acceleration_held(&y, &qd, &c, GAIN, hold, ws, &mut next, &mut velocity)
                .unwrap();
        };
        act(&mut ws, &mut hold);
        let made = count_allocations(|| {
            for _ in 0..5 {
                act(&mut ws, &mut hold);
            }
        });
        assert_eq!(made, 0, "variant {k}: 25 actions allocated {made} times");
    }
}

/// A joint of the narrow box at its barrier, moving into the limit: the field of a random
/// flow drives it on into the stop from some of these starts, and the hold engages.
fn into_the_stop(joint: usize, upper: bool) -> (Vec<f64>, Vec<f64>) {
    let mut q: Vec<f64> = (0..3)
        .map(|i| 0.5 * (NARROW_MIN[i] + NARROW_MAX[i]))
        .collect();
    let mut qd = vec![0.0; 3];
    (q[joint], qd[joint]) = match upper {
        true => (NARROW_MAX[joint] - BARRIER_MARGIN, 0.2),
        false => (NARROW_MIN[joint] + BARRIER_MARGIN, -0.2),
    };
    (q, qd)
}

#[test]
fn an_engaged_end_stop_hold_allocates_nothing() {
    let config = narrow(AFFINE, 1.0, 10.0);
    let c = [0.3, -0.2];
    let (mut a, mut v) = (vec![0.0; 3], vec![0.0; 3]);
    let mut engaged_periods = 0;
    for seed in 0..40 {
        let policy = Policy::new(&config, tame_weights(&config, 700 + seed)).unwrap();
        let mut ws = policy.workspace();
        let mut hold = EndStopHold::new(3, PERIOD).unwrap();
        for (joint, upper) in (0..3).flat_map(|j| [(j, true), (j, false)]) {
            let (q, qd) = into_the_stop(joint, upper);
            hold.clear();
            let held = |hold: &mut EndStopHold, ws: &mut _, a: &mut [f64], v: &mut [f64]| {
                policy
                    .acceleration_held(&q, &qd, &c, GAIN, hold, ws, a, v)
                    .unwrap();
            };
            held(&mut hold, &mut ws, &mut a, &mut v);
            if !hold.is_engaged() {
                continue;
            }
            let made = count_allocations(|| {
                for _ in 0..5 {
                    held(&mut hold, &mut ws, &mut a, &mut v);
                    engaged_periods += usize::from(hold.is_engaged());
                }
            });
            assert_eq!(
                made, 0,
                "seed {seed}, joint {joint}: 5 held periods allocated {made} times"
            );
        }
    }
    assert!(
        engaged_periods >= 20,
        "only {engaged_periods} periods with the hold engaged"
    );
}

/// Negative control: the counter sees what making a policy's workspace allocates.
#[test]
fn the_counter_sees_a_workspace_made() {
    let config = narrow(AFFINE, 1.0, 10.0);
    let policy = Policy::new(&config, tame_weights(&config, 700)).unwrap();
    let made = count_allocations(|| {
        std::hint::black_box(policy.workspace());
    });
    assert!(made > 0, "making a workspace allocated {made} times");
}
