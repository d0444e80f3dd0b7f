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
