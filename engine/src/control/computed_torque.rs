//! Computed-torque control with torque saturation and a torque-rate limit.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::JointMask;
use crate::algorithm::{DynamicsError, check_len};
use crate::math::{DVector, Real};
use crate::robot::Robot;

#[derive(Debug, Error)]
pub enum ControlError {
    #[error("the control period must be finite and positive, got {0}")]
    InvalidPeriod(Real),
    #[error("robots with more than {max} joints are not supported, got {dof}", max = JointMask::CAPACITY)]
    TooManyJoints { dof: usize },
    #[error(transparent)]
    Dynamics(#[from] DynamicsError),
}

/// Which joints the limits changed in one control period.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Saturation {
    /// `|τᵢ| > τ_max,ᵢ`: clipped to `±τ_max,ᵢ`.
    pub clipped: JointMask,
    /// `|τᵢ − τᵢ⁻| > τ̇_max,ᵢ Δt`: moved only `±τ̇_max,ᵢ Δt` from the previous command.
    pub rate_limited: JointMask,
}

impl Saturation {
    /// Whether the applied torque differs from the requested one.
    pub fn is_active(&self) -> bool {
        !(self.clipped.is_empty() && self.rate_limited.is_empty())
    }
}

/// The computed-torque law `τ* = M(q) q̈_des + C(q, q̇) q̇ + g(q)` (evaluated as one RNEA
/// call), then the actuator limits:
///
/// 1. clip: `τ̄ = clamp(τ*, −τ_max, τ_max)`;
/// 2. rate-limit: `τ = clamp(τ̄, τ⁻ − τ̇_max Δt, τ⁻ + τ̇_max Δt)`, `τ⁻` the previous
///    command, starting from `clamp(g(q₀), ±τ_max)` at [`ComputedTorque::reset`] (zero
///    before any reset).
///
/// Since `τ⁻` already lies in `[−τ_max, τ_max]`, step 2 keeps `|τ| ≤ τ_max`: both limits
/// hold for every command. Without active limits the closed loop gives
/// `q̈ = q̈_des + M⁻¹ τ_ext`; with them `q̈ = M⁻¹ (τ − C q̇ − g + τ_ext)`, and the
/// returned [`Saturation`] says which joints were affected.
#[derive(Clone, Debug)]
pub struct ComputedTorque {
    period: Real,
    requested: DVector,
    command: DVector,
}

impl ComputedTorque {
    /// A controller for `dof` joints running every `period` seconds.
    pub fn new(dof: usize, period: Real) -> Result<Self, ControlError> {
        if !(period.is_finite() && period > 0.0) {
            return Err(ControlError::InvalidPeriod(period));
        }
        if dof > JointMask::CAPACITY {
            return Err(ControlError::TooManyJoints { dof });
        }
        Ok(Self {
            period,
            requested: DVector::zeros(dof),
            command: DVector::zeros(dof),
        })
    }

    pub fn period(&self) -> Real {
        self.period
    }

    /// Starts the rate limiter from the (clipped) gravity torque `g(q₀)`.
    pub fn reset(&mut self, robot: &mut dyn Robot, q0: &[Real]) -> Result<(), ControlError> {
        self.check_robot(robot)?;
        robot.gravity(q0, &mut self.command)?;
        let tau_max = &robot.limits().tau_max;
        for (tau, max) in self.command.iter_mut().zip(tau_max.iter()) {
            *tau = tau.clamp(-max, *max);
        }
        Ok(())
    }

    /// Sets the previous command `τ⁻` (e.g. after a torque applied directly).
    pub fn hold(&mut self, tau: &[Real]) -> Result<(), ControlError> {
        crate::algorithm::check_vector("tau", tau, self.command.len())?;
        self.command.copy_from_slice(tau);
        Ok(())
    }

    /// One control period: the limited command lands in [`ComputedTorque::command`].
    pub fn compute(
        &mut self,
        robot: &mut dyn Robot,
        q: &[Real],
        qd: &[Real],
        qdd_desired: &[Real],
    ) -> Result<Saturation, ControlError> {
        self.check_robot(robot)?;
        robot.inverse_dynamics(q, qd, qdd_desired, &mut self.requested)?;
        let limits = robot.limits();
        let mut saturation = Saturation::default();
        for i in 0..self.command.len() {
            let tau_max = limits.tau_max[i];
            let clipped = self.requested[i].clamp(-tau_max, tau_max);
            if clipped != self.requested[i] {
                saturation.clipped.insert(i);
            }
            let step = limits.tau_rate_max[i] * self.period;
            let previous = self.command[i];
            let limited = clipped.clamp(previous - step, previous + step);
            if limited != clipped {
                saturation.rate_limited.insert(i);
            }
            self.command[i] = limited;
        }
        Ok(saturation)
    }

    /// The last limited command `τ`.
    pub fn command(&self) -> &DVector {
        &self.command
    }

    /// The last unlimited request `τ* = M q̈_des + C q̇ + g`.
    pub fn requested(&self) -> &DVector {
        &self.requested
    }

    fn check_robot(&self, robot: &dyn Robot) -> Result<(), DynamicsError> {
        check_len("robot dof", robot.dof(), self.command.len())
    }
}
