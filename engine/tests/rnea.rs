//! RNEA: inverse dynamics against forward dynamics, CRBA and its special cases.

mod common;

use ciflow_engine::math::DVector;
use ciflow_engine::robot::{DynamicsError, Robot, SerialChain, panda};
use common::*;

#[test]
fn rnea_splits_into_mass_matrix_and_nonlinear_effects() {
    let mut robot = panda();
    let mut rng = rng(2);
    let zero = DVector::zeros(robot.dof());
    for _ in 0..100 {
        let s = random_state(&robot, &mut rng);
        let tau = inverse_dynamics(&mut robot, &s.q, &s.qd, &s.qdd);
        let m = mass_matrix(&mut robot, &s.q);
        let nle = nonlinear_effects(&mut robot, &s.q, &s.qd);
        assert_close(
            tau.as_slice(),
            (&m * &s.qdd + &nle).as_slice(),
            1e-12,
            "τ = M q̈ + b",
        );
        let rnea_no_acceleration = inverse_dynamics(&mut robot, &s.q, &s.qd, &zero);
        assert_close(
            nle.as_slice(),
            rnea_no_acceleration.as_slice(),
            1e-12,
            "b = RNEA(q, q̇, 0)",
        );
        let g = gravity(&mut robot, &s.q);
        let rnea_static = inverse_dynamics(&mut robot, &s.q, &zero, &zero);
        assert_close(
            g.as_slice(),
            rnea_static.as_slice(),
            1e-12,
            "g = RNEA(q, 0, 0)",
        );
    }
}

#[test]
fn gravity_is_the_gradient_of_potential_energy() {
    // g(q) = ∂V/∂q: a central difference of V along a random direction checks the
    // magnitude and sign convention of gravity.
    let mut robot = panda();
    let chain = panda();
    let mut rng = rng(3);
    for _ in 0..20 {
        let s = random_state(&robot, &mut rng);
        let g = gravity(&mut robot, &s.q);
        let eps = 1e-6;
        let dv = (potential_energy(&chain, &(&s.q + &s.qd * eps))
            - potential_energy(&chain, &(&s.q - &s.qd * eps)))
            / (2.0 * eps);
        assert!(
            (dv - g.dot(&s.qd)).abs() < 1e-6 * (1.0 + dv.abs()),
            "dV = {dv}, gᵀ dq = {}",
            g.dot(&s.qd)
        );
    }
}

/// `V(q) = Σ mᵢ 9.81 zᵢ` from the bodies' centres of mass.
fn potential_energy(chain: &SerialChain, q: &DVector) -> f64 {
    chain
        .model()
        .bodies()
        .iter()
        .enumerate()
        .map(|(i, body)| {
            let placement = chain.frame_placement(q.as_slice(), i + 1).unwrap();
            let com = placement * nalgebra::Point3::from(body.inertia.com());
            body.inertia.mass * 9.81 * com.z
        })
        .sum()
}

#[test]
fn bad_input_is_a_typed_error() {
    let mut robot = panda();
    let n = robot.dof();
    let mut tau = DVector::zeros(n);
    let good = vec![0.1; n];
    assert_eq!(
        robot.inverse_dynamics(&good[..6], &good, &good, &mut tau),
        Err(DynamicsError::Dimension {
            quantity: "q",
            expected: 7,
            actual: 6
        })
    );
    let mut nan = good.clone();
    nan[3] = f64::NAN;
    assert_eq!(
        robot.inverse_dynamics(&good, &nan, &good, &mut tau),
        Err(DynamicsError::NonFinite {
            quantity: "qd",
            index: 3
        })
    );
    let mut inf = good.clone();
    inf[0] = f64::INFINITY;
    assert!(matches!(
        robot.inverse_dynamics(&good, &good, &inf, &mut tau),
        Err(DynamicsError::NonFinite {
            quantity: "qdd",
            index: 0
        })
    ));
    let mut short = DVector::zeros(n - 1);
    assert!(matches!(
        robot.inverse_dynamics(&good, &good, &good, &mut short),
        Err(DynamicsError::Dimension {
            quantity: "tau",
            ..
        })
    ));
}
