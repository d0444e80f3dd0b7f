//! The noise-free rollout `y_{k+1} = F(y_k, c)` of any policy ([`MeanDynamics`]): what
//! the LASA scores compare with the demonstrations and the field figures draw.

use ciflow_engine::flow::{FlowResult, MeanDynamics};

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
    let mut path = Vec::with_capacity(steps + 1);
    path.push(start);
    let mut next = [0.0; N];
    for _ in 0..steps {
        let last = *path.last().expect("starts with the start");
        model.mean_next(&last, context, ws, &mut next)?;
        path.push(next);
        if next.iter().any(|v| !v.is_finite()) {
            break;
        }
    }
    Ok(path)
}
