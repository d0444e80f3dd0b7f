//! Coriolis matrix: C(q, 0) = 0, C q̇ = RNEA(q, q̇, 0) − g, and Ṁ = C + Cᵀ.

mod common;

use ciflow_engine::math::DVector;
use ciflow_engine::robot::{Robot, panda};
use common::*;

#[test]
fn coriolis_vanishes_at_rest() {
    let mut robot = panda();
    let mut rng = rng(20);
    let zero = DVector::zeros(robot.dof());
    for _ in 0..50 {
        let s = random_state(&robot, &mut rng);
        let c = coriolis(&mut robot, &s.q, &zero);
        assert_eq!(c.amax(), 0.0, "C(q, 0) = 0");
    }
}

#[test]
fn coriolis_times_velocity_is_rnea_without_gravity() {
    let mut robot = panda();
    let mut rng = rng(21);
    for _ in 0..200 {
        let s = random_state(&robot, &mut rng);
        let c = coriolis(&mut robot, &s.q, &s.qd);
        let expected = nonlinear_effects(&mut robot, &s.q, &s.qd) - gravity(&mut robot, &s.q);
        assert_close((&c * &s.qd).as_slice(), expected.as_slice(), 1e-12, "C q̇");
    }
}

#[test]
fn mass_matrix_derivative_is_c_plus_c_transpose() {
    let mut robot = panda();
    let mut rng = rng(22);
    let eps = 1e-6;
    for _ in 0..50 {
        let s = random_state(&robot, &mut rng);
        let m_plus = mass_matrix(&mut robot, &(&s.q + &s.qd * eps));
        let m_minus = mass_matrix(&mut robot, &(&s.q - &s.qd * eps));
        let m_dot = (m_plus - m_minus) / (2.0 * eps);
        let c = coriolis(&mut robot, &s.q, &s.qd);
        assert_matrix_close(&(&c + c.transpose()), &m_dot, 1e-8, "Ṁ = C + Cᵀ");
        // Equivalently Ṁ − 2C is skew-symmetric.
        let n = &m_dot - &c * 2.0;
        assert_matrix_close(&n, &(-n.transpose()), 1e-8, "Ṁ − 2C skew");
    }
}
