//! Spatial (6-D) algebra for rigid bodies in the Featherstone / Pinocchio convention.
//!
//! Vectors are stored as `[linear; angular]` pairs of 3-vectors, so every operation is a
//! handful of fixed-size 3×3 / 3×1 products instead of dense 6×6 algebra:
//!
//! - [`Motion`]: a twist `(v, ω)` (velocity, acceleration, joint motion subspace);
//! - [`Force`]: a wrench `(f, n)`, `n` the moment about the frame origin;
//! - [`Inertia`]: a spatial inertia `(m, h = m c, I_o)` about the frame origin;
//! - [`Se3`]: a rigid transform `ᵃMᵦ = (R, p)` acting on all three.
//!
//! Reference: R. Featherstone, *Rigid Body Dynamics Algorithms*, Springer 2008, ch. 2.

mod axis_aligned;
mod force;
mod inertia;
mod motion;
mod se3;

pub use crate::math::skew;
pub use axis_aligned::AxisAlignedRotation;
pub use force::Force;
pub use inertia::Inertia;
pub use motion::Motion;
pub use se3::Se3;
