//! # ciflow-bridge
//!
//! The Zenoh server and wire protocol that expose every `ciflow-envs` task as a
//! Gymnasium environment.
