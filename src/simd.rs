//! Runs hot loops (the Gaussian process's Cholesky factor and inverse, the HMM's general
//! recursions, the particle filter's per-feature exponents) with 256-bit vectors where the
//! processor has them (AVX: four multiplies or additions per instruction instead of two), and
//! for the Cholesky factor and inverse a copy with 512-bit tiles where there is AVX-512F.
//! Only the width changes: each lane still rounds every multiply and every addition on its
//! own (Rust never fuses a multiply and an addition unasked, even where AVX-512 brings FMA), so
//! the bits are those of the plain build.
//!
//! A `#[target_feature]` function only widens code inlined into it, and a closure passed to a
//! generic one is not reliably inlined (the earlier generic dispatch ran the plain build), so
//! each kernel gets a named copy made by [`with_avx!`].

/// Defines `fn $name($args) -> $out` that runs the `#[inline(always)]` function `$work` compiled
/// for AVX when the processor has it, else as built; with `avx512 = $wide`, runs `$wide` (a
/// form of `$work` with wider register tiles, the same chains) compiled for AVX-512 where the
/// processor has that. AVX-512 brings FMA instructions too, but Rust never fuses a multiply and
/// an addition on its own, so every lane still rounds both.
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
    ($(#[$doc:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),*) -> $out:ty = $work:ident,
        avx512 = $wide:expr) => {
        $(#[$doc])*
        $vis fn $name($($arg: $ty),*) -> $out {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                fn widest($($arg: $ty),*) -> $out {
                    $wide($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the processor was just found to have AVX-512F, all `widest` needs.
                    return unsafe { widest($($arg),*) };
                }
            }
            $crate::simd::with_avx!(fn narrower($($arg: $ty),*) -> $out = $work);
            narrower($($arg),*)
        }
    };
}
pub(crate) use with_avx;
