//! The register blocks of [`super`]'s kernels in AVX2 and FMA intrinsics.
//!
//! For one tap row `(a, c)` the `kW·Ci` inputs a cell reads are contiguous in the
//! channels-last input (`k = e·Ci + ci`), and so are their weights (`w[a, c, e, ci, :]`), so a
//! block is one loop over `k` with no index arithmetic beyond two pointer steps:
//!
//! ```text
//! acc[r] += Σ_k x[r·step + k] · w[k, :]        (step = sW·Ci between neighbouring cells)
//! ```
//!
//! `Co = 8` and `Co = 16` keep `R × Co/8` accumulators, one broadcast input and `Co/8` weight
//! vectors in registers. `Co = 4` (the fine head's first layer) would fill half a vector, so
//! there each vector holds the taps `k` and `k + 1` side by side: lanes `(2j, 2j + 1)` are
//! output channel `j` for the two taps, one 8-byte broadcast `(x[k], x[k + 1], ...)` feeds
//! them, the weights are interleaved once per layer ([`pack_pairs_co4`]) and a cell's
//! neighbouring lanes are summed when it is stored.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::{
    __m256, _mm256_broadcast_ss, _mm256_castpd_ps, _mm256_fmadd_ps, _mm256_loadu_ps,
    _mm256_set1_pd, _mm256_setzero_ps, _mm256_storeu_ps,
};

/// Lanes of an AVX2 `f32` vector.
pub(super) const LANES: usize = 8;

/// Output channels of the paired kernel.
pub(super) const CO_PAIRED: usize = 4;

/// `acc[r][v] += Σ_{k < len} x[r·step + k] · w[k·8V + 8v ..][..8]`.
///
/// # Safety
/// AVX2 and FMA; `x` readable at `r·step + k` and `w` at `k·8V + 8V − 1` for every `r < R`,
/// `k < len`.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn block<const V: usize, const R: usize>(
    x: *const f32,
    step: usize,
    w: *const f32,
    len: usize,
    acc: &mut [[__m256; V]; R],
) {
    for k in 0..len {
        let mut wv = [_mm256_setzero_ps(); V];
        for (v, wv) in wv.iter_mut().enumerate() {
            *wv = _mm256_loadu_ps(w.add((k * V + v) * LANES));
        }
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let xv = _mm256_broadcast_ss(&*x.add(r * step + k));
            for (a, &wj) in acc_r.iter_mut().zip(&wv) {
                *a = _mm256_fmadd_ps(xv, wj, *a);
            }
        }
    }
}

/// Stores `acc[r]` at `y[r·8V ..]`.
///
/// # Safety
/// AVX2; `y` writable for `R·8V` values.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn store<const V: usize, const R: usize>(acc: &[[__m256; V]; R], y: *mut f32) {
    for (r, acc_r) in acc.iter().enumerate() {
        for (v, a) in acc_r.iter().enumerate() {
            _mm256_storeu_ps(y.add((r * V + v) * LANES), *a);
        }
    }
}

/// The weights of one tap row, `len = kW·Ci` taps of 4 channels each (`w[k·4 + j]`), as pairs of
/// taps: pair `p` is the 8 values `(w[2p, j], w[2p + 1, j])` for `j = 0..4`, a missing last
/// odd tap's weights zero.
pub(super) fn pack_pairs_co4(w: &[f32], len: usize) -> Vec<f32> {
    let pairs = len.div_ceil(2);
    let mut packed = vec![0f32; pairs * LANES];
    for (k, wk) in w[..len * CO_PAIRED].chunks_exact(CO_PAIRED).enumerate() {
        let (p, half) = (k / 2, k % 2);
        for (j, &v) in wk.iter().enumerate() {
            packed[p * LANES + 2 * j + half] = v;
        }
    }
    packed
}

/// The paired `Co = 4` block: `acc[r]` lanes `(2j, 2j + 1)` gather output channel `j` of cell
/// `r` over the even and the odd taps `k < len`; `w` is [`pack_pairs_co4`]'s.
///
/// # Safety
/// AVX2 and FMA; `x` readable at `r·step + k` for every `r < R`, `k < len`, and `w` for
/// `len.div_ceil(2)·8` values.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn block_co4<const R: usize>(
    x: *const f32,
    step: usize,
    w: *const f32,
    len: usize,
    acc: &mut [__m256; R],
) {
    let pairs = len / 2;
    for p in 0..pairs {
        let wv = _mm256_loadu_ps(w.add(p * LANES));
        for (r, a) in acc.iter_mut().enumerate() {
            // (x[2p], x[2p + 1]) in every 8-byte lane pair
            // (an unaligned 8-byte read: a `&f64` to it would have to be aligned)
            let pair = x.add(r * step + 2 * p).cast::<f64>().read_unaligned();
            let xv = _mm256_castpd_ps(_mm256_set1_pd(pair));
            *a = _mm256_fmadd_ps(xv, wv, *a);
        }
    }
    if len % 2 == 1 {
        // the odd tap alone: its partner's weights are zero, so the lanes read x[len − 1] twice
        let wv = _mm256_loadu_ps(w.add(pairs * LANES));
        for (r, a) in acc.iter_mut().enumerate() {
            let xv = _mm256_broadcast_ss(&*x.add(r * step + len - 1));
            *a = _mm256_fmadd_ps(xv, wv, *a);
        }
    }
}

/// Stores the paired accumulators as `R` cells of 4 channels at `y`: channel `j` of cell `r`
/// is lane `2j` plus lane `2j + 1` of `acc[r]`.
///
/// # Safety
/// AVX2; `y` writable for `R·4` values.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn store_co4<const R: usize>(acc: &[__m256; R], y: *mut f32) {
    let mut lanes = [0f32; LANES];
    for (r, a) in acc.iter().enumerate() {
        _mm256_storeu_ps(lanes.as_mut_ptr(), *a);
        for j in 0..CO_PAIRED {
            *y.add(r * CO_PAIRED + j) = lanes[2 * j] + lanes[2 * j + 1];
        }
    }
}
