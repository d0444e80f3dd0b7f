//! The neural-network numerics of `ciflow_engine::nn` in tch.

pub mod mlp;
