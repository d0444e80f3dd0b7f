//! Forward dynamics: the inverse of RNEA, and `q̈ = M⁻¹ (τ − b)`.

mod common;

use ciflow_engine::math::DVector;
use ciflow_engine::robot::{DynamicsError, Robot, panda};
use common::*;

#[test]
fn forward_dynamics_of_rnea_returns_qdd() {
    let mut robot = panda();
    let mut rng = rng(1);
    for _ in 0..200 {
        let s = random_state(&robot, &mut rng);
        let tau = inverse_dynamics(&mut robot, &s.q, &s.qd, &s.qdd);
        let qdd = forward_dynamics(&mut robot, &s.q, &s.qd, &tau);
        assert_close(qdd.as_slice(), s.qdd.as_slice(), 1e-10, "FD(RNEA(q, q̇, q̈))");
    }
}

#[test]
fn forward_dynamics_solves_the_equation_of_motion() {
    let mut robot = panda();
    let mut rng = rng(2);
    for _ in 0..50 {
        let s = random_state(&robot, &mut rng);
        let tau = &s.qdd * 10.0;
        let qdd = forward_dynamics(&mut robot, &s.q, &s.qd, &tau);
        let m = mass_matrix(&mut robot, &s.q);
        let b = nonlinear_effects(&mut robot, &s.q, &s.qd);
        assert_close(
            (&m * &qdd).as_slice(),
            (&tau - &b).as_slice(),
            1e-11,
            "M q̈ = τ − b",
        );
    }
}

#[test]
fn forward_dynamics_rejects_bad_torque() {
    let mut robot = panda();
    let mut qdd = DVector::zeros(7);
    let tau = [0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(
        robot.forward_dynamics(&[0.0; 7], &[0.0; 7], &tau, &mut qdd),
        Err(DynamicsError::NonFinite {
            quantity: "tau",
            index: 2
        })
    );
    assert!(matches!(
        robot.forward_dynamics(&[0.0; 7], &[0.0; 7], &[0.0; 8], &mut qdd),
        Err(DynamicsError::Dimension {
            quantity: "tau",
            expected: 7,
            actual: 8
        })
    ));
}
