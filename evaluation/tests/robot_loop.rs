//! The policy driving the computed-torque simulator: without saturation every start inside
//! the joint limits converges (the module docs' claim 1, now through real dynamics and a
//! 1 ms zero-order hold); with the Panda's real torque limits saturation is detected and
//! reported.

// The engine's flow test fixtures, shared rather than copied.
#[path = "../../engine/tests/flow_common/mod.rs"]
mod flow_common;

use ciflow_engine::flow::{FlowConfig, JointRange, LatentKind, Policy, Weights};
use ciflow_engine::math::DVector;
use ciflow_engine::robot::{JointLimits, PointMass2d, panda, panda_limits};
use ciflow_engine::sim::{SimConfig, Simulator};
use ciflow_evaluation::robot_loop::{RobotLoopConfig, RobotPush, measure_robot_loop};
use flow_common::*;

/// A goal-conditioned go-to flow whose targets (the context) lie inside `[lo, hi]` shrunk
/// to its middle half.
fn goal_policy(lo: &[f64], hi: &[f64], seed: u64) -> Policy {
    let config = goal_config(lo, hi);
    Policy::new(&config, goal_weights(&config, seed)).unwrap()
}

fn goal_weights(config: &FlowConfig, seed: u64) -> Weights {
    Weights::random(&config.parameter_shapes(), 0.3, &mut rng(seed))
}

fn goal_config(lo: &[f64], hi: &[f64]) -> FlowConfig {
    let d = lo.len();
    let mut config: FlowConfig = config(d, d, LatentKind::GoTo, SPLINE);
    config.min_rate = 1.0;
    config.goal_context_indices = Some((0..d).collect());
    config.bounds.state_min = lo.to_vec();
    config.bounds.state_max = hi.to_vec();
    config.bounds.context_min = lo.iter().zip(hi).map(|(a, b)| a + 0.25 * (b - a)).collect();
    config.bounds.context_max = lo.iter().zip(hi).map(|(a, b)| b - 0.25 * (b - a)).collect();
    config
}

fn check(starts: usize) -> RobotLoopConfig {
    RobotLoopConfig {
        starts,
        duration: 15.0,
        ..RobotLoopConfig::default()
    }
}

#[test]
fn unsaturated_point_mass_converges_from_everywhere_inside_its_limits() {
    let mut limits = JointLimits::unlimited(2);
    limits.q_min = DVector::from_element(2, -2.0);
    limits.q_max = DVector::from_element(2, 2.0);
    let robot = PointMass2d::new(1.5).unwrap().with_limits(limits).unwrap();
    let mut sim = Simulator::new(Box::new(robot), SimConfig::default()).unwrap();
    let policy = goal_policy(&[-2.0, -2.0], &[2.0, 2.0], 1);
    let report = measure_robot_loop(&policy, &mut sim, &check(8), |_| {}).unwrap();
    assert_eq!(report.saturated, 0, "{report:?}");
    assert_eq!(report.fraction, 1.0, "{report:?}");
}

#[test]
fn panda_converges_without_torque_limits_and_reports_saturation_with_them() {
    let real = panda_limits();
    let (lo, hi): (Vec<f64>, Vec<f64>) = (
        real.q_min.iter().copied().collect(),
        real.q_max.iter().copied().collect(),
    );
    let policy = goal_policy(&lo, &hi, 2);

    let mut unlimited_torque = real.clone();
    unlimited_torque.tau_max = DVector::from_element(7, f64::INFINITY);
    unlimited_torque.tau_rate_max = DVector::from_element(7, f64::INFINITY);
    let mut robot = panda();
    robot.set_limits(unlimited_torque).unwrap();
    let mut sim = Simulator::new(Box::new(robot), SimConfig::default()).unwrap();
    let report = measure_robot_loop(&policy, &mut sim, &check(3), |_| {}).unwrap();
    assert_eq!(report.saturated, 0, "{report:?}");
    assert_eq!(report.fraction, 1.0, "{report:?}");

    let mut sim = Simulator::new(Box::new(panda()), SimConfig::default()).unwrap();
    let aggressive = RobotLoopConfig {
        velocity_gain: 200.0,
        ..check(3)
    };
    let report = measure_robot_loop(&policy, &mut sim, &aggressive, |_| {}).unwrap();
    assert!(report.saturated > 0, "{report:?}");

    // The negative control of the check through the robot (`ciflow stability
    // --robot-loop --negative-control`): the same flow with its latent run backwards
    // drives the arm, within its real limits, and never counts as converged.
    let mut sim = Simulator::new(Box::new(panda()), SimConfig::default()).unwrap();
    let report = measure_robot_loop(&policy.time_reversed(), &mut sim, &check(3), |_| {}).unwrap();
    assert_eq!(report.converged, 0, "{report:?}");
}

#[test]
fn a_joint_range_keeps_the_panda_off_its_end_stops_where_the_same_weights_hit_them() {
    let real = panda_limits();
    let (lo, hi): (Vec<f64>, Vec<f64>) = (
        real.q_min.iter().copied().collect(),
        real.q_max.iter().copied().collect(),
    );
    let mut config = goal_config(&lo, &hi);
    let weights = goal_weights(&config, 3);
    let free = Policy::new(&config, weights.clone()).unwrap();
    config.joint_range = Some(JointRange::from_limits(&real));
    let ranged = Policy::new(&config, weights).unwrap();
    let report = |policy: &Policy, push: Option<RobotPush>| {
        let mut sim = Simulator::new(Box::new(panda()), SimConfig::default()).unwrap();
        let config = RobotLoopConfig { push, ..check(10) };
        measure_robot_loop(policy, &mut sim, &config, |_| {}).unwrap()
    };
    let (with_range, without) = (report(&ranged, None), report(&free, None));
    assert_eq!(with_range.hit_end_stops, 0, "{with_range:?}");
    assert_eq!(with_range.over_speed_steps, 0, "{with_range:?}");
    assert_eq!(with_range.fraction, 1.0, "{with_range:?}");
    assert!(without.hit_end_stops > 0, "{without:?}");
    assert!(without.over_speed_steps > 0, "{without:?}");
    // A 40 N push on the hand of every rollout moves it: more steps, still converging.
    let push = RobotPush {
        force: 40.0,
        at: 1.0,
        duration: 0.2,
    };
    let pushed = report(&ranged, Some(push));
    assert_eq!(pushed.fraction, 1.0, "{pushed:?}");
    assert!(pushed.steps != with_range.steps, "{pushed:?}");
}
