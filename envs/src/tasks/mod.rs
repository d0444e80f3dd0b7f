//! The tasks, one module each, documented like Gymnasium environments.

pub mod arm_start;
pub mod lasa;
pub mod limit_cycle;
pub mod obstacle_avoidance;
pub mod pouring;
pub mod reach;
