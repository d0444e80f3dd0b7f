//! The layers of the conditioned invertible network `f(·, c)`, each a bijection for every
//! context and weight value: the coupling transforms ([`affine`], [`spline`]) inside
//! [`coupling`] blocks whose parameters come from [`conditioner`] networks, the LU
//! [`mixing`] between blocks, the [`radial`] contractions about context points, the
//! permutation-invariant [`context_set`] encoders that feed the conditioners, and the
//! [`joint_range`] that keeps a robot's policy inside its limits. An affine coupling's
//! parameters may [`taper`] off far from the data.

pub mod affine;
pub mod conditioner;
pub mod context_set;
pub mod coupling;
pub mod joint_range;
pub mod mixing;
pub mod radial;
pub mod spline;
pub mod taper;
