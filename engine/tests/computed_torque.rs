//! The computed-torque layer in closed loop: exact without active limits, and what it
//! guarantees with them.

mod common;

use ciflow_engine::control::{ComputedTorque, ControlError};
use ciflow_engine::math::{DVector, Real, Vector3};
use ciflow_engine::model::JointLimits;
use ciflow_engine::robot::{PANDA_HOME, Robot, SerialChain, panda};
use ciflow_engine::sim::{Perturbation, PerturbationKind, SimConfig, Simulator};
use common::*;
use rand::RngExt;

const DT: Real = 1e-3;

fn panda_without_torque_limits() -> SerialChain {
    let mut robot = panda();
    let limits = JointLimits {
        tau_max: DVector::from_element(7, Real::INFINITY),
        tau_rate_max: DVector::from_element(7, Real::INFINITY),
        ..robot.limits().clone()
    };
    robot.set_limits(limits).unwrap();
    robot
}

/// The acceleration realised over one semi-implicit Euler step: `(q̇₁ − q̇₀) / h`.
fn realised_acceleration(
    sim: &mut Simulator,
    qdd_desired: &DVector,
) -> (DVector, ciflow_engine::sim::StepReport) {
    let qd0 = sim.qd().clone();
    let report = sim.step(qdd_desired.as_slice()).unwrap();
    ((sim.qd() - qd0) / DT, report)
}

#[test]
fn without_limits_the_closed_loop_adds_m_inverse_external_torque() {
    let mut model = panda_without_torque_limits();
    let mut sim = Simulator::new(Box::new(model.clone()), SimConfig::default()).unwrap();
    let mut rng = rng(60);
    for trial in 0..50 {
        let s = random_state(&model, &mut rng);
        sim.reset(s.q.as_slice(), s.qd.as_slice()).unwrap();
        let tau_ext = DVector::from_fn(7, |_, _| rng.random_range(-5.0..5.0));
        let (force, torque) = (Vector3::new(10.0, -4.0, 7.0), Vector3::new(0.5, -1.0, 0.2));
        let kind = if trial % 2 == 0 {
            PerturbationKind::JointTorque(tau_ext.as_slice().to_vec())
        } else {
            PerturbationKind::LinkWrench {
                link: 5,
                force: force.into(),
                torque: torque.into(),
            }
        };
        let mut expected_ext = tau_ext.clone();
        if trial % 2 == 1 {
            model
                .wrench_to_joint_torque(s.q.as_slice(), 5, &force, &torque, &mut expected_ext)
                .unwrap();
        }
        sim.perturb(Perturbation {
            kind,
            start: 0.0,
            duration: 1.0,
        })
        .unwrap();
        let (qdd, report) = realised_acceleration(&mut sim, &s.qdd);
        assert!(!report.saturation.is_active() && report.end_stops.is_empty());
        let m_inv_ext = forward_dynamics(&mut model, &s.q, &DVector::zeros(7), &expected_ext)
            - forward_dynamics(&mut model, &s.q, &DVector::zeros(7), &DVector::zeros(7));
        assert_close(
            qdd.as_slice(),
            (&s.qdd + m_inv_ext).as_slice(),
            1e-8,
            "q̈ = q̈_des + M⁻¹ τ_ext",
        );
    }
}

