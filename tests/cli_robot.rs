//! `ciflow robot`: the binary prints the library's values as JSON and rejects bad input.

mod common;

use ciflow_engine::math::DVector;
use ciflow_engine::robot::{PANDA_HOME, Robot, panda};
use common::{ciflow, succeed};
use serde_json::Value;

/// The JSON that a successful `ciflow <args>` printed.
fn json(args: &[&str]) -> Value {
    serde_json::from_slice(&succeed(args).stdout).expect("JSON on stdout")
}

fn numbers(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// JSON numbers round-trip to within an ulp or so.
fn assert_close(actual: &[f64], expected: &[f64]) {
    assert_eq!(actual.len(), expected.len());
    for (a, b) in actual.iter().zip(expected) {
        assert!(
            (a - b).abs() <= 1e-12 * (1.0 + b.abs()),
            "{actual:?} vs {expected:?}"
        );
    }
}

fn home() -> String {
    PANDA_HOME.map(|q| q.to_string()).join(",")
}

#[test]
fn gravity_matches_the_library() {
    let output = json(&["robot", "panda", "gravity", "--q", &home()]);
    let mut expected = DVector::zeros(7);
    panda().gravity(&PANDA_HOME, &mut expected).unwrap();
    assert_close(&numbers(&output["gravity"]), expected.as_slice());
}

#[test]
fn inverse_dynamics_and_mass_matrix_match_the_library() {
    let qdd = "1,-1,0.5,0,2,0,-3";
    let output = json(&[
        "robot",
        "panda",
        "inverse-dynamics",
        "--q",
        &home(),
        "--qd",
        "0.1,0,0,-0.2,0,0.3,0",
        "--qdd",
        qdd,
    ]);
    let mut robot = panda();
    let mut tau = DVector::zeros(7);
    robot
        .inverse_dynamics(
            &PANDA_HOME,
            &[0.1, 0.0, 0.0, -0.2, 0.0, 0.3, 0.0],
            &[1.0, -1.0, 0.5, 0.0, 2.0, 0.0, -3.0],
            &mut tau,
        )
        .unwrap();
    assert_close(&numbers(&output["tau"]), tau.as_slice());
    let output = json(&["robot", "panda", "mass-matrix", "--q", &home()]);
    let rows = output["mass_matrix"].as_array().unwrap();
    assert_eq!(rows.len(), 7);
    let mut m = nalgebra::DMatrix::zeros(7, 7);
    robot.mass_matrix(&PANDA_HOME, &mut m).unwrap();
    assert_close(
        &numbers(&rows[2]),
        &m.row(2).iter().copied().collect::<Vec<_>>(),
    );
}

#[test]
fn forward_kinematics_of_one_frame_and_of_the_point_mass() {
    let output = json(&[
        "robot",
        "panda",
        "forward-kinematics",
        "--q",
        "0,0,0,-0.0698,0,0,0",
        "--link",
        "panda_link8",
    ]);
    let frame = &output["frames"][0];
    assert_eq!(frame["name"], "panda_link8");
    let expected = panda()
        .frame_placement(&[0.0, 0.0, 0.0, -0.0698, 0.0, 0.0, 0.0], 8)
        .unwrap();
    assert_close(
        &numbers(&frame["translation"]),
        expected.translation.vector.as_slice(),
    );
    let output = json(&[
        "robot",
        "point-mass",
        "--mass",
        "2",
        "forward-kinematics",
        "--q",
        "0.5,-0.25",
    ]);
    let frames = output["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 2);
    assert_eq!(numbers(&frames[1]["translation"]), [0.5, -0.25, 0.0]);
    let output = json(&[
        "robot",
        "point-mass",
        "--mass",
        "2",
        "forward-dynamics",
        "--q",
        "0,0",
        "--tau",
        "4,-1",
    ]);
    assert_eq!(numbers(&output["qdd"]), [2.0, -0.5]);
}

#[test]
fn bad_input_exits_non_zero_with_a_message() {
    let output = ciflow(&["robot", "panda", "gravity", "--q", "0,1,2"]);
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("q has 3 entries, expected 7"), "{stderr}");
    let output = ciflow(&["robot", "panda", "gravity", "--q", "0,a,2"]);
    assert!(!output.status.success());
    let output = ciflow(&[
        "robot",
        "panda",
        "forward-kinematics",
        "--q",
        &home(),
        "--link",
        "elbow",
    ]);
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("no frame named `elbow`"));
    let output = ciflow(&[
        "robot",
        "point-mass",
        "--mass",
        "-1",
        "gravity",
        "--q",
        "0,0",
    ]);
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("invalid point mass"));
}

