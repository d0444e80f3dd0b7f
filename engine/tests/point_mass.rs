//! The planar point mass behind the `Robot` trait.

mod common;

use ciflow_engine::math::{DMatrix, DVector, Vector3};
use ciflow_engine::model::{JointLimits, ModelError};
use ciflow_engine::robot::{DynamicsError, PointMass2d, Robot};
use common::*;

#[test]
fn point_mass_obeys_newton() {
    let mut robot = PointMass2d::new(2.5).unwrap();
    let mut rng = rng(50);
    for _ in 0..20 {
        let s = random_state(&robot, &mut rng);
        let m = mass_matrix(&mut robot, &s.q);
        assert_matrix_close(&m, &(DMatrix::identity(2, 2) * 2.5), 0.0, "M = m 1");
        assert_eq!(gravity(&mut robot, &s.q), DVector::zeros(2));
        assert_eq!(coriolis(&mut robot, &s.q, &s.qd), DMatrix::zeros(2, 2));
        assert_eq!(
            nonlinear_effects(&mut robot, &s.q, &s.qd),
            DVector::zeros(2)
        );
        let tau = inverse_dynamics(&mut robot, &s.q, &s.qd, &s.qdd);
        assert_close(tau.as_slice(), (&s.qdd * 2.5).as_slice(), 1e-15, "τ = m q̈");
        let qdd = forward_dynamics(&mut robot, &s.q, &s.qd, &tau);
        assert_close(qdd.as_slice(), s.qdd.as_slice(), 1e-15, "FD ∘ ID");
    }
}

#[test]
fn point_mass_kinematics_and_wrench() {
    let robot = PointMass2d::new(1.0).unwrap();
    let mass = robot.end_effector();
    assert_eq!(robot.frames()[mass].name, "mass");
    let q = [0.3, -0.7];
    let placement = robot.frame_placement(&q, mass).unwrap();
    assert_eq!(placement.translation.vector, Vector3::new(0.3, -0.7, 0.0));
    let mut jacobian = DMatrix::zeros(6, 2);
    robot
        .frame_jacobian(&q, mass, &Vector3::zeros(), &mut jacobian)
        .unwrap();
    let mut tau = DVector::zeros(2);
    let (force, torque) = (Vector3::new(1.5, -2.0, 9.0), Vector3::new(0.0, 0.0, 4.0));
    robot
        .wrench_to_joint_torque(&q, 0, &force, &torque, &mut tau)
        .unwrap();
    let wrench = DVector::from_iterator(6, force.iter().chain(torque.iter()).copied());
    assert_eq!(
        tau,
        jacobian.transpose() * wrench,
        "τ = Jᵀ w: the in-plane force"
    );
    assert_eq!(tau, DVector::from_row_slice(&[1.5, -2.0]));
}

#[test]
fn point_mass_rejects_bad_input() {
    assert!(matches!(
        PointMass2d::new(0.0),
        Err(ModelError::InvalidInertia { .. })
    ));
    assert!(matches!(
        PointMass2d::new(f64::NAN),
        Err(ModelError::InvalidInertia { .. })
    ));
    let mut limits = JointLimits::unlimited(2);
    limits.q_min[0] = 1.0;
    limits.q_max[0] = -1.0;
    assert!(matches!(
        PointMass2d::new(1.0).unwrap().with_limits(limits),
        Err(ModelError::InvalidLimits {
            what: "q_min",
            joint: 0,
            ..
        })
    ));
    let mut robot = PointMass2d::new(1.0).unwrap();
    let mut qdd = DVector::zeros(2);
    assert_eq!(
        robot.forward_dynamics(&[0.0; 3], &[0.0; 2], &[0.0; 2], &mut qdd),
        Err(DynamicsError::Dimension {
            quantity: "q",
            expected: 2,
            actual: 3
        })
    );
    let mut tau = DVector::zeros(2);
    assert_eq!(
        robot.wrench_to_joint_torque(&[0.0; 2], 1, &Vector3::x(), &Vector3::zeros(), &mut tau),
        Err(DynamicsError::NoSuchLink { index: 1, count: 1 })
    );
}

/// Point masses without limits read one shared (infinite) set; limits given to one are
/// its own.
#[test]
fn unlimited_point_masses_share_their_limits() {
    let (a, b) = (
        PointMass2d::new(1.0).unwrap(),
        PointMass2d::new(2.0).unwrap(),
    );
    assert!(std::ptr::eq(a.limits(), b.limits()));
    assert_eq!(*a.limits(), JointLimits::unlimited(2));
    let mut limits = JointLimits::unlimited(2);
    limits.q_max = DVector::from_element(2, 1.0);
    let limited = PointMass2d::new(1.0)
        .unwrap()
        .with_limits(limits.clone())
        .unwrap();
    assert!(!std::ptr::eq(a.limits(), limited.limits()));
    assert_eq!(*limited.limits(), limits);
    assert_eq!(*a.limits(), JointLimits::unlimited(2));
}
