//! The CPU features the hand-vectorised kernels may use, detected once at run time.
//!
//! The crate is built for the baseline x86-64 (SSE2), so that the binary runs on any x86-64
//! robot computer. The hot loops of the cost volume (the sweep's feature moments and the
//! photometric ZNCC channel) are also compiled a second time with AVX2 and FMA enabled
//! (`#[target_feature]`), and run that way where [`avx2_fma`] says the CPU has them: the same
//! arithmetic in 8-wide rather than 4-wide vectors.

/// Whether this CPU runs AVX2 and FMA instructions (always `false` off x86-64).
#[inline]
pub fn avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
