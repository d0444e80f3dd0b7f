//! The names of a checkpoint's parameters, defined once for the pure-Rust loaders,
//! [`FlowConfig::parameter_shapes`](super::config::FlowConfig::parameter_shapes) and the
//! tch trainer. A parameter's name is its path of segments joined with `.` — how tch's
//! `VarStore` names a variable created under `root / a / b` as `var(c)`, and how the
//! safetensors file stores it.

use std::fmt::Display;

/// The latent dynamics: `latent.<parameter>`.
pub const LATENT: &str = "latent";
/// `log σ` of the transition noise and `log σ₀` of the initial state.
pub const LOG_SIGMA: &str = "log_sigma";
pub const LOG_SIGMA0: &str = "log_sigma0";
/// `F` and `W` of the linear attractor `A = −(F Fᵀ + ε I) + (W_l − W_lᵀ)`.
pub const FACTOR: &str = "factor";
pub const SKEW: &str = "skew";
/// The scalars of the limit cycle (`ρ* = e^r`, `α = −e^a`, `ω`) and the saturated go-to
/// (`λ = ε + e^a`, `v = e^b`).
pub const LOG_RADIUS: &str = "log_radius";
pub const LOG_RATE: &str = "log_rate";
pub const LOG_SPEED: &str = "log_speed";
pub const OMEGA: &str = "omega";

/// Block `i` of the network: `layers.<i>.mixing.*`, `layers.<i>.conditioner.*`,
/// `layers.<i>.local.<k>.*`.
pub const LAYERS: &str = "layers";
pub const MIXING: &str = "mixing";
pub const CONDITIONER: &str = "conditioner";
pub const LOCAL: &str = "local";
/// The LU mixing `y = L U x + b`: `L`, `U`, `log diag U`, `b`.
pub const LOWER: &str = "lower";
pub const UPPER: &str = "upper";
pub const LOG_DIAG: &str = "log_diag";
pub const BIAS: &str = "bias";
/// A dense layer `j` of an MLP: `<mlp>.<j>.weight`, `<mlp>.<j>.bias` (tch's `nn::linear`).
pub const WEIGHT: &str = "weight";

/// Radial contraction layer `l`: `radial.<l>.strength`, `radial.<l>.width`.
pub const RADIAL: &str = "radial";
pub const STRENGTH: &str = "strength";
pub const WIDTH: &str = "width";

/// Set `k`'s encoder: `sets.<k>.encoder.*`.
pub const SETS: &str = "sets";
pub const ENCODER: &str = "encoder";

/// The behaviour-cloning baseline's MLP: `net.*`.
pub const NET: &str = "net";

/// The name of the parameter at `segments`: `["layers", 3, "mixing"]` → `layers.3.mixing`.
pub fn name(segments: &[&dyn Display]) -> String {
    segments
        .iter()
        .map(|s| s.to_string())
        .collect::<Vec<_>>()
        .join(".")
}
