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

/// A chain in joint frames whose every joint sits off its parent's axis in x and y (the
/// Panda, UR5e and iiwa place their second joint on the first one's axis).
const OFFSET_CHAIN_URDF: &str = r#"<robot name="offsets"><link name="base"/>
    <link name="a"><inertial><origin xyz="0.1 -0.05 0.2"/><mass value="3"/>
        <inertia ixx="0.05" iyy="0.04" izz="0.03" ixy="0.001" ixz="-0.002" iyz="0.003"/></inertial></link>
    <link name="b"><inertial><origin xyz="-0.2 0.1 0.05"/><mass value="2"/>
        <inertia ixx="0.02" iyy="0.03" izz="0.01" ixy="-0.001" ixz="0.001" iyz="0.002"/></inertial></link>
    <link name="c"><inertial><origin xyz="0.05 0.15 -0.1"/><mass value="1"/>
        <inertia ixx="0.01" iyy="0.02" izz="0.015" ixy="0.0005" ixz="0" iyz="-0.001"/></inertial></link>
    <joint name="j0" type="revolute"><parent link="base"/><child link="a"/>
        <origin xyz="0.1 0.2 0.3"/><axis xyz="0 0 1"/>
        <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
    <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
        <origin xyz="0.3 -0.2 0.1" rpy="1.5707963267948966 0 0"/><axis xyz="0 0 1"/>
        <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
    <joint name="j2" type="revolute"><parent link="b"/><child link="c"/>
        <origin xyz="-0.25 0.15 0.05" rpy="0 -1.5707963267948966 0"/><axis xyz="0 0 1"/>
        <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
    </robot>"#;

/// Both forms of the CRBA against the RNEA: the Panda's joints turn about their z axes
/// and its placements are axis-aligned (joint frames), as do the offset chain's; the Panda
/// with a prismatic finger is not (world coordinates).
#[test]
fn mass_matrix_columns_are_rnea_of_unit_accelerations() {
    let finger = SerialChain::from_urdf_file(PANDA_GRIPPER_URDF, &panda_finger_options()).unwrap();
    let offsets = SerialChain::from_urdf_str(OFFSET_CHAIN_URDF).unwrap();
    for (mut robot, in_joint_frames) in [(panda(), true), (offsets, true), (finger, false)] {
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
