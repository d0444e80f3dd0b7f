//! CRBA: the mass matrix is symmetric positive definite and matches RNEA column by column.

mod common;

use ciflow_engine::math::{DMatrix, DVector};
use ciflow_engine::robot::{DynamicsError, Robot, SerialChain, panda};
use common::*;

#[test]
fn mass_matrix_is_symmetric_positive_definite() {
    let mut robot = panda();
    let mut rng = rng(10);
    for _ in 0..200 {
        let s = random_state(&robot, &mut rng);
        let m = mass_matrix(&mut robot, &s.q);
        assert_matrix_close(&m, &m.transpose(), 1e-14, "M = Mᵀ");
        let eigenvalues = m.symmetric_eigenvalues();
        assert!(
            eigenvalues.min() > 1e-4,
            "M not positive definite: {eigenvalues}"
        );
    }
}

/// Both forms of the CRBA against the RNEA: the Panda's joints turn about their z axes
/// and its placements are axis-aligned (joint frames); the Panda with a prismatic finger
/// is not (world coordinates).
#[test]
fn mass_matrix_columns_are_rnea_of_unit_accelerations() {
    let finger = SerialChain::from_urdf_file(PANDA_GRIPPER_URDF, &panda_finger_options()).unwrap();
    for (mut robot, in_joint_frames) in [(panda(), true), (finger, false)] {
        assert_eq!(
            robot.model().axis_aligned_placements().is_some(),
            in_joint_frames
        );
        let n = robot.dof();
        let mut rng = rng(11);
        let zero = DVector::zeros(n);
        for _ in 0..50 {
            let s = random_state(&robot, &mut rng);
            let m = mass_matrix(&mut robot, &s.q);
            let g = gravity(&mut robot, &s.q);
            for j in 0..n {
                let column = inverse_dynamics(
                    &mut robot,
                    &s.q,
                    &zero,
                    &DVector::from_fn(n, |i, _| (i == j) as u8 as f64),
                ) - &g;
                assert_close(
                    m.column(j).as_slice(),
                    column.as_slice(),
                    1e-12,
                    "M eⱼ = RNEA(q, 0, eⱼ) − g",
                );
            }
        }
    }
}

#[test]
fn kinetic_energy_matches_the_sum_over_bodies() {
    // ½ q̇ᵀ M q̇ equals Σ ½ mᵢ |v_cᵢ|² + ½ ωᵢᵀ I_cᵢ ωᵢ from Jacobians at the centres of mass.
    let mut robot = panda();
    let chain = panda();
    let n = robot.dof();
    let mut rng = rng(12);
    let mut jacobian = DMatrix::zeros(6, n);
    for _ in 0..20 {
        let s = random_state(&robot, &mut rng);
        let m = mass_matrix(&mut robot, &s.q);
        let expected = 0.5 * s.qd.dot(&(&m * &s.qd));
        let mut energy = 0.0;
        for (i, body) in chain.model().bodies().iter().enumerate() {
            let frame = i + 1;
            robot
                .frame_jacobian(s.q.as_slice(), frame, &body.inertia.com(), &mut jacobian)
                .unwrap();
            let twist = &jacobian * &s.qd;
            let v = twist.fixed_rows::<3>(0);
            let w = twist.fixed_rows::<3>(3);
            let rotation = robot
                .frame_placement(s.q.as_slice(), frame)
                .unwrap()
                .rotation;
            let inertia_world = rotation.to_rotation_matrix()
                * body.inertia.inertia_com()
                * rotation.to_rotation_matrix().transpose();
            energy +=
                0.5 * body.inertia.mass * v.norm_squared() + 0.5 * w.dot(&(inertia_world * w));
        }
        // The rotors turn with their joints: ½ Σ I_a q̇².
        energy += 0.5
            * chain
                .model()
                .armature()
                .iter()
                .zip(s.qd.iter())
                .map(|(a, v)| a * v * v)
                .sum::<f64>();
        assert!(
            (energy - expected).abs() < 1e-10 * (1.0 + expected),
            "{energy} vs {expected}"
        );
    }
}

#[test]
fn wrong_buffer_shape_is_a_typed_error() {
    let mut robot = panda();
    let mut m = DMatrix::zeros(6, 7);
    assert!(matches!(
        robot.mass_matrix(&[0.0; 7], &mut m),
        Err(DynamicsError::Shape { quantity: "m", .. })
    ));
}
