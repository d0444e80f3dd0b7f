//! The mutable workspace of the algorithms.

use super::Model;
use crate::math::{DMatrix, DVector, Real, Vector3};
use crate::spatial::{Force, Inertia, Motion, Se3};

/// Per-body buffers and results, allocated once by [`Data::new`] so that the algorithms
/// never allocate. Results land in named fields, as in Pinocchio: `tau` (RNEA), `nle`
/// (`C q̇ + g`), `g`, `m` (CRBA, full symmetric), `c` (Coriolis matrix), `ddq` (forward
/// dynamics).
#[derive(Clone, Debug)]
pub struct Data {
    /// `sin qᵢ`, `cos qᵢ`.
    pub(crate) sin_q: Vec<Real>,
    pub(crate) cos_q: Vec<Real>,
    /// `ᵖMᵢ`: body `i` in its parent.
    pub(crate) li_m_i: Vec<Se3>,
    /// `⁰Mᵢ`: body `i` in the base frame.
    pub(crate) o_m_i: Vec<Se3>,
    pub(crate) v: Vec<Motion>,
    pub(crate) a: Vec<Motion>,
    pub(crate) f: Vec<Force>,
    /// Each body's first moment of mass `mₖ cₖ`, base frame (gravity).
    pub(crate) first_moments: Vec<Vector3>,
    /// World-frame quantities of the Coriolis algorithm (the CRBA shares `S` and `Iᶜ`):
    /// `S`, `Ṡ`, and the composites of the inertias `I`, their rates `İ` and the momenta
    /// `I v`.
    pub(crate) s_world: Vec<Motion>,
    pub(crate) s_dot_world: Vec<Motion>,
    pub(crate) ic_world: Vec<Inertia>,
    pub(crate) ic_dot_world: Vec<Inertia>,
    pub(crate) hc_world: Vec<Force>,
    /// Cholesky factor `L` of `M` (lower triangle, the diagonal inverted), forward
    /// dynamics.
    pub(crate) cholesky: DMatrix,
    pub tau: DVector,
    pub nle: DVector,
    pub g: DVector,
    pub m: DMatrix,
    pub c: DMatrix,
    pub ddq: DVector,
}

impl Data {
    pub fn new(model: &Model) -> Self {
        let n = model.nv();
        Self {
            sin_q: vec![0.0; n],
            cos_q: vec![1.0; n],
            li_m_i: vec![Se3::identity(); n],
            o_m_i: vec![Se3::identity(); n],
            v: vec![Motion::zero(); n],
            a: vec![Motion::zero(); n],
            f: vec![Force::zero(); n],
            first_moments: vec![Vector3::zeros(); n],
            s_world: vec![Motion::zero(); n],
            s_dot_world: vec![Motion::zero(); n],
            ic_world: vec![Inertia::zero(); n],
            ic_dot_world: vec![Inertia::zero(); n],
            hc_world: vec![Force::zero(); n],
            cholesky: DMatrix::zeros(n, n),
            tau: DVector::zeros(n),
            nle: DVector::zeros(n),
            g: DVector::zeros(n),
            m: DMatrix::zeros(n, n),
            c: DMatrix::zeros(n, n),
            ddq: DVector::zeros(n),
        }
    }
}
