//! Agreement with Pinocchio (an independent rigid-body library) on the shipped Panda URDF:
//! RNEA, CRBA and generalized gravity over random states, to 1e-9, with the Panda's
//! armature (reflected rotor inertias) given to Pinocchio's `model.armature`.
//!
//! Needs the project's Python environment (`make test` or `scripts/setup-python.sh`);
//! `$CIFLOW_PYTHON` overrides `<workspace>/.venv/bin/python`.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use ciflow_engine::math::{DMatrix, DVector, Real};
use ciflow_engine::robot::{Robot, panda};
use common::{
    assert_close, assert_matrix_close, gravity, inverse_dynamics, mass_matrix, random_state, rng,
};
use serde_json::{Value, json};

const STATES: usize = 128;
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

#[test]
fn panda_rnea_crba_gravity_match_pinocchio() {
    let mut robot = panda();
    let n = robot.dof();
    let mut rng = rng(7);
    let states: Vec<_> = (0..STATES)
        .map(|_| random_state(&robot, &mut rng))
        .collect();
    let request = json!({
        "armature": robot.model().armature().as_slice(),
        "states": states.iter().map(|s| json!({
            "q": s.q.as_slice(), "qd": s.qd.as_slice(), "qdd": s.qdd.as_slice()
        })).collect::<Vec<_>>()
    });
    let dir = std::env::temp_dir().join(format!("ciflow-pinocchio-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states_path = dir.join("states.json");
    let out_path = dir.join("reference.json");
    std::fs::write(&states_path, request.to_string()).unwrap();
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let output = Command::new(python())
        .arg(manifest.join("tests/pinocchio_reference.py"))
        .arg(manifest.join("assets/panda.urdf"))
        .arg(&states_path)
        .arg(&out_path)
        .output()
        .expect("run the Pinocchio reference script");
    assert!(
        output.status.success(),
        "pinocchio_reference.py failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let reference: Value =
        serde_json::from_str(&std::fs::read_to_string(&out_path).unwrap()).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(reference["nq"].as_u64(), Some(n as u64), "Pinocchio's nq");
    let results = reference["results"].as_array().unwrap();
    assert_eq!(results.len(), STATES);
    for (i, (state, expected)) in states.iter().zip(results).enumerate() {
        let tau = inverse_dynamics(&mut robot, &state.q, &state.qd, &state.qdd);
        assert_close(
            tau.as_slice(),
            &numbers(&expected["tau"]),
            TOLERANCE,
            &format!("rnea, state {i}"),
        );
        let m = mass_matrix(&mut robot, &state.q);
        let m_expected = DMatrix::from_row_slice(n, n, &numbers(&expected["m"]));
        assert_matrix_close(&m, &m_expected, TOLERANCE, &format!("crba, state {i}"));
        let g = gravity(&mut robot, &state.q);
        assert_close(
            g.as_slice(),
            &numbers(&expected["g"]),
            TOLERANCE,
            &format!("gravity, state {i}"),
        );
        assert!(
            DVector::from(numbers(&expected["g"])).norm() > 1.0,
            "gravity is not trivially zero"
        );
    }
}
