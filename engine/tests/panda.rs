//! The shipped Panda URDF and the modified-DH construction describe the same robot.

mod common;

use ciflow_engine::math::{DMatrix, DVector};
use ciflow_engine::model::Model;
use ciflow_engine::robot::{PANDA_ARMATURE, PANDA_HOME, Robot, panda, panda_from_dh, panda_limits};
use common::*;

#[test]
fn urdf_and_dh_construction_agree() {
    let mut from_urdf = panda();
    let mut from_dh = panda_from_dh().unwrap();
    let names = |robot: &dyn Robot| {
        robot
            .frames()
            .iter()
            .map(|f| f.name.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(names(&from_urdf), names(&from_dh));
    assert_eq!(from_urdf.frames()[0].name, "panda_link0");
    assert_eq!(from_urdf.frames().len(), 10, "base, 7 links, flange, hand");
    let mut rng = rng(40);
    for _ in 0..20 {
        let s = random_state(&from_urdf, &mut rng);
        for frame in 0..from_urdf.frames().len() {
            let a = from_urdf.frame_placement(s.q.as_slice(), frame).unwrap();
            let b = from_dh.frame_placement(s.q.as_slice(), frame).unwrap();
            assert!(
                (a.translation.vector - b.translation.vector).norm() < 1e-12
                    && a.rotation.angle_to(&b.rotation) < 1e-9,
                "frame {frame}"
            );
        }
        assert_matrix_close(
            &mass_matrix(&mut from_urdf, &s.q),
            &mass_matrix(&mut from_dh, &s.q),
            1e-12,
            "M",
        );
        let tau = inverse_dynamics(&mut from_urdf, &s.q, &s.qd, &s.qdd);
        assert_close(
            tau.as_slice(),
            inverse_dynamics(&mut from_dh, &s.q, &s.qd, &s.qdd).as_slice(),
            1e-12,
            "τ",
        );
    }
}

#[test]
fn limits_come_from_the_reference_data() {
    let robot = panda();
    let limits = robot.limits();
    assert_eq!(limits, &panda_limits());
    assert_eq!(limits.tau_max[0], 87.0);
    assert_eq!(limits.tau_max[6], 12.0);
    assert_eq!(limits.tau_rate_max[3], 1000.0);
    let home_inside = PANDA_HOME
        .iter()
        .enumerate()
        .all(|(i, &q)| limits.q_min[i] <= q && q <= limits.q_max[i]);
    assert!(home_inside, "the home posture lies within the limits");
}

#[test]
fn armature_adds_the_reflected_rotor_inertia_to_the_joints() {
    let mut robot = panda();
    let mut bare = panda();
    bare.set_armature(DVector::zeros(7)).unwrap();
    assert_eq!(robot.model().armature().as_slice(), &PANDA_ARMATURE);
    let mut rng = rng(41);
    for _ in 0..10 {
        let s = random_state(&robot, &mut rng);
        let armature = DMatrix::from_diagonal(&DVector::from_row_slice(&PANDA_ARMATURE));
        assert_matrix_close(
            &mass_matrix(&mut robot, &s.q),
            &(mass_matrix(&mut bare, &s.q) + &armature),
            1e-12,
            "M = M_links + diag(I_a)",
        );
        let expected = inverse_dynamics(&mut bare, &s.q, &s.qd, &s.qdd) + &armature * &s.qdd;
        assert_close(
            inverse_dynamics(&mut robot, &s.q, &s.qd, &s.qdd).as_slice(),
            expected.as_slice(),
            1e-9,
            "τ = τ_links + I_a ⊙ q̈",
        );
    }
    for bad in [
        DVector::zeros(6),
        DVector::from_element(7, -0.1),
        DVector::from_element(7, f64::NAN),
    ] {
        assert!(bare.set_armature(bad).is_err());
    }
}

#[test]
fn hand_mass_is_lumped_into_link_7() {
    let total = |model: &Model| model.bodies().iter().map(|b| b.inertia.mass).sum::<f64>();
    let expected =
        4.970684 + 0.646926 + 3.228604 + 3.587895 + 1.225946 + 1.666555 + 0.735522 + 0.73;
    assert!((total(panda().model()) - expected).abs() < 1e-12);
}

/// Thousands of environments hold a Panda each: they share one model and own only their
/// workspace, and changing one arm's model copies it instead of changing the others.
#[test]
fn pandas_share_one_model_until_one_is_changed() {
    let (first, mut second) = (panda(), panda());
    assert!(std::ptr::eq(first.model(), second.model()));
    second
        .set_gravity(ciflow_engine::math::Vector3::new(0.0, 0.0, -1.62))
        .unwrap();
    assert!(!std::ptr::eq(first.model(), second.model()));
    assert_eq!(
        first.model(),
        panda().model(),
        "the shared model is untouched"
    );
    let mut rng = rng(41);
    let s = random_state(&first, &mut rng);
    let (mut earth, mut moon) = (DVector::zeros(7), DVector::zeros(7));
    let mut first = first;
    first.gravity(s.q.as_slice(), &mut earth).unwrap();
    second.gravity(s.q.as_slice(), &mut moon).unwrap();
    assert!((earth * (1.62 / 9.81) - moon).amax() < 1e-9);
}
