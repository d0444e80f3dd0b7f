//! The layers of `ciflow_engine::flow::layers` in tch, file for file.

pub mod affine;
pub mod coupling;
pub mod joint_range;
pub mod mixing;
pub mod radial;
pub mod spline;
pub mod taper;
