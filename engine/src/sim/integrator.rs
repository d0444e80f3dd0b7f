//! Time integration of `ẋ = (q̇, q̈(t, q, q̇))` over one physics step.

use serde::{Deserialize, Serialize};

use crate::math::{DVector, Real};

/// The integration scheme of one physics step `h`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Integrator {
    /// Symplectic Euler: `q̇ ← q̇ + h q̈(t, q, q̇)`, then `q ← q + h q̇`. One dynamics
    /// evaluation; first order, bounded energy error.
    #[default]
    SemiImplicitEuler,
    /// Classical fourth-order Runge–Kutta. Four dynamics evaluations.
    Rk4,
}

/// Stage buffers, allocated once.
#[derive(Clone, Debug)]
pub(super) struct Stages {
    q: DVector,
    qd: DVector,
    k_q: [DVector; 4],
    k_qd: [DVector; 4],
}

impl Stages {
    pub(super) fn new(dof: usize) -> Self {
        let zero = DVector::zeros(dof);
        Self {
            q: zero.clone(),
            qd: zero.clone(),
            k_q: std::array::from_fn(|_| zero.clone()),
            k_qd: std::array::from_fn(|_| zero.clone()),
        }
    }
}

impl Integrator {
    /// Advances `(q, q̇)` from `t` to `t + h`; `acceleration(t, q, q̇, q̈)` writes `q̈`.
    pub(super) fn step<E>(
        self,
        stages: &mut Stages,
        time: Real,
        h: Real,
        q: &mut DVector,
        qd: &mut DVector,
        mut acceleration: impl FnMut(Real, &DVector, &DVector, &mut DVector) -> Result<(), E>,
    ) -> Result<(), E> {
        match self {
            Integrator::SemiImplicitEuler => {
                let qdd = &mut stages.k_qd[0];
                acceleration(time, q, qd, qdd)?;
                qd.axpy(h, qdd, 1.0);
                q.axpy(h, qd, 1.0);
            }
            Integrator::Rk4 => {
                const OFFSETS: [Real; 4] = [0.0, 0.5, 0.5, 1.0];
                const WEIGHTS: [Real; 4] = [1.0, 2.0, 2.0, 1.0];
                for (stage, offset) in OFFSETS.iter().enumerate() {
                    stages.q.copy_from(q);
                    stages.qd.copy_from(qd);
                    if stage > 0 {
                        stages.q.axpy(offset * h, &stages.k_q[stage - 1], 1.0);
                        stages.qd.axpy(offset * h, &stages.k_qd[stage - 1], 1.0);
                    }
                    stages.k_q[stage].copy_from(&stages.qd);
                    acceleration(
                        time + offset * h,
                        &stages.q,
                        &stages.qd,
                        &mut stages.k_qd[stage],
                    )?;
                }
                for (stage, weight) in WEIGHTS.iter().enumerate() {
                    let w = weight * h / 6.0;
                    q.axpy(w, &stages.k_q[stage], 1.0);
                    qd.axpy(w, &stages.k_qd[stage], 1.0);
                }
            }
        }
        Ok(())
    }
}
