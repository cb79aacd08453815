//! The CPU features the hand-vectorised kernels may use, detected once at run time.
//!
//! The crate is built for the baseline x86-64 (SSE2), so that the binary runs on any x86-64
//! robot computer. The hot loops of the cost volume (the sweep's feature moments and the
//! photometric ZNCC channel) are also compiled a second time with AVX2 and FMA enabled
//! (`#[target_feature]`), and run that way where [`avx2_fma`] says the CPU has them: the same
//! arithmetic in 8-wide rather than 4-wide vectors, so both give the same bits.

use std::sync::atomic::{AtomicBool, Ordering};

/// Set while [`with_baseline_kernels`] runs.
static BASELINE_ONLY: AtomicBool = AtomicBool::new(false);

/// Whether the kernels may use AVX2 and FMA: the CPU runs them (always `false` off x86-64) and
/// [`with_baseline_kernels`] is not running.
#[inline]
pub fn avx2_fma() -> bool {
    if BASELINE_ONLY.load(Ordering::Relaxed) {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Runs `f` with the baseline builds of the kernels only, process-wide (so that a test can
/// compare them with the AVX2 builds; other work running meanwhile gets the same results,
/// more slowly). Restored on return, also when `f` panics.
pub fn with_baseline_kernels<T>(f: impl FnOnce() -> T) -> T {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            BASELINE_ONLY.store(self.0, Ordering::Relaxed);
        }
    }
    let _restore = Restore(BASELINE_ONLY.swap(true, Ordering::Relaxed));
    f()
}
