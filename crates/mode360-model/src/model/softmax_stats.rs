//! One pixel's softmax over its hypothesis costs, for the fused inference readout
//! ([`super::regression::regress_inference`]): the unnormalized probabilities in place and the
//! sums the readout needs,
//!
//! ```text
//! e_i = exp(c_i − max_j c_j),   sum = Σ_i e_i,   moment = Σ_i i·e_i,   argmax = first i of max e_i
//! ```
//!
//! so `p_i = e_i / sum` and the expected index is `moment / sum`. On x86-64 CPUs with AVX2 and
//! FMA eight hypotheses at a time, `exp` by the Cephes polynomial ([`exp_avx2`], within 2 ulp of
//! the library's `expf` over the range used here); elsewhere one at a time.

/// What [`softmax_in_place`] returns besides the exponentials.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftmaxSums {
    /// `Σ_i e_i` (at least 1: the maximum's own term).
    pub sum: f32,
    /// `Σ_i i·e_i`.
    pub moment: f32,
    /// The first index of the largest `e_i`.
    pub argmax: usize,
}

/// Replaces the costs `c` by `exp(c_i − max c)` and returns their [`SoftmaxSums`]; `c` must not
/// be empty.
pub fn softmax_in_place(c: &mut [f32]) -> SoftmaxSums {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: AVX2 and FMA were detected.
            return unsafe { softmax_avx2(c) };
        }
    }
    softmax_scalar(c)
}

/// [`softmax_in_place`] one hypothesis at a time.
pub fn softmax_scalar(c: &mut [f32]) -> SoftmaxSums {
    let max = c.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    finish_from(c, 0, max, 0.0, 0.0)
}

/// Exponentiates `c[first..]` one at a time, adds them to the sums of `c[..first]` and finds the
/// argmax of all.
fn finish_from(c: &mut [f32], first: usize, max: f32, sum: f32, moment: f32) -> SoftmaxSums {
    let (mut sum, mut moment) = (sum, moment);
    for (i, x) in c.iter_mut().enumerate().skip(first) {
        *x = (*x - max).exp();
        sum += *x;
        moment += *x * i as f32;
    }
    SoftmaxSums {
        sum,
        moment,
        argmax: first_argmax(c),
    }
}

/// The first index of the largest value (0 for an empty slice).
fn first_argmax(e: &[f32]) -> usize {
    let mut arg = 0;
    for (i, &v) in e.iter().enumerate().skip(1) {
        if v > e[arg] {
            arg = i;
        }
    }
    arg
}

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::{
    __m128, __m256, _mm256_add_epi32, _mm256_add_ps, _mm256_and_ps, _mm256_castps256_ps128,
    _mm256_castsi256_ps, _mm256_cmp_ps, _mm256_cvtps_epi32, _mm256_extractf128_ps, _mm256_floor_ps,
    _mm256_fmadd_ps, _mm256_fnmadd_ps, _mm256_loadu_ps, _mm256_max_ps, _mm256_min_ps,
    _mm256_mul_ps, _mm256_set1_epi32, _mm256_set1_ps, _mm256_setr_ps, _mm256_setzero_ps,
    _mm256_slli_epi32, _mm256_storeu_ps, _mm256_sub_ps, _mm_add_ps, _mm_cvtss_f32, _mm_max_ps,
    _mm_movehl_ps, _mm_shuffle_ps, _CMP_GE_OQ,
};

/// Lanes of an AVX2 `f32` vector.
const LANES: usize = 8;

/// Cephes `expf`: `exp(x) = 2^n · exp(r)`, `n = round(x / ln 2)`, `r = x − n ln 2` (in two
/// parts), `exp(r)` by a degree-7 polynomial; `x` clamped to `[−87.3, 88.7]`, and zero below
/// (where the library's result is a denormal under 1e-38 or zero).
///
/// # Safety
/// AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn exp_avx2(x: __m256) -> __m256 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const X_MIN: f32 = -87.3;
    const X_MAX: f32 = 88.7;
    const P: [f32; 6] = [
        1.987_569_1e-4,
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        1.666_666_5e-1,
        0.5,
    ];
    const F32_EXPONENT_BIAS: i32 = 127;
    const F32_MANTISSA_BITS: i32 = 23;
    let above_min = _mm256_cmp_ps::<_CMP_GE_OQ>(x, _mm256_set1_ps(X_MIN));
    let x = _mm256_min_ps(
        _mm256_max_ps(x, _mm256_set1_ps(X_MIN)),
        _mm256_set1_ps(X_MAX),
    );
    let n = _mm256_floor_ps(_mm256_fmadd_ps(
        x,
        _mm256_set1_ps(LOG2E),
        _mm256_set1_ps(0.5),
    ));
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_HI), x);
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_LO), r);
    let mut y = _mm256_set1_ps(P[0]);
    for &coef in &P[1..] {
        y = _mm256_fmadd_ps(y, r, _mm256_set1_ps(coef));
    }
    // y r² + r + 1
    let y = _mm256_fmadd_ps(
        y,
        _mm256_mul_ps(r, r),
        _mm256_add_ps(r, _mm256_set1_ps(1.0)),
    );
    let two_n = _mm256_castsi256_ps(_mm256_slli_epi32::<F32_MANTISSA_BITS>(_mm256_add_epi32(
        _mm256_cvtps_epi32(n),
        _mm256_set1_epi32(F32_EXPONENT_BIAS),
    )));
    _mm256_and_ps(_mm256_mul_ps(y, two_n), above_min)
}

