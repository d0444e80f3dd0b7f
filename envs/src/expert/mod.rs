//! The experts that generate the demonstrations.

pub mod demo_field;
pub mod limit_cycle;
pub mod modulation;
pub mod pouring;
pub mod reach;
pub mod resolved_acceleration;
pub mod tracking;
