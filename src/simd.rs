//! Runs hot loops (the Gaussian process's Cholesky factor and inverse, the HMM's general
//! recursions, the particle filter's per-feature exponents) with 256-bit vectors where the
//! processor has them (AVX: four multiplies or additions per instruction instead of two).
//! Only the width changes: each lane still rounds every multiply and every addition on its
//! own (no fused multiply-add is enabled), so the bits are those of the plain build.
//!
//! A `#[target_feature]` function only widens code inlined into it, and a closure passed to a
//! generic one is not reliably inlined (the earlier generic dispatch ran the plain build), so
//! each kernel gets a named copy made by [`with_avx!`].

/// Defines `fn $name($args) -> $out` that runs the `#[inline(always)]` function `$work` compiled
/// for AVX when the processor has it, else as built.
macro_rules! with_avx {
    ($(#[$doc:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),*) -> $out:ty = $work:ident) => {
        $(#[$doc])*
        $vis fn $name($($arg: $ty),*) -> $out {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx")]
                fn widened($($arg: $ty),*) -> $out {
                    $work($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx") {
                    // SAFETY: the processor was just found to have AVX, all `widened` needs.
                    return unsafe { widened($($arg),*) };
                }
            }
            $work($($arg),*)
        }
    };
}
pub(crate) use with_avx;