/// A vector's lanes folded by `op` (an associative 4-lane operation: sum, max).
///
/// # Safety
/// AVX2.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn lane_fold(v: __m256, op: impl Fn(__m128, __m128) -> __m128) -> f32 {
    let q = op(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let q = op(q, _mm_movehl_ps(q, q));
    _mm_cvtss_f32(op(q, _mm_shuffle_ps::<0b01>(q, q)))
}

/// [`softmax_in_place`] eight hypotheses at a time (the last `len % 8` one at a time).
///
/// # Safety
/// AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn softmax_avx2(c: &mut [f32]) -> SoftmaxSums {
    let full = c.len() / LANES * LANES;
    let mut max_v = _mm256_set1_ps(f32::NEG_INFINITY);
    for chunk in c[..full].chunks_exact(LANES) {
        max_v = _mm256_max_ps(max_v, _mm256_loadu_ps(chunk.as_ptr()));
    }
    let max = c[full..]
        .iter()
        .copied()
        .fold(lane_fold(max_v, |a, b| _mm_max_ps(a, b)), f32::max);
    let max_b = _mm256_set1_ps(max);
    let (mut sum_v, mut moment_v) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    let mut index = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    let step = _mm256_set1_ps(LANES as f32);
    for chunk in c[..full].chunks_exact_mut(LANES) {
        let e = exp_avx2(_mm256_sub_ps(_mm256_loadu_ps(chunk.as_ptr()), max_b));
        _mm256_storeu_ps(chunk.as_mut_ptr(), e);
        sum_v = _mm256_add_ps(sum_v, e);
        moment_v = _mm256_fmadd_ps(e, index, moment_v);
        index = _mm256_add_ps(index, step);
    }
    let add = |a, b| _mm_add_ps(a, b);
    finish_from(
        c,
        full,
        max,
        lane_fold(sum_v, add),
        lane_fold(moment_v, add),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Costs like a pixel's: a smooth background, a sharp mode, a flat far end and values far
    /// below the maximum (whose exponentials underflow).
    fn costs(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let t = i as f32 / n as f32;
                let mode = if i % 37 == (seed as usize % 37) {
                    6.0
                } else {
                    0.0
                };
                let deep = if i % 11 == 3 { -120.0 } else { 0.0 };
                (t * 9.0 + seed as f32).sin() * 3.0 + mode + deep
            })
            .collect()
    }

    #[test]
    fn the_vector_path_matches_the_library_exp() {
        for n in [1, 7, 8, 9, 48, 96, 100] {
            for seed in 0..5 {
                let c = costs(n, seed);
                let max = c.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                let (mut fast, mut slow) = (c.clone(), c.clone());
                let f = softmax_in_place(&mut fast);
                let s = softmax_scalar(&mut slow);
                for (i, (a, b)) in fast.iter().zip(&slow).enumerate() {
                    // (below 1e-37 the library returns denormals, the vector path zero)
                    assert!(
                        (a - b).abs() <= 4.0 * f32::EPSILON * b + 1e-37,
                        "n {n} seed {seed} hypothesis {i}: {a} against {b}"
                    );
                    // an exponential of a cost at least 87 below the maximum is at most 1e-38
                    if c[i] - max < -90.0 {
                        assert!(*a < 1e-37, "n {n}: {a} for a cost {} below", max - c[i]);
                    }
                }
                assert!((f.sum - s.sum).abs() <= 1e-5 * s.sum, "n {n}: {f:?} {s:?}");
                assert!((f.moment - s.moment).abs() <= 1e-5 * s.moment.max(1.0));
                assert_eq!(f.argmax, s.argmax, "n {n} seed {seed}");
                assert!(f.sum >= 1.0);
            }
        }
    }

    #[test]
    fn ties_take_the_first_index() {
        let mut c = vec![0.0f32; 24];
        c[5] = 2.0;
        c[17] = 2.0;
        let s = softmax_in_place(&mut c);
        assert_eq!(s.argmax, 5);
        assert!((c[5] - 1.0).abs() < 1e-7 && (c[17] - 1.0).abs() < 1e-7);
        // 22 values of exp(-2) and two of 1
        let expected = 2.0 + 22.0 * (-2.0f32).exp();
        assert!(
            (s.sum - expected).abs() < 1e-5,
            "{} against {expected}",
            s.sum
        );
    }
}
