//! Joint limits.

use super::ModelError;
use crate::math::{DVector, Real};

/// Per-joint limits; `±∞` means "no limit".
///
/// - `q_min ≤ q ≤ q_max` (rad): end stops in simulation;
/// - `|q̇| ≤ qd_max` (rad/s), `|q̈| ≤ qdd_max` (rad/s²): nominal, for planners and policies;
/// - `|τ| ≤ tau_max` (N·m): torque saturation of the computed-torque layer;
/// - `|τ̇| ≤ tau_rate_max` (N·m/s): torque rate limit of the computed-torque layer.
#[derive(Clone, Debug, PartialEq)]
pub struct JointLimits {
    pub q_min: DVector,
    pub q_max: DVector,
    pub qd_max: DVector,
    pub qdd_max: DVector,
    pub tau_max: DVector,
    pub tau_rate_max: DVector,
}

impl JointLimits {
    /// No limit on anything.
    pub fn unlimited(dof: usize) -> Self {
        let inf = DVector::from_element(dof, Real::INFINITY);
        Self {
            q_min: -inf.clone(),
            q_max: inf.clone(),
            qd_max: inf.clone(),
            qdd_max: inf.clone(),
            tau_max: inf.clone(),
            tau_rate_max: inf,
        }
    }

    pub fn dof(&self) -> usize {
        self.q_min.len()
    }

    /// Checks dimensions (`dof` each), that nothing is NaN, `q_min ≤ q_max`, and that the
    /// symmetric bounds are positive.
    pub fn validate(&self, dof: usize) -> Result<(), ModelError> {
        let named = [
            ("q_min", &self.q_min),
            ("q_max", &self.q_max),
            ("qd_max", &self.qd_max),
            ("qdd_max", &self.qdd_max),
            ("tau_max", &self.tau_max),
            ("tau_rate_max", &self.tau_rate_max),
        ];
        for (what, values) in named {
            if values.len() != dof {
                return Err(ModelError::Dimension {
                    what,
                    expected: dof,
                    actual: values.len(),
                });
            }
            if let Some(joint) = values.iter().position(|x| x.is_nan()) {
                return Err(ModelError::InvalidLimits {
                    what,
                    joint,
                    reason: "NaN",
                });
            }
        }
        for (what, values) in &named[2..] {
            if let Some(joint) = values.iter().position(|&x| x <= 0.0) {
                return Err(ModelError::InvalidLimits {
                    what,
                    joint,
                    reason: "must be positive",
                });
            }
        }
        if let Some(joint) = (0..dof).find(|&i| self.q_min[i] > self.q_max[i]) {
            return Err(ModelError::InvalidLimits {
                what: "q_min",
                joint,
                reason: "greater than q_max",
            });
        }
        Ok(())
    }
}
