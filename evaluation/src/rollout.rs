//! The noise-free rollout `y_{k+1} = F(y_k, c)` of any policy ([`MeanDynamics`]): what
//! the stability check runs from far starts, the LASA scores compare with the
//! demonstrations and the field figures draw.

use ciflow_engine::flow::{FlowResult, MeanDynamics};
use ciflow_engine::math::distance;

/// A noise-free rollout as it goes: the current state, stepped one control period at a
/// time under a fixed context.
pub struct MeanStepper<'a, M: MeanDynamics> {
    model: &'a M,
    state: Vec<f64>,
    next: Vec<f64>,
}

impl<'a, M: MeanDynamics> MeanStepper<'a, M> {
    /// A rollout of `model` from the origin; set the start with [`state_mut`](Self::state_mut).
    pub fn new(model: &'a M) -> Self {
        let d = model.bounds().state_min.len();
        Self {
            model,
            state: vec![0.0; d],
            next: vec![0.0; d],
        }
    }

    pub fn state(&self) -> &[f64] {
        &self.state
    }

    pub fn state_mut(&mut self) -> &mut [f64] {
        &mut self.state
    }

    /// `y ← F(y, c)`; returns the length of the step, `‖F(y, c) − y‖`.
    pub fn step(&mut self, context: &[f64], ws: &mut M::Workspace) -> FlowResult<f64> {
        self.model
            .mean_next(&self.state, context, ws, &mut self.next)?;
        let length = distance(&self.state, &self.next);
        std::mem::swap(&mut self.state, &mut self.next);
        Ok(length)
    }
}

/// `start` and the `steps` states after it under the fixed context `context`, or fewer:
/// the rollout stops at the first non-finite state, which it keeps (so that a score sees
/// the failure; a figure drops it).
pub fn mean_rollout<M: MeanDynamics, const N: usize>(
    model: &M,
    start: [f64; N],
    context: &[f64],
    steps: usize,
    ws: &mut M::Workspace,
) -> FlowResult<Vec<[f64; N]>> {
    let mut stepper = MeanStepper::new(model);
    stepper.state_mut().copy_from_slice(&start);
    let mut path = Vec::with_capacity(steps + 1);
    path.push(start);
    for _ in 0..steps {
        stepper.step(context, ws)?;
        let state = stepper.state();
        path.push(std::array::from_fn(|i| state[i]));
        if state.iter().any(|v| !v.is_finite()) {
            break;
        }
    }
    Ok(path)
}
