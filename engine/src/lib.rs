//! # ciflow-engine
//!
//! The numerical core of ciflow, free of libtorch:
//!
//! - [`model`] and [`algorithm`]: serial-chain rigid-body dynamics
//!   `M(q) q̈ + C(q, q̇) q̇ + g(q) = τ + τ_ext` (RNEA, CRBA, Coriolis, forward dynamics),
//!   with the Franka Panda and a planar point mass behind one [`robot::Robot`] trait;
//! - [`control`]: the computed-torque layer `τ = C q̇ + g + M q̈_des`;
//! - [`sim`]: fixed-step simulation with perturbations in simulated time;
//! - [`flow`]: stable conditioned invertible-network policies (inference only; training
//!   lives in the `ciflow-train` crate, the only libtorch user);
//! - [`nn`]: the neural-network numerics the policies run on (dual numbers, dense layers
//!   with an AVX2 kernel);
//! - [`training`]: the settings of a training run, so tasks can carry their recipes;
//! - [`allocations`]: counting heap allocations, for the tests of allocation-free steps.

pub mod algorithm;
pub mod allocations;
pub mod control;
pub mod flow;
pub mod math;
pub mod model;
pub mod nn;
pub mod robot;
pub mod sim;
pub mod spatial;
pub mod training;
