//! The closed-loop claim of the module docs, on the double integrator `q̈ = q̈_des`
//! (computed torque without saturation or external torque): the velocity error decays
//! as `e(t) = e^{-K_v t} e(0)` and the position converges to the attractor.

mod flow_common;

use ciflow_engine::flow::{LatentKind, Policy, PolicyWorkspace, Weights};
use flow_common::*;

const GAIN: f64 = 4.0;

fn derivative(
    policy: &Policy,
    ws: &mut PolicyWorkspace,
    c: &[f64],
    state: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let d = state.len() / 2;
    let (mut acc, mut v) = (vec![0.0; d], vec![0.0; d]);
    policy
        .acceleration(&state[..d], &state[d..], c, GAIN, ws, &mut acc, &mut v)
        .unwrap();
    let mut out = state[d..].to_vec();
    out.extend(acc);
    (out, v)
}

/// Classical RK4 step of `(q, q̇)`.
fn rk4(policy: &Policy, ws: &mut PolicyWorkspace, c: &[f64], state: &[f64], h: f64) -> Vec<f64> {
    let add =
        |a: &[f64], b: &[f64], s: f64| a.iter().zip(b).map(|(x, y)| x + s * y).collect::<Vec<_>>();
    let k1 = derivative(policy, ws, c, state).0;
    let k2 = derivative(policy, ws, c, &add(state, &k1, h / 2.0)).0;
    let k3 = derivative(policy, ws, c, &add(state, &k2, h / 2.0)).0;
    let k4 = derivative(policy, ws, c, &add(state, &k3, h)).0;
    (0..state.len())
        .map(|i| state[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
        .collect()
}

fn velocity_error(policy: &Policy, ws: &mut PolicyWorkspace, c: &[f64], state: &[f64]) -> f64 {
    let d = state.len() / 2;
    let v = derivative(policy, ws, c, state).1;
    (0..d)
        .map(|i| (state[d + i] - v[i]).powi(2))
        .sum::<f64>()
        .sqrt()
}

#[test]
fn double_integrator_tracks_the_flow_and_converges() {
    // Affine couplings are smooth, so fixed-step RK4 reproduces e(t) tightly. Splines are
    // only C¹ at their knots: q̈_des jumps there and each crossing costs RK4 accuracy
    // (not the loop: ė = -K_v e holds between knots), hence the looser tolerance.
    for (coupling, e_tolerance) in [(AFFINE, 1e-3), (SPLINE, 0.1)] {
        let mut config = config(2, 1, LatentKind::GoTo, coupling);
        config.min_rate = 1.0;
        // Milder random weights than the other tests: Jacobians of 10³ make the ODE too
        // stiff for a fixed-step integrator, and this test is about the loop, not the flow.
        let weights = Weights::random(&config.parameter_shapes(), 0.5, &mut rng(21));
        let policy = Policy::new(&config, weights).unwrap();
        let mut ws = policy.workspace();
        let mut r = rng(22);
        for _ in 0..3 {
            let c = uniform(&mut r, 1, 1.0);
            let mut state = uniform(&mut r, 2, 1.5);
            state.extend(uniform(&mut r, 2, 2.0));
            let e0 = velocity_error(&policy, &mut ws, &c, &state);
            let (h, horizon) = (1e-3, 1.0);
            for _ in 0..(horizon / h) as usize {
                state = rk4(&policy, &mut ws, &c, &state, h);
            }
            let e1 = velocity_error(&policy, &mut ws, &c, &state);
            let predicted = e0 * (-GAIN * horizon).exp();
            assert!(
                (e1 - predicted).abs() < e_tolerance * predicted + 1e-9,
                "e(T) = {e1}, e0·exp(-K_v T) = {predicted}"
            );
            for _ in 0..(14.0 / h) as usize {
                state = rk4(&policy, &mut ws, &c, &state, h);
            }
            let mut attractor = vec![0.0; 2];
            policy.attractor(&c, &mut ws, &mut attractor).unwrap();
            let distance = max_abs_diff(&state[..2], &attractor);
            assert!(
                distance < 1e-3,
                "did not converge: {state:?} vs {attractor:?}"
            );
            assert!(state[2].abs().max(state[3].abs()) < 1e-2);
        }
    }
}
