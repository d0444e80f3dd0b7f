//! Helpers shared by the dynamics tests: seeded random states and tolerant comparisons.
#![allow(dead_code)]

use ciflow_engine::math::{DMatrix, DVector, Real};
use ciflow_engine::robot::{LockedJoint, PANDA_ARMATURE, Robot, UrdfOptions};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The Panda with its gripper, relative to the engine crate.
pub const PANDA_GRIPPER_URDF: &str = "tests/assets/panda_gripper.urdf";

/// [`PANDA_GRIPPER_URDF`] as an 8-joint chain ending in the left finger (prismatic), the
/// right one locked at 2 cm, as Pinocchio's `buildReducedModel` would lock it.
pub fn panda_finger_options() -> UrdfOptions {
    UrdfOptions {
        locked: vec![LockedJoint {
            name: "panda_finger_joint2".into(),
            position: 0.02,
        }],
        tool: Some("panda_leftfinger".into()),
        armature: Some([PANDA_ARMATURE.as_slice(), &[0.01]].concat()),
    }
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A random state within the robot's limits (unbounded quantities in `[-1, 1]`).
pub struct State {
    pub q: DVector,
    pub qd: DVector,
    pub qdd: DVector,
}

pub fn random_state(robot: &dyn Robot, rng: &mut ChaCha8Rng) -> State {
    let limits = robot.limits();
    let n = robot.dof();
    let q = DVector::from_fn(n, |i, _| {
        let (min, max) = match (limits.q_min[i].is_finite(), limits.q_max[i].is_finite()) {
            (true, true) => (limits.q_min[i], limits.q_max[i]),
            (true, false) => (limits.q_min[i], limits.q_min[i] + 2.0),
            (false, true) => (limits.q_max[i] - 2.0, limits.q_max[i]),
            (false, false) => (-1.0, 1.0),
        };
        rng.random_range(min..=max)
    });
    let symmetric = |rng: &mut ChaCha8Rng, max: &DVector| {
        DVector::from_fn(n, |i, _| {
            let bound = if max[i].is_finite() { max[i] } else { 1.0 };
            rng.random_range(-bound..=bound)
        })
    };
    let qd = symmetric(rng, &limits.qd_max);
    let qdd = symmetric(rng, &limits.qdd_max);
    State { q, qd, qdd }
}

/// `max |a − b| ≤ tol (1 + max |b|)` over all entries.
pub fn assert_close(actual: &[Real], expected: &[Real], tol: Real, what: &str) {
    assert_eq!(actual.len(), expected.len(), "{what}: length");
    let scale = 1.0 + expected.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    let error = actual
        .iter()
        .zip(expected)
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        error <= tol * scale,
        "{what}: max error {error:e} > {tol:e} × {scale}\nactual   {actual:?}\nexpected {expected:?}"
    );
}

pub fn assert_matrix_close(actual: &DMatrix, expected: &DMatrix, tol: Real, what: &str) {
    assert_eq!(actual.shape(), expected.shape(), "{what}: shape");
    assert_close(actual.as_slice(), expected.as_slice(), tol, what);
}

/// `M(q)` of a robot, allocated (tests only).
pub fn mass_matrix(robot: &mut dyn Robot, q: &DVector) -> DMatrix {
    let mut m = DMatrix::zeros(robot.dof(), robot.dof());
    robot.mass_matrix(q.as_slice(), &mut m).unwrap();
    m
}

pub fn inverse_dynamics(
    robot: &mut dyn Robot,
    q: &DVector,
    qd: &DVector,
    qdd: &DVector,
) -> DVector {
    let mut tau = DVector::zeros(robot.dof());
    robot
        .inverse_dynamics(q.as_slice(), qd.as_slice(), qdd.as_slice(), &mut tau)
        .unwrap();
    tau
}

pub fn forward_dynamics(
    robot: &mut dyn Robot,
    q: &DVector,
    qd: &DVector,
    tau: &DVector,
) -> DVector {
    let mut qdd = DVector::zeros(robot.dof());
    robot
        .forward_dynamics(q.as_slice(), qd.as_slice(), tau.as_slice(), &mut qdd)
        .unwrap();
    qdd
}

pub fn gravity(robot: &mut dyn Robot, q: &DVector) -> DVector {
    let mut g = DVector::zeros(robot.dof());
    robot.gravity(q.as_slice(), &mut g).unwrap();
    g
}

pub fn nonlinear_effects(robot: &mut dyn Robot, q: &DVector, qd: &DVector) -> DVector {
    let mut nle = DVector::zeros(robot.dof());
    robot
        .nonlinear_effects(q.as_slice(), qd.as_slice(), &mut nle)
        .unwrap();
    nle
}

pub fn coriolis(robot: &mut dyn Robot, q: &DVector, qd: &DVector) -> DMatrix {
    let mut c = DMatrix::zeros(robot.dof(), robot.dof());
    robot
        .coriolis_matrix(q.as_slice(), qd.as_slice(), &mut c)
        .unwrap();
    c
}
