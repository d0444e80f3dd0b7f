//! The URDF loader: prismatic joints, locked joints and the tool frame give the dynamics
//! of the equivalent chain, and what a chain cannot express is a typed error, never a panic.

mod common;

use ciflow_engine::math::{DMatrix, DVector, Real, Vector3};
use ciflow_engine::model::{LockedJoint, Model, ModelError};
use ciflow_engine::robot::{PANDA_URDF, Robot, SerialChain, UrdfOptions};
use common::*;

const INERTIAL: &str = r#"<inertial><mass value="2"/><inertia ixx="0.1" iyy="0.2" izz="0.3" ixy="0" ixz="0" iyz="0"/></inertial>"#;

/// A robot of links `base`, `a`, `b`, … named by `links`, joined by the `joints` XML.
fn urdf(links: &[&str], joints: &str) -> String {
    let links: String = links
        .iter()
        .map(|l| format!(r#"<link name="{l}">{INERTIAL}</link>"#))
        .collect();
    format!(r#"<robot name="r"><link name="base"/>{links}{joints}</robot>"#)
}

fn joint(name: &str, kind: &str, parent: &str, child: &str) -> String {
    format!(
        r#"<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>
        <origin xyz="0.1 0 0.2" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
        <limit lower="-1" upper="1" effort="10" velocity="2"/></joint>"#
    )
}

#[test]
fn a_prismatic_joint_lifts_its_mass_against_gravity() {
    // A 2 kg slider on a vertical axis: g = m g₀, M = m + armature, J = [axis; 0].
    let text = format!(
        r#"<robot name="lift"><link name="base"/><link name="carriage">{INERTIAL}</link>
        <joint name="z" type="prismatic"><parent link="base"/><child link="carriage"/>
        <axis xyz="0 0 2"/><limit lower="0" upper="0.5" effort="100" velocity="1"/></joint></robot>"#
    );
    let options = UrdfOptions {
        armature: Some(vec![0.5]),
        ..UrdfOptions::default()
    };
    let mut robot = SerialChain::from_urdf(&text, &options).unwrap();
    assert_eq!(robot.limits().q_max[0], 0.5);
    let q = DVector::from_element(1, 0.3);
    assert_close(
        gravity(&mut robot, &q).as_slice(),
        &[2.0 * 9.81],
        1e-12,
        "g",
    );
    assert_close(mass_matrix(&mut robot, &q).as_slice(), &[2.5], 1e-12, "M");
    let placement = robot.frame_placement(&[0.3], 1).unwrap();
    assert_close(
        placement.translation.vector.as_slice(),
        &[0.0, 0.0, 0.3],
        1e-12,
        "x",
    );
    let mut jacobian = DMatrix::zeros(6, 1);
    robot
        .frame_jacobian(&[0.3], 1, &Vector3::new(0.2, 0.0, 0.0), &mut jacobian)
        .unwrap();
    assert_close(
        jacobian.as_slice(),
        &[0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        1e-12,
        "J",
    );
}

#[test]
fn a_locked_joint_gives_the_dynamics_of_the_full_chain_held_there() {
    // Locking the Panda's joint 7 at 0.5: the 6-joint model's τ, M and g are those of the
    // 7-joint model at q₇ = 0.5 with q̇₇ = q̈₇ = 0, and its tool frame is in the same place.
    let mut full = SerialChain::from_urdf_str(PANDA_URDF).unwrap();
    let options = UrdfOptions {
        locked: vec![LockedJoint {
            name: "panda_joint7".into(),
            position: 0.5,
        }],
        tool: Some("panda_hand".into()),
        armature: None,
    };
    let mut locked = SerialChain::from_urdf(PANDA_URDF, &options).unwrap();
    assert_eq!(locked.dof(), 6);
    let hand = full.frame_index("panda_hand").unwrap();
    let mut rng = rng(3);
    for _ in 0..20 {
        let s = random_state(&locked, &mut rng);
        let extend = |v: &DVector, last| DVector::from_iterator(7, v.iter().copied().chain([last]));
        let (q, qd, qdd) = (extend(&s.q, 0.5), extend(&s.qd, 0.0), extend(&s.qdd, 0.0));
        let tau = inverse_dynamics(&mut full, &q, &qd, &qdd);
        let tau_locked = inverse_dynamics(&mut locked, &s.q, &s.qd, &s.qdd);
        assert_close(tau_locked.as_slice(), &tau.as_slice()[..6], 1e-12, "τ");
        let m = mass_matrix(&mut full, &q);
        assert_matrix_close(
            &mass_matrix(&mut locked, &s.q),
            &m.view((0, 0), (6, 6)).into_owned(),
            1e-12,
            "M",
        );
        let tool = locked
            .frame_placement(s.q.as_slice(), locked.end_effector())
            .unwrap();
        let expected = full.frame_placement(q.as_slice(), hand).unwrap();
        assert!((tool.to_homogeneous() - expected.to_homogeneous()).amax() < 1e-12);
    }
}

#[test]
fn branches_are_refused_unless_all_but_one_is_locked() {
    let text = urdf(
        &["a", "left", "right"],
        &[
            joint("shoulder", "revolute", "base", "a"),
            joint("left_finger", "prismatic", "a", "left"),
            joint("right_finger", "prismatic", "a", "right"),
        ]
        .concat(),
    );
    match Model::from_urdf_str(&text) {
        Err(ModelError::NotSerialChain(why)) => {
            assert!(
                why.contains("left_finger") && why.contains("right_finger"),
                "{why}"
            )
        }
        other => panic!("expected NotSerialChain, got {other:?}"),
    }
    let locked = [LockedJoint {
        name: "right_finger".into(),
        position: 0.5,
    }];
    let model = Model::from_urdf_str_locked(&text, &locked).unwrap();
    assert_eq!(model.nv(), 2);
    // The locked finger's mass rides on link `a`.
    assert_eq!(model.bodies()[0].inertia.mass, 4.0);
}

#[test]
fn joints_a_chain_cannot_express_are_typed_errors() {
    for kind in ["floating", "planar"] {
        let text = urdf(&["a"], &joint("free", kind, "base", "a"));
        match Model::from_urdf_str(&text) {
            Err(ModelError::UnsupportedJoint { joint, kind: found }) => {
                assert_eq!((joint.as_str(), found.as_str()), ("free", kind))
            }
            other => panic!("{kind}: expected UnsupportedJoint, got {other:?}"),
        }
    }
    let zero_axis = urdf(
        &["a"],
        &joint("j", "revolute", "base", "a").replace(r#"xyz="0 1 0""#, r#"xyz="0 0 0""#),
    );
    assert!(matches!(
        Model::from_urdf_str(&zero_axis),
        Err(ModelError::ZeroAxis { .. })
    ));
    assert!(matches!(
        Model::from_urdf_str("<robot"),
        Err(ModelError::Urdf(_))
    ));
}

#[test]
fn a_movable_joint_without_room_to_move_is_refused() {
    let limited = joint("j", "revolute", "base", "a");
    // No <limit> at all (urdf-rs reads [0, 0]), an empty range and an inverted one.
    let without = limited.replace(
        r#"<limit lower="-1" upper="1" effort="10" velocity="2"/>"#,
        "",
    );
    let pinned = limited.replace(r#"lower="-1""#, r#"lower="1""#);
    let inverted = limited.replace(r#"lower="-1""#, r#"lower="2""#);
    for (case, joint_xml, range) in [
        ("no <limit>", without, (0.0, 0.0)),
        ("lower = upper", pinned, (1.0, 1.0)),
        ("lower > upper", inverted, (2.0, 1.0)),
    ] {
        match Model::from_urdf_str(&urdf(&["a"], &joint_xml)) {
            Err(ModelError::NoMotion {
                joint,
                lower,
                upper,
                ..
            }) => assert_eq!((joint.as_str(), (lower, upper)), ("j", range), "{case}"),
            other => panic!("{case}: expected NoMotion, got {other:?}"),
        }
    }
    // A prismatic joint alike; a continuous joint needs no position limits at all.
    let prismatic = joint("p", "prismatic", "base", "a").replace(r#"lower="-1""#, r#"lower="1""#);
    assert!(matches!(
        Model::from_urdf_str(&urdf(&["a"], &prismatic)),
        Err(ModelError::NoMotion {
            kind: "prismatic",
            ..
        })
    ));
    let continuous = joint("c", "continuous", "base", "a").replace(
        r#"<limit lower="-1" upper="1" effort="10" velocity="2"/>"#,
        "",
    );
    assert_eq!(
        Model::from_urdf_str(&urdf(&["a"], &continuous))
            .unwrap()
            .nv(),
        1
    );
    // Locked, a pinned joint holds its one position and moves nothing.
    let held = urdf(
        &["a", "b"],
        &(joint("j", "revolute", "base", "a").replace(r#"lower="-1""#, r#"lower="1""#)
            + &joint("k", "revolute", "a", "b")),
    );
    let lock = [LockedJoint {
        name: "j".into(),
        position: 1.0,
    }];
    assert_eq!(Model::from_urdf_str_locked(&held, &lock).unwrap().nv(), 1);
}

#[test]
fn a_name_used_twice_is_refused() {
    let twice = urdf(
        &["a", "b"],
        &(joint("j", "revolute", "base", "a") + &joint("j", "revolute", "a", "b")),
    );
    match Model::from_urdf_str(&twice) {
        Err(ModelError::DuplicateName { kind, name }) => {
            assert_eq!((kind, name.as_str()), ("joint", "j"))
        }
        other => panic!("expected a duplicate joint, got {other:?}"),
    }
    let links = urdf(&["a", "a"], &joint("j", "revolute", "base", "a"));
    assert!(matches!(
        Model::from_urdf_str(&links),
        Err(ModelError::DuplicateName { kind: "link", .. })
    ));
}

#[test]
fn a_joint_that_moves_no_mass_is_refused() {
    // The last link has no <inertial>: its joint would make M(q) singular.
    let text = urdf(&["a"], &joint("j1", "revolute", "base", "a")).replace(
        "</robot>",
        &format!(
            r#"<link name="bare"/>{}</robot>"#,
            joint("j2", "revolute", "a", "bare")
        ),
    );
    match Model::from_urdf_str(&text) {
        Err(ModelError::Massless { joint, link }) => {
            assert_eq!((joint.as_str(), link.as_str()), ("j2", "bare"))
        }
        other => panic!("expected Massless, got {other:?}"),
    }
    // A massless link inside the chain is fine: the links after it carry mass.
    let inner = urdf(&["b"], "")
        .replace(
            r#"<link name="base"/>"#,
            r#"<link name="base"/><link name="a"/>"#,
        )
        .replace(
            "</robot>",
            &format!(
                "{}{}</robot>",
                joint("j1", "revolute", "base", "a"),
                joint("j2", "revolute", "a", "b")
            ),
        );
    assert_eq!(Model::from_urdf_str(&inner).unwrap().nv(), 2);
}

#[test]
fn non_finite_numbers_are_typed_errors() {
    let good = urdf(&["a"], &joint("j", "revolute", "base", "a"));
    for (from, to) in [
        (r#"xyz="0.1 0 0.2""#, r#"xyz="NaN 0 0.2""#),
        (r#"xyz="0 1 0""#, r#"xyz="0 inf 0""#),
        (r#"<mass value="2"/>"#, r#"<mass value="NaN"/>"#),
        (r#"ixx="0.1""#, r#"ixx="NaN""#),
        (r#"upper="1""#, r#"upper="NaN""#),
    ] {
        let bad = good.replace(from, to);
        assert_ne!(bad, good, "{from} is in the document");
        let result = Model::from_urdf_str(&bad);
        assert!(result.is_err(), "{to}: accepted");
    }
    let locked = [LockedJoint {
        name: "j".into(),
        position: Real::NAN,
    }];
    assert!(matches!(
        Model::from_urdf_str_locked(&good, &locked),
        Err(ModelError::Lock { .. })
    ));
}

#[test]
fn a_bad_lock_is_a_typed_error() {
    let text = urdf(
        &["a", "b"],
        &[
            joint("j1", "revolute", "base", "a"),
            joint("j2", "fixed", "a", "b"),
        ]
        .concat(),
    );
    let lock = |name: &str, position| {
        vec![LockedJoint {
            name: name.into(),
            position,
        }]
    };
    for (locked, why) in [
        (lock("nope", 0.0), "no joint"),
        (lock("j1", 1.5), "outside its limits"),
        (lock("j2", 0.0), "fixed"),
        ([lock("j1", 0.0), lock("j1", 0.1)].concat(), "twice"),
    ] {
        match Model::from_urdf_str_locked(&text, &locked) {
            Err(ModelError::Lock { reason, .. }) => assert!(reason.contains(why), "{reason}"),
            other => panic!("{locked:?}: expected a Lock error, got {other:?}"),
        }
    }
}

#[test]
fn the_tool_and_armature_options_are_checked() {
    let bad_tool = UrdfOptions {
        tool: Some("nowhere".into()),
        ..UrdfOptions::default()
    };
    assert!(matches!(
        SerialChain::from_urdf(PANDA_URDF, &bad_tool),
        Err(ModelError::NoSuchFrame(_))
    ));
    let short = UrdfOptions {
        armature: Some(vec![0.1; 3]),
        ..UrdfOptions::default()
    };
    assert!(matches!(
        SerialChain::from_urdf(PANDA_URDF, &short),
        Err(ModelError::Dimension { .. })
    ));
    let missing = SerialChain::from_urdf_file("/nonexistent/robot.urdf", &UrdfOptions::default());
    assert!(matches!(missing, Err(ModelError::Read { .. })));
}

#[test]
fn a_gripper_loads_once_all_but_one_finger_is_locked() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/assets/panda_gripper.urdf"
    );
    match SerialChain::from_urdf_file(path, &UrdfOptions::default()) {
        Err(ModelError::NotSerialChain(why)) => assert!(
            why.contains("panda_finger_joint1") && why.contains("panda_finger_joint2"),
            "{why}"
        ),
        other => panic!("expected NotSerialChain, got {other:?}"),
    }
    let options = UrdfOptions {
        locked: vec![LockedJoint {
            name: "panda_finger_joint2".into(),
            position: 0.04,
        }],
        ..UrdfOptions::default()
    };
    let robot = SerialChain::from_urdf_file(path, &options).unwrap();
    assert_eq!(robot.dof(), 8);
    assert_eq!(robot.limits().q_max[7], 0.04, "the finger's travel");
}

#[test]
fn a_locked_joint_reads_as_a_name_held_at_zero_or_at_a_position() {
    let locked = |name: &str, position| LockedJoint {
        name: name.into(),
        position,
    };
    assert_eq!("finger".parse(), Ok(locked("finger", 0.0)));
    assert_eq!(" finger = 0.02".parse(), Ok(locked("finger", 0.02)));
    assert!("finger=wide".parse::<LockedJoint>().is_err());
    assert!("=0.1".parse::<LockedJoint>().is_err());
}
