//! Stable conditioned invertible-network policies (C-IFlows; Urain et al. 2020,
//! "Structured policy representation: imposing stability in arbitrarily conditioned
//! dynamic systems"), inference in pure Rust.
//!
//! # Model
//!
//! `z_{k-1} = f⁻¹(y_{k-1}, c)`, `z_k ~ p(z_k | z_{k-1})`, `y_k = f(z_k, c)`, where the
//! latent dynamics ([`latent`]) are globally asymptotically stable *in discrete time* for
//! every parameter value (exact steps `exp(A dt)`, exact radial step of the limit cycle)
//! and `f(·, c)` ([`network`]) is a bijection for every context and every weight value
//! (LU mixing with `exp` diagonal, coupling layers with bounded affine or monotone spline
//! transforms). The exact transition density is
//!
//! `p(y_k | y_{k-1}, c) = p(z_k | z_{k-1}) |det ∂f(z_k, c)/∂z_k|⁻¹`,
//!
//! with the normalisation of states and contexts inside `f`, so log-likelihoods are in
//! the data's own units.
//!
//! **Which context.** A transition uses one context for both `f⁻¹(y_{k-1}, ·)` and
//! `f(·, c)`: `c = c_{k-1}`, the context known when the action for step `k` is chosen
//! (the paper's likelihood, Appendix "Behavioural Cloning Learning"). Using the same `c`
//! on both sides keeps the transition a change of variables of the latent one; using
//! `c_k` would condition on the future.
//!
//! **Stability in observation space.** For fixed `c` the noise-free map
//! `y ↦ f(μ(f⁻¹(y, c)), c)` is conjugate to the latent map `μ`, so every trajectory
//! converges to `f(0, c)` (go-to; `= target(c)` when the target is part of the context)
//! or to the orbit `f({ρ = ρ*}, c)` (limit cycle), for every weight value.
//! `ciflow_evaluation::stability` measures it by rolling out in observation space.
//!
//! # Closed loop with the computed-torque layer
//!
//! The robot runs `q̈ = q̈_des + M(q)⁻¹ τ_ext` under computed torque, and the policy
//! commands ([`Policy::acceleration`])
//! `q̈_des = (∂v_des/∂q) q̇ + K_v (v_des(q) - q̇)` with `v_des = J_f v ∘ f⁻¹`, the
//! continuous-time field whose time-`dt` flow is the policy's mean step. What we claim,
//! for a fixed context:
//!
//! 1. *No saturation, `τ_ext = 0`.* The velocity error `e = q̇ - v_des(q)` obeys
//!    `ė = -K_v e` exactly, so `e(t) = e^{-K_v t} e(0)` for every initial state. Started
//!    on `q̇ = v_des(q)` the robot follows the learned flow and converges to the
//!    attractor from every `q`. From any `(q, q̇)` the equilibrium `(q*, 0)` is locally
//!    exponentially stable, and every trajectory along which `‖∂f⁻¹/∂y‖` stays bounded
//!    converges (`ż = v(z) + J_f⁻¹ e` with the latent Lyapunov function
//!    `U = ‖z‖²`, `U̇ ≤ -2ε U + 2‖z‖ G ‖e‖` and `e` integrable). That bound holds
//!    globally for spline couplings (identity tails, bounded conditioner Jacobian) with
//!    LU mixing; for affine couplings `‖∂f⁻¹/∂y‖` can grow with `|y|`, so convergence is
//!    global only for trajectories that stay bounded. Tested with a double integrator
//!    `q̈ = q̈_des` (tests/flow_closed_loop.rs).
//! 2. *Bounded `τ_ext`.* `ė = -K_v e + M⁻¹ τ_ext`, so `‖e‖ ≤ sup ‖M⁻¹ τ_ext‖ / K_v`
//!    ultimately; once the disturbance stops, case 1 applies from the state it left.
//! 3. *Torque saturation.* While the computed torque stays inside the limits nothing
//!    changes. Once it saturates, `q̈ ≠ q̈_des` and no guarantee remains: stability of the
//!    saturated loop is only measured (the robot-loop stability check), not claimed.
//! 4. *Sampled control.* A controller holds each command for its period `Δt`; where the
//!    field slows down along the motion faster than `1/Δt − K_v` the held command would
//!    overshoot, and a 100 Hz loop can lock into `q̇ → −q̇` short of the attractor.
//!    [`Policy::acceleration_held`] shortens the command along the motion there
//!    ([`sampled_control`]) and leaves it exactly as above everywhere else.
//!
//! The limit cycle's latent field is undefined at the origin of the cycle plane
//! (`ρ = 0`); the discrete step maps it onto `ρ > 0`, the continuous loop claims exclude it.

pub mod baseline;
pub mod checkpoint;
pub mod end_stop_hold;
pub mod error;
pub mod latent;
pub mod layers;
pub mod mean_dynamics;
pub mod network;
pub mod policy;
pub mod sampled_control;

pub use baseline::BehaviourCloning;
pub use checkpoint::config::{
    AFFINE_SCALE_BOUND, BaselineConfig, Bounds, CheckpointConfig, CouplingKind, FlowConfig, Goal,
    LatentKind, Normalisation,
};
pub use checkpoint::weights::{Tensor, Weights};
pub use end_stop_hold::EndStopHold;
pub use error::{FlowError, FlowResult};
pub use layers::context_set::{ContextSet, LocalConfig, SetEncoderConfig};
pub use layers::joint_range::JointRange;
pub use layers::radial::ContractionConfig;
pub use mean_dynamics::MeanDynamics;
pub use policy::{Policy, PolicyWorkspace};
