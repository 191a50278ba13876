//! Run-time choice of vector instructions for a few hot loops.
//!
//! The default build targets baseline x86-64 (SSE2), so loops the compiler vectorises use 4 lanes of `f32`.
//! [`dispatch_simd!`] compiles one generic function body three times (AVX-512F, AVX2 + FMA, baseline) and
//! picks the widest the CPU has, once per call. The results are the same bit for bit on every path: Rust
//! never contracts `a * b + c` into a fused multiply-add on its own, and the vector square root, adds and
//! multiplies round as the scalar ones do.

/// Defines `fn $name(args) -> ret` (or without a result) that calls `$generic(args)` compiled for the widest of AVX-512F,
/// AVX2 + FMA and the baseline that the CPU supports. `$generic` should be `#[inline(always)]` so that each
/// copy is compiled with its instruction set.
macro_rules! dispatch_simd {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? = $generic:path;) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                unsafe fn avx512($($arg: $ty),*) $(-> $ret)? {
                    $generic($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                unsafe fn avx2($($arg: $ty),*) $(-> $ret)? {
                    $generic($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU supports the features the function was compiled for.
                    return unsafe { avx512($($arg),*) };
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: the CPU supports the features the function was compiled for.
                    return unsafe { avx2($($arg),*) };
                }
            }
            $generic($($arg),*)
        }
    };
}

pub(crate) use dispatch_simd;
