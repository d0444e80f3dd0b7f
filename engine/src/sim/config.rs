//! Simulation settings.

use serde::{Deserialize, Serialize};

use super::{Integrator, SimError};
use crate::math::Real;

/// Time steps and integrator. `control_dt` must be a whole multiple of `physics_dt`; the
/// computed torque is held constant (zero-order hold) over the
/// `control_dt / physics_dt` physics substeps of one control period.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SimConfig {
    /// Physics step, s (default 1 ms).
    pub physics_dt: Real,
    /// Control period, s (default 1 ms: one physics substep per control step).
    pub control_dt: Real,
    pub integrator: Integrator,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            physics_dt: 1e-3,
            control_dt: 1e-3,
            integrator: Integrator::SemiImplicitEuler,
        }
    }
}

impl SimConfig {
    /// Checks the steps and returns the number of physics substeps per control period.
    pub fn substeps(&self) -> Result<usize, SimError> {
        for (name, value) in [
            ("physics_dt", self.physics_dt),
            ("control_dt", self.control_dt),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(SimError::InvalidTimeStep { name, value });
            }
        }
        let ratio = self.control_dt / self.physics_dt;
        let substeps = ratio.round();
        if substeps < 1.0 || (ratio - substeps).abs() > 1e-9 * ratio {
            return Err(SimError::NotAMultiple {
                control_dt: self.control_dt,
                physics_dt: self.physics_dt,
            });
        }
        Ok(substeps as usize)
    }
}
