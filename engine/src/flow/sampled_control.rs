//! The policy's acceleration command held for one control period: where the learned field
//! is stiff along the motion, the command is shortened so that one period cannot overshoot.
//!
//! The continuous-time law `q̈ = (∂v/∂q) q̇ + K_v (v(q) − q̇)` ([`crate::flow::Policy::acceleration`])
//! depends on `q̇` through the gain matrix `(∂v/∂q) − K_v I`. A controller holds the command
//! for a period `Δt`, an explicit Euler step of the velocity loop: along the unit direction
//! of motion `u = q̇ / ‖q̇‖` the velocity is multiplied per period by `1 − Δt g`,
//!
//! `g = K_v − σ`, `σ = uᵀ (∂v/∂q) u`,
//!
//! which flips sign for `Δt g > 1` and grows for `Δt g > 2`. `σ` is the rate at which the
//! field slows down along the motion; where a field learned from data slows sharply (seams
//! at the edge of the demonstrations' box, e.g. `σ ≈ −180 /s` for an obstacle policy) a
//! 100 Hz loop locks into a period-2 oscillation, `q̇ → −q̇`, and never arrives although the
//! continuous-time loop does (up to 9% of `ciflow stability --robot-loop`'s far starts for
//! the obstacle policies).
//!
//! The guard scales the command's component along `u` by `s = min(1, 1 / (Δt g))`: at
//! worst the period is deadbeat along the motion (factor `1 − Δt g s ≥ 0`), and wherever
//! `Δt g ≤ 1` — everywhere the field is not stiff, `Δt K_v = 0.1` at the defaults — the
//! command is untouched, so the continuous-time claims of [`crate::flow`] carry over
//! exactly there. `g` needs no extra pass through the network: without a joint range the
//! command is affine in `q̇`, `q̈ − K_v v = ((∂v/∂q) − K_v I) q̇`, so
//! `g = −q̇ᵀ (q̈ − K_v v) / ‖q̇‖²`.

/// Scales the component of `acceleration` (the command `q̈` of the continuous-time law at
/// `q̇ = velocity_measured`, with `v(q) = velocity_desired` and gain `K_v`) along the
/// direction of motion so that one period of `period` seconds cannot overshoot; see the
/// module docs. A robot at rest, or a period that does not overshoot, keeps its command.
pub fn limit_overshoot(
    velocity_measured: &[f64],
    velocity_desired: &[f64],
    velocity_gain: f64,
    period: f64,
    acceleration: &mut [f64],
) {
    let speed_squared: f64 = velocity_measured.iter().map(|v| v * v).sum();
    if speed_squared == 0.0 {
        return;
    }
    // q̇ᵀ q̈ and q̇ᵀ v in one pass: q̇ᵀ (q̈ − K_v v) = −g ‖q̇‖².
    let (along_command, along_desired) = velocity_measured
        .iter()
        .zip(acceleration.iter().zip(velocity_desired))
        .fold((0.0, 0.0), |(qa, qv), (qd, (a, v))| {
            (qa + qd * a, qv + qd * v)
        });
    let gain = (velocity_gain * along_desired - along_command) / speed_squared;
    if period * gain <= 1.0 {
        return;
    }
    // q̈ ← q̈ − (1 − s) (uᵀ q̈) u, s = 1 / (Δt g).
    let shrink = (1.0 - 1.0 / (period * gain)) * along_command / speed_squared;
    for (a, qd) in acceleration.iter_mut().zip(velocity_measured) {
        *a -= shrink * qd;
    }
}