/// The shipped Panda URDF, given as a user's file.
fn panda_urdf() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/engine/assets/panda.urdf").to_owned()
}

#[test]
fn a_urdf_with_tool_and_armature_is_the_robot_the_library_builds() {
    let armature = ciflow_engine::robot::PANDA_ARMATURE
        .map(|a| a.to_string())
        .join(",");
    let urdf = panda_urdf();
    let robot = panda();
    for query in ["mass-matrix", "jacobian"] {
        let args = [
            "robot",
            "--urdf",
            &urdf,
            "--tool",
            "panda_hand",
            "--armature",
            &armature,
            query,
            "--q",
            &home(),
        ];
        let from_file = json(&args);
        let shipped = json(&["robot", "panda", query, "--q", &home()]);
        assert_eq!(
            from_file[query.replace('-', "_")],
            shipped[query.replace('-', "_")],
            "{query}"
        );
    }
    // A locked joint: 6 joints remain, and the tool's Jacobian loses the locked column.
    let six = &home()[..home().rfind(',').unwrap()];
    let output = json(&[
        "robot",
        "--urdf",
        &urdf,
        "--tool",
        "panda_hand",
        "--lock-joints",
        "panda_joint7=0.7853981633974483",
        "jacobian",
        "--q",
        six,
    ]);
    let mut jacobian = ciflow_engine::math::DMatrix::zeros(6, 7);
    robot
        .frame_jacobian(
            &PANDA_HOME,
            robot.end_effector(),
            &ciflow_engine::math::Vector3::zeros(),
            &mut jacobian,
        )
        .unwrap();
    let rows = output["jacobian"].as_array().unwrap();
    for (r, row) in rows.iter().enumerate() {
        let expected: Vec<f64> = (0..6).map(|c| jacobian[(r, c)]).collect();
        assert_close(&numbers(row), &expected);
    }
}

#[test]
fn a_urdf_the_engine_cannot_model_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("ciflow-cli-urdf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let floating = dir.join("floating.urdf");
    std::fs::write(
        &floating,
        r#"<robot name="drone"><link name="world"/><link name="body"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
        <joint name="free" type="floating"><parent link="world"/><child link="body"/></joint></robot>"#,
    )
    .unwrap();
    let floating = floating.to_string_lossy().into_owned();
    let urdf = panda_urdf();
    for (args, message) in [
        (
            vec!["robot", "--urdf", &floating, "gravity", "--q", "0"],
            "joint `free` is floating",
        ),
        (
            vec![
                "robot",
                "--urdf",
                "/nonexistent.urdf",
                "gravity",
                "--q",
                "0",
            ],
            "cannot read /nonexistent.urdf",
        ),
        (
            vec![
                "robot",
                "--urdf",
                &urdf,
                "--lock-joints",
                "elbow",
                "gravity",
                "--q",
                "0",
            ],
            "cannot lock joint `elbow`",
        ),
        (
            vec![
                "robot",
                "--urdf",
                &urdf,
                "--armature",
                "1,2",
                "gravity",
                "--q",
                "0",
            ],
            "armature: expected 7 entries, got 2",
        ),
        (
            vec!["robot", "--urdf", &urdf, "panda", "gravity", "--q", "0"],
            "--urdf gives the robot",
        ),
        (vec!["robot", "gravity", "--q", "0"], "--urdf FILE"),
    ] {
        let output = ciflow(&args);
        assert!(!output.status.success(), "{args:?} succeeded");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(stderr.contains(message), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