#[test]
fn with_limits_torque_stays_bounded_and_the_dynamics_use_the_applied_torque() {
    let mut model = panda();
    let limits = model.limits().clone();
    let mut sim = Simulator::new(Box::new(model.clone()), SimConfig::default()).unwrap();
    sim.reset(&PANDA_HOME, &[0.0; 7]).unwrap();
    let tau_ext = DVector::from_row_slice(&[3.0, -2.0, 1.0, 4.0, -0.5, 0.3, 0.1]);
    sim.perturb(Perturbation {
        kind: PerturbationKind::JointTorque(tau_ext.as_slice().to_vec()),
        start: 0.0,
        duration: f64::INFINITY,
    })
    .unwrap();
    let mut rng = rng(61);
    let mut previous = gravity(&mut model, &DVector::from_row_slice(&PANDA_HOME));
    let (mut clipped, mut rate_limited) = (0, 0);
    let mut qdd_desired = DVector::zeros(7);
    for step in 0..300 {
        // Blocks of 50 steps pushing hard in random directions, so that the torque ramps
        // into the clipping bound at the rate limit.
        if step % 50 == 0 {
            qdd_desired = DVector::from_fn(7, |i, _| {
                let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                20.0 * sign * limits.qdd_max[i]
            });
        }
        let (q, qd) = (sim.q().clone(), sim.qd().clone());
        let (qdd, report) = realised_acceleration(&mut sim, &qdd_desired);
        let requested = sim.controller().requested();
        for i in 0..7 {
            assert!(
                sim.controller().command()[i].abs() <= limits.tau_max[i],
                "|τ| ≤ τ_max"
            );
            assert!(
                (sim.controller().command()[i] - previous[i]).abs()
                    <= limits.tau_rate_max[i] * DT + 1e-9,
                "|τ̇| ≤ τ̇_max"
            );
            assert_eq!(
                report.saturation.clipped.contains(i),
                requested[i].abs() > limits.tau_max[i]
            );
        }
        clipped += report.saturation.clipped.len();
        rate_limited += report.saturation.rate_limited.len();
        previous = sim.controller().command().clone();
        if report.end_stops.is_empty() {
            let expected = forward_dynamics(
                &mut model,
                &q,
                &qd,
                &(sim.controller().command() + &tau_ext),
            );
            assert_close(
                qdd.as_slice(),
                expected.as_slice(),
                1e-8,
                "q̈ = M⁻¹ (τ_sat − C q̇ − g + τ_ext)",
            );
        }
    }
    assert!(
        clipped > 0 && rate_limited > 0,
        "the test exercised both limits ({clipped}, {rate_limited})"
    );
}

#[test]
fn rate_limiter_starts_from_gravity_at_reset() {
    let mut model = panda();
    let mut sim = Simulator::new(Box::new(model.clone()), SimConfig::default()).unwrap();
    sim.reset(&PANDA_HOME, &[0.0; 7]).unwrap();
    let g = gravity(&mut model, &DVector::from_row_slice(&PANDA_HOME));
    let report = sim.step(&[0.0; 7]).unwrap();
    assert!(
        !report.saturation.is_active(),
        "holding still needs exactly g(q₀)"
    );
    assert_close(
        sim.controller().command().as_slice(),
        g.as_slice(),
        1e-12,
        "τ = g(q₀)",
    );
    sim.reset(&PANDA_HOME, &[0.0; 7]).unwrap();
    let report = sim
        .step(&[10.0, -10.0, 10.0, -10.0, 10.0, -10.0, 10.0])
        .unwrap();
    let requested = sim.controller().requested();
    let max_step = 1000.0 * DT;
    for i in 0..7 {
        let change = requested[i] - g[i];
        let expected = g[i] + change.clamp(-max_step, max_step);
        assert!(
            (sim.controller().command()[i] - expected).abs() < 1e-12,
            "joint {i}: at most one rate step from g(q₀)"
        );
        assert_eq!(
            report.saturation.rate_limited.contains(i),
            change.abs() > max_step
        );
    }
    assert!(!report.saturation.rate_limited.is_empty());
}

#[test]
fn invalid_period_is_a_typed_error() {
    assert!(matches!(
        ComputedTorque::new(7, 0.0),
        Err(ControlError::InvalidPeriod(_))
    ));
    assert!(matches!(
        ComputedTorque::new(7, f64::NAN),
        Err(ControlError::InvalidPeriod(_))
    ));
    assert!(matches!(
        ComputedTorque::new(65, 1e-3),
        Err(ControlError::TooManyJoints { dof: 65 })
    ));
}
