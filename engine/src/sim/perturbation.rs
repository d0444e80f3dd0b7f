//! External disturbances applied for a window of simulated time.

use serde::{Deserialize, Serialize};

use crate::math::Real;

/// What pushes the robot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum PerturbationKind {
    /// Joint torques `τ_ext` (one per joint, N·m).
    JointTorque(Vec<Real>),
    /// A wrench on movable link `link`, world-aligned (`force` in N, `torque` in N·m), applied
    /// at the link frame's origin: `τ_ext = J(q)ᵀ [force; torque]`.
    LinkWrench {
        link: usize,
        force: [Real; 3],
        torque: [Real; 3],
    },
}

/// A disturbance active for `start ≤ t < start + duration` (absolute simulated time, s).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Perturbation {
    pub kind: PerturbationKind,
    pub start: Real,
    pub duration: Real,
}

impl Perturbation {
    pub fn is_active(&self, time: Real) -> bool {
        self.start <= time && time < self.start + self.duration
    }

    /// Whether the disturbance acts at some time of `[from, to)`.
    pub fn overlaps(&self, from: Real, to: Real) -> bool {
        self.start < to && from < self.start + self.duration
    }
}
