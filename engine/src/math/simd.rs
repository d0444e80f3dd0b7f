//! Run-time choice of the instruction set.
//!
//! The release build targets baseline x86-64 (SSE2) so that it runs on any x86-64 CPU;
//! hot loops get AVX2 and fused multiply-adds (the networks' layers AVX-512 as well)
//! where the CPU has them by being compiled again for those features and picked at run
//! time.

/// Whether this CPU has AVX2 and FMA (detected once, then cached by the standard library).
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) fn has_avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Whether this CPU has AVX-512F (detected once, then cached by the standard library).
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) fn has_avx512f() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

/// `run()`, compiled for AVX2 and FMA when the CPU has them (`run` and everything it
/// inlines, so its helpers should be `#[inline(always)]`).
///
/// No multiply-add is fused unless the code asks for it (`mul_add`), so both versions
/// round alike and return the same bits: the wider registers only process more lanes of
/// the same operations at once.
#[inline(always)]
pub(crate) fn with_avx2_fma<R>(run: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // Both features were just detected, as `Simd` requires.
        return Simd::Avx2Fma.compiled(run);
    }
    run()
}

/// `run()` compiled for AVX2 and FMA (callable only where the CPU has them).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn compiled_for_avx2_fma<R>(run: impl FnOnce() -> R) -> R {
    run()
}

/// `run()` compiled for AVX-512F besides AVX2 and FMA (callable only where the CPU has
/// all three).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f")]
fn compiled_for_avx512<R>(run: impl FnOnce() -> R) -> R {
    run()
}

/// Which instruction set a hot loop runs on, chosen once per call by [`Simd::detect`] and
/// carried down so that kernels and the code compiled around them agree. A value other
/// than `Portable` is only made once its features were detected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Simd {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
    /// AVX-512F besides AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Simd {
    /// The widest instruction set of this CPU.
    #[inline]
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if has_avx2_fma() {
            return if has_avx512f() {
                Self::Avx512
            } else {
                Self::Avx2Fma
            };
        }
        Self::Portable
    }

    /// Whether fused multiply-adds are single instructions (else `mul_add` is a library
    /// call, and code should round twice instead).
    #[inline(always)]
    pub(crate) fn fused(self) -> bool {
        self != Self::Portable
    }

    /// `run()`, compiled for this instruction set, so that its loops vectorise for it
    /// (`run` and everything it inlines, so its helpers should be `#[inline(always)]`,
    /// closures included). Each lane rounds as a scalar would: a wider register only
    /// processes more lanes of the same operations at once.
    #[inline(always)]
    pub(crate) fn compiled<R>(self, run: impl FnOnce() -> R) -> R {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the features were detected before this value was made.
            Self::Avx2Fma => unsafe { compiled_for_avx2_fma(run) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            Self::Avx512 => unsafe { compiled_for_avx512(run) },
            Self::Portable => run(),
        }
    }
}
