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
    /// The RNEA's velocities, accelerations and forces; the CRBA carries its columns'
    /// forces `Iᶜᵢ Sᵢ` in `f`.
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
    /// Asks the CPU to bring the buffers the dynamics of a time step use into cache, all
    /// at once: a workspace idle while thousands of others ran is out of cache, and
    /// its buffers are separate allocations the first algorithm would otherwise miss on
    /// one after another. Only a hint: it changes no value.
    pub fn prefetch(&self) {
        #[cfg(target_arch = "x86_64")]
        fn lines<T>(buffer: &[T]) {
            let start = buffer.as_ptr().cast::<i8>();
            for offset in (0..size_of_val(buffer)).step_by(64) {
                // SAFETY: a prefetch reads nothing and never faults; the address is
                // inside `buffer` anyway.
                unsafe {
                    std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                        start.add(offset),
                    )
                };
            }
        }
        // Elsewhere the hardware prefetchers are left to it.
        #[cfg(not(target_arch = "x86_64"))]
        fn lines<T>(_: &[T]) {}
        lines(&self.sin_q);
        lines(&self.cos_q);
        lines(&self.li_m_i);
        lines(&self.o_m_i);
        lines(&self.v);
        lines(&self.a);
        lines(&self.f);
        lines(&self.s_world);
        lines(&self.ic_world);
        lines(self.cholesky.as_slice());
        lines(self.tau.as_slice());
        lines(self.nle.as_slice());
        lines(self.m.as_slice());
        lines(self.ddq.as_slice());
    }

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
