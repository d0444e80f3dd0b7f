//! Forward kinematics, frame Jacobians and wrench mapping.

mod common;

use ciflow_engine::math::{DMatrix, DVector, Vector3};
use ciflow_engine::robot::{DynamicsError, Robot, panda};
use common::*;
use nalgebra::Point3;

#[test]
fn flange_at_zero_posture_sums_the_dh_offsets() {
    // At q = 0 the Panda stands upright: x = a₄ + a₆ (0.0825 − 0.0825 + 0.088),
    // z = d₁ + d₃ + d₅ − d_F (the flange points down after the last two α = π/2).
    let robot = panda();
    let flange = robot.frame_index("panda_link8").unwrap();
    let placement = robot.frame_placement(&[0.0; 7], flange).unwrap();
    assert_close(
        placement.translation.vector.as_slice(),
        &[0.088, 0.0, 0.333 + 0.316 + 0.384 - 0.107],
        1e-12,
        "flange position",
    );
    let z_axis = placement.rotation * Vector3::z();
    assert_close(z_axis.as_slice(), &[0.0, 0.0, -1.0], 1e-12, "flange z axis");
}

#[test]
fn hand_is_the_flange_turned_minus_45_degrees() {
    let robot = panda();
    let mut rng = rng(30);
    let (flange, hand) = (
        robot.frame_index("panda_link8").unwrap(),
        robot.end_effector(),
    );
    assert_eq!(robot.frames()[hand].name, "panda_hand");
    let s = random_state(&robot, &mut rng);
    let relative = robot
        .frame_placement(s.q.as_slice(), flange)
        .unwrap()
        .inverse()
        * robot.frame_placement(s.q.as_slice(), hand).unwrap();
    assert!(relative.translation.vector.norm() < 1e-12);
    assert!((relative.rotation.angle() - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
    assert!((relative.rotation.axis().unwrap().z + 1.0).abs() < 1e-12);
}

#[test]
fn jacobian_matches_finite_differences_of_forward_kinematics() {
    let robot = panda();
    let n = robot.dof();
    let mut rng = rng(31);
    let eps = 1e-6;
    let mut jacobian = DMatrix::zeros(6, n);
    for frame in 0..robot.frames().len() {
        let s = random_state(&robot, &mut rng);
        let point = Vector3::new(0.05, -0.02, 0.1);
        robot
            .frame_jacobian(s.q.as_slice(), frame, &point, &mut jacobian)
            .unwrap();
        let placement = |q: &DVector| robot.frame_placement(q.as_slice(), frame).unwrap();
        let mut expected = DMatrix::zeros(6, n);
        for j in 0..n {
            let dq = DVector::from_fn(n, |i, _| if i == j { eps } else { 0.0 });
            let (plus, minus) = (placement(&(&s.q + &dq)), placement(&(&s.q - &dq)));
            let velocity = (plus * Point3::from(point) - minus * Point3::from(point)) / (2.0 * eps);
            let omega = (plus.rotation * minus.rotation.inverse()).scaled_axis() / (2.0 * eps);
            expected.fixed_view_mut::<3, 1>(0, j).copy_from(&velocity);
            expected.fixed_view_mut::<3, 1>(3, j).copy_from(&omega);
        }
        assert_matrix_close(&jacobian, &expected, 1e-8, &format!("J of frame {frame}"));
    }
}

#[test]
fn wrench_torque_is_jacobian_transpose_times_wrench() {
    let robot = panda();
    let n = robot.dof();
    let mut rng = rng(32);
    let mut jacobian = DMatrix::zeros(6, n);
    let mut tau = DVector::zeros(n);
    for link in 0..robot.link_count() {
        let s = random_state(&robot, &mut rng);
        let (force, torque) = (Vector3::new(3.0, -2.0, 5.0), Vector3::new(0.4, 0.1, -0.3));
        robot
            .wrench_to_joint_torque(s.q.as_slice(), link, &force, &torque, &mut tau)
            .unwrap();
        let link_frame = robot
            .frame_index(&format!("panda_link{}", link + 1))
            .unwrap();
        robot
            .frame_jacobian(s.q.as_slice(), link_frame, &Vector3::zeros(), &mut jacobian)
            .unwrap();
        let wrench = DVector::from_iterator(6, force.iter().chain(torque.iter()).copied());
        assert_close(
            tau.as_slice(),
            (jacobian.transpose() * wrench).as_slice(),
            1e-12,
            "Jᵀ w",
        );
        assert!(
            tau.iter().skip(link + 1).all(|&t| t == 0.0),
            "joints after the link feel nothing"
        );
    }
}

#[test]
fn unknown_frames_and_links_are_typed_errors() {
    let robot = panda();
    let frames = robot.frames().len();
    assert_eq!(
        robot.frame_placement(&[0.0; 7], frames),
        Err(DynamicsError::NoSuchFrame {
            index: frames,
            count: frames
        })
    );
    let mut tau = DVector::zeros(7);
    assert_eq!(
        robot.wrench_to_joint_torque(&[0.0; 7], 7, &Vector3::x(), &Vector3::zeros(), &mut tau),
        Err(DynamicsError::NoSuchLink { index: 7, count: 7 })
    );
    let mut jacobian = DMatrix::zeros(3, 7);
    assert!(matches!(
        robot.frame_jacobian(&[0.0; 7], 1, &Vector3::zeros(), &mut jacobian),
        Err(DynamicsError::Shape {
            quantity: "jacobian",
            ..
        })
    ));
}

#[test]
fn joint_rotation_matches_axis_angle_for_any_axis() {
    use ciflow_engine::model::Joint;
    use ciflow_engine::spatial::Se3;
    use nalgebra::{Rotation3, Unit};
    let placement = Se3::new(
        Rotation3::from_euler_angles(0.3, -0.2, 1.1).into_inner(),
        Vector3::new(0.1, 0.2, 0.3),
    );
    for axis in [
        Vector3::z(),
        Vector3::x(),
        Vector3::new(0.3, -0.5, 0.8).normalize(),
    ] {
        let joint = Joint::revolute("j", placement, axis);
        for q in [-2.0, 0.0, 0.7, 3.0] {
            let expected = placement.rotation
                * Rotation3::from_axis_angle(&Unit::new_normalize(axis), q).into_inner();
            let transform = joint.transform(q);
            assert!(
                (transform.rotation - expected).amax() < 1e-14,
                "axis {axis:?}, q {q}"
            );
            assert_eq!(transform.translation, placement.translation);
        }
    }
}

#[test]
fn a_frame_is_found_by_index_or_by_name() {
    let robot = panda();
    let flange = robot.frame_index("panda_link8").unwrap();
    assert_eq!(robot.find_frame("panda_link8"), Ok(flange));
    assert_eq!(robot.find_frame(&flange.to_string()), Ok(flange));
    let count = robot.frames().len();
    assert_eq!(
        robot.find_frame(&count.to_string()),
        Err(DynamicsError::NoSuchFrame {
            index: count,
            count
        })
    );
    let unknown = robot.find_frame("elbow").unwrap_err();
    assert!(
        matches!(&unknown, DynamicsError::NoFrameNamed { name, known }
        if name == "elbow" && known.len() == count)
    );
}
