//! Forward dynamics: the inverse of RNEA, and `q̈ = M⁻¹ (τ − b)`.

mod common;

use ciflow_engine::math::DVector;
use ciflow_engine::robot::{DynamicsError, Robot, SerialChain, panda};
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

/// A joint whose link is a point mass on its own axis (mass, no rotational inertia, nothing
/// after it) gives a singular `M(q)`: refused, naming that joint.
#[test]
fn forward_dynamics_names_the_joint_that_moves_nothing() {
    let urdf = r#"<robot name="r"><link name="base"/>
        <link name="a"><inertial><origin xyz="0.3 0 0"/><mass value="1"/>
            <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
        <link name="b"><inertial><origin xyz="0 0 0"/><mass value="2"/>
            <inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/></inertial></link>
        <joint name="j0" type="revolute"><parent link="base"/><child link="a"/>
            <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
        <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
            <origin xyz="0.6 0 0"/><axis xyz="0 0 1"/>
            <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
        </robot>"#;
    let mut robot = SerialChain::from_urdf_str(urdf).unwrap();
    let mut qdd = DVector::zeros(2);
    assert_eq!(
        robot.forward_dynamics(&[0.1, 0.2], &[0.0; 2], &[0.0; 2], &mut qdd),
        Err(DynamicsError::NotPositiveDefinite { joint: 1 })
    );
    // The same link with rotational inertia about the axis moves.
    let turning = urdf.replace(
        r#"ixx="0" iyy="0" izz="0""#,
        r#"ixx="0" iyy="0" izz="0.02""#,
    );
    let mut robot = SerialChain::from_urdf_str(&turning).unwrap();
    robot
        .forward_dynamics(&[0.1, 0.2], &[0.0; 2], &[0.0; 2], &mut qdd)
        .unwrap();
}
