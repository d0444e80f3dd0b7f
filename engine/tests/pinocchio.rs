//! Agreement with Pinocchio (an independent rigid-body library) on four URDF arms: the
//! shipped Panda, a UR5e, a KUKA LBR iiwa 14 and the Panda with its gripper's fingers
//! (prismatic; one finger locked, as Pinocchio's `buildReducedModel` locks it). Over random
//! states, to 1e-9 relative: RNEA, CRBA, generalized gravity, forward dynamics (ABA), the
//! tool frame's placement and its world-aligned Jacobian, with rotor inertias given to
//! Pinocchio's `model.armature`.
//!
//! Needs the project's Python environment (`make test` or `scripts/setup-python.sh`);
//! `$CIFLOW_PYTHON` overrides `<workspace>/.venv/bin/python`.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use ciflow_engine::math::{DMatrix, DVector, Real, Vector3};
use ciflow_engine::robot::{PANDA_ARMATURE, Robot, SerialChain, UrdfOptions};
use common::{
    PANDA_GRIPPER_URDF, assert_close, assert_matrix_close, forward_dynamics, gravity,
    inverse_dynamics, mass_matrix, panda_finger_options, random_state, rng,
};
use rand::RngExt;
use serde_json::{Value, json};

const STATES: usize = 64;
const TOLERANCE: Real = 1e-9;

fn python() -> PathBuf {
    let path = std::env::var_os("CIFLOW_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .parent()
                .expect("the engine crate lives in the workspace")
                .join(".venv/bin/python")
        });
    assert!(
        path.exists(),
        "Python with Pinocchio not found at {}: run `make test` or `scripts/setup-python.sh` \
         (or set CIFLOW_PYTHON)",
        path.display()
    );
    path
}

fn numbers(value: &Value) -> Vec<Real> {
    value
        .as_array()
        .expect("an array")
        .iter()
        .map(|x| x.as_f64().expect("a number"))
        .collect()
}

/// Loads `urdf` (relative to the engine crate) with `options` here and in Pinocchio, and
/// compares the two over random states.
fn compare_with_pinocchio(urdf: &str, options: UrdfOptions, seed: u64) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(urdf);
    let mut robot = SerialChain::from_urdf_file(&path, &options).expect("the URDF loads");
    let n = robot.dof();
    let mut rng = rng(seed);
    let states: Vec<_> = (0..STATES)
        .map(|_| {
            let state = random_state(&robot, &mut rng);
            let tau = DVector::from_fn(n, |i, _| {
                let bound = robot.limits().tau_max[i].min(50.0);
                rng.random_range(-bound..=bound)
            });
            (state, tau)
        })
        .collect();
    let tool = robot.end_effector();
    let request = json!({
        "armature": robot.model().armature().as_slice(),
        "lock": options.locked.iter().map(|l| (l.name.clone(), json!(l.position))).collect::<serde_json::Map<_, _>>(),
        "tool": robot.frames()[tool].name,
        "states": states.iter().map(|(s, tau)| json!({
            "q": s.q.as_slice(), "qd": s.qd.as_slice(), "qdd": s.qdd.as_slice(), "tau": tau.as_slice()
        })).collect::<Vec<_>>()
    });
    let dir = std::env::temp_dir().join(format!("ciflow-pinocchio-{}-{seed}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let request_path = dir.join("request.json");
    let out_path = dir.join("reference.json");
    std::fs::write(&request_path, request.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pinocchio_reference.py");
    let output = Command::new(python())
        .arg(script)
        .arg(&path)
        .arg(&request_path)
        .arg(&out_path)
        .output()
        .expect("run the Pinocchio reference script");
    assert!(
        output.status.success(),
        "pinocchio_reference.py failed on {urdf}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let reference: Value =
        serde_json::from_str(&std::fs::read_to_string(&out_path).unwrap()).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    let joints: Vec<_> = robot
        .model()
        .bodies()
        .iter()
        .map(|b| b.joint.name.as_str())
        .collect();
    let pinocchio_joints: Vec<_> = reference["joints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j.as_str().unwrap())
        .collect();
    assert_eq!(
        joints, pinocchio_joints,
        "{urdf}: the moving joints, in order"
    );
    let results = reference["results"].as_array().unwrap();
    assert_eq!(results.len(), STATES);
    for (i, ((state, tau), expected)) in states.iter().zip(results).enumerate() {
        let what = |quantity: &str| format!("{urdf}: {quantity}, state {i}");
        let rnea = inverse_dynamics(&mut robot, &state.q, &state.qd, &state.qdd);
        assert_close(
            rnea.as_slice(),
            &numbers(&expected["tau"]),
            TOLERANCE,
            &what("rnea"),
        );
        let m = mass_matrix(&mut robot, &state.q);
        let m_expected = DMatrix::from_row_slice(n, n, &numbers(&expected["m"]));
        assert_matrix_close(&m, &m_expected, TOLERANCE, &what("crba"));
        let g = gravity(&mut robot, &state.q);
        assert_close(
            g.as_slice(),
            &numbers(&expected["g"]),
            TOLERANCE,
            &what("gravity"),
        );
        assert!(
            DVector::from(numbers(&expected["g"])).norm() > 1.0,
            "gravity is not trivially zero"
        );
        let qdd = forward_dynamics(&mut robot, &state.q, &state.qd, tau);
        assert_close(
            qdd.as_slice(),
            &numbers(&expected["qdd"]),
            TOLERANCE,
            &what("aba"),
        );
        let placement = robot.frame_placement(state.q.as_slice(), tool).unwrap();
        assert_close(
            placement.translation.vector.as_slice(),
            &numbers(&expected["tool_translation"]),
            TOLERANCE,
            &what("tool position"),
        );
        let rotation = placement.rotation.to_rotation_matrix().into_inner();
        assert_matrix_close(
            &DMatrix::from_iterator(3, 3, rotation.iter().copied()),
            &DMatrix::from_row_slice(3, 3, &numbers(&expected["tool_rotation"])),
            TOLERANCE,
            &what("tool rotation"),
        );
        let mut jacobian = DMatrix::zeros(6, n);
        robot
            .frame_jacobian(state.q.as_slice(), tool, &Vector3::zeros(), &mut jacobian)
            .unwrap();
        assert_matrix_close(
            &jacobian,
            &DMatrix::from_row_slice(6, n, &numbers(&expected["tool_jacobian"])),
            TOLERANCE,
            &what("tool Jacobian"),
        );
    }
}

#[test]
fn panda_matches_pinocchio() {
    let options = UrdfOptions {
        tool: Some("panda_hand".into()),
        armature: Some(PANDA_ARMATURE.to_vec()),
        ..UrdfOptions::default()
    };
    compare_with_pinocchio("assets/panda.urdf", options, 7);
}

#[test]
fn ur5e_matches_pinocchio() {
    let options = UrdfOptions {
        tool: Some("tool0".into()),
        armature: Some(vec![0.4, 0.4, 0.2, 0.05, 0.05, 0.05]),
        ..UrdfOptions::default()
    };
    compare_with_pinocchio("tests/assets/ur5e.urdf", options, 8);
}

#[test]
fn iiwa14_matches_pinocchio() {
    compare_with_pinocchio("tests/assets/iiwa14.urdf", UrdfOptions::default(), 9);
}

#[test]
fn a_gripper_finger_moves_as_a_prismatic_joint_as_in_pinocchio() {
    compare_with_pinocchio(PANDA_GRIPPER_URDF, panda_finger_options(), 10);
}
