//! What the arm tasks (pouring, reach) share at `reset`: the demonstrations' push option
//! and the checks of a given start state.

use std::collections::BTreeMap;

use ciflow_engine::robot::JointLimits;
use ciflow_engine::sim::{Perturbation, PerturbationKind};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::env::EnvError;

/// Reset option: pushes the hand once per episode with up to this force, N.
pub const PUSH_FORCE_OPTION: &str = "push_force";
/// Duration of the `push_force` push, s.
pub const DEMO_PUSH_DURATION: f64 = 0.2;
/// When the `push_force` push starts: uniform in this window, s.
pub const DEMO_PUSH_WINDOW: (f64, f64) = (0.3, 3.0);

/// The `push_force` option (0 when absent): a finite force ≥ 0.
pub fn push_force(extra: &BTreeMap<String, f64>) -> Result<f64, EnvError> {
    let force = extra.get(PUSH_FORCE_OPTION).copied().unwrap_or(0.0);
    if force.is_finite() && force >= 0.0 {
        Ok(force)
    } else {
        Err(EnvError::InvalidOption {
            name: PUSH_FORCE_OPTION.into(),
            detail: format!("{force} N; a finite force >= 0 is needed"),
        })
    }
}

/// The episode's push of `link` for a `push_force` of `force` (none for 0): a horizontal
/// force of magnitude `U(0, force)` in a uniform direction for [`DEMO_PUSH_DURATION`],
/// starting at `U(`[`DEMO_PUSH_WINDOW`]`)` s, drawn from `rng` in that order.
pub fn demo_push(rng: &mut ChaCha8Rng, force: f64, link: usize) -> Option<Perturbation> {
    (force > 0.0).then(|| {
        let magnitude = rng.random_range(0.0..=force);
        let angle = rng.random_range(0.0..std::f64::consts::TAU);
        Perturbation {
            kind: PerturbationKind::LinkWrench {
                link,
                force: [magnitude * angle.cos(), magnitude * angle.sin(), 0.0],
                torque: [0.0; 3],
            },
            start: rng.random_range(DEMO_PUSH_WINDOW.0..=DEMO_PUSH_WINDOW.1),
            duration: DEMO_PUSH_DURATION,
        }
    })
}

/// `values` as a vector of one finite number per joint.
pub fn joint_vector(
    what: &'static str,
    values: &[f64],
    joints: usize,
) -> Result<Vec<f64>, EnvError> {
    if values.len() != joints {
        return Err(EnvError::WrongDimension {
            what,
            expected: joints,
            got: values.len(),
        });
    }
    if values.iter().any(|v| !v.is_finite()) {
        return Err(EnvError::NotFinite { what });
    }
    Ok(values.to_vec())
}

/// A given start position: one finite number per joint, inside the joint limits.
pub fn initial_position(values: &[f64], limits: &JointLimits) -> Result<Vec<f64>, EnvError> {
    let q0 = joint_vector("initial_position", values, limits.q_min.len())?;
    match (0..q0.len()).find(|&i| q0[i] < limits.q_min[i] || q0[i] > limits.q_max[i]) {
        Some(i) => Err(EnvError::OutOfBounds {
            what: "initial_position",
            detail: format!("joint {i} = {} is outside its limits", q0[i]),
        }),
        None => Ok(q0),
    }
}
