//! Runs the tiled loops of the Cholesky factor and the inverse with 256-bit vectors where the
//! processor has them (AVX: four multiplies or subtractions per instruction instead of two).
//! Only the width changes: each lane still rounds every multiply and every subtraction on its
//! own (no fused multiply-add is enabled), so the bits are those of the plain build.

/// `work()` compiled for AVX when the processor has it, else as built. `work` must be
/// `#[inline(always)]` code (closures are) for the AVX copy to reach its loops.
#[inline(always)]
pub(super) fn dispatch<T>(work: impl FnOnce() -> T) -> T {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor was just found to have AVX, all that `with_avx` requires.
        return unsafe { with_avx(work) };
    }
    work()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn with_avx<T>(work: impl FnOnce() -> T) -> T {
    work()
}
