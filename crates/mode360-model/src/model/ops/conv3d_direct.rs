//! Direct forward kernel of [`super::conv3d`] for the narrow layers of the cost aggregation
//! (`Cout` of 4, 8 or 16, and `Cout = 1` over 8 or 16 input channels), on x86-64 CPUs with
//! AVX2 and FMA.
//!
//! A GEMM over `(Wo × kW·Ci) · (kW·Ci × Co)` panels runs far below the machine's peak when `Co`
//! is 8: every panel is a handful of FMAs between two memory passes. Here a block of `R`
//! neighbouring output cells keeps its `R × Co` accumulators in vector registers across all
//! `kD·kH·kW·Ci` taps:
//!
//! ```text
//! y[b, od, oh, ow, :] = Σ_{a, c, e, ci} x[b, od·sD + a − pD, oh·sH + c − pH, ow·sW + e − pW, ci] · w[a, c, e, ci, :]
//! ```
//!
//! Taps outside the input are skipped (zero padding without a padded copy of the input, which
//! for the sweep volume would be a 100 MB copy). For `Co = 1` the vector runs along `Ci`
//! instead and each cell's accumulator is summed across lanes once at the end.

use rayon::prelude::*;

use super::types::Conv3dGeometry;

#[cfg(target_arch = "x86_64")]
mod avx2;

/// Output cells per register block when `Co` fills one 8-lane vector.
const BLOCK_CO8: usize = 12;
/// Output cells per register block when `Co` fills two 8-lane vectors.
const BLOCK_CO16: usize = 6;
/// Output cells per register block when `Co` fills half an 8-lane vector (the fine head's
/// first layer, in 4-lane vectors; 4, 6, 12 and 16 cells ran slower on the fine head's volume).
const BLOCK_CO4: usize = 12;
/// Output cells per register block of the `Co = 1` (dot product) kernel.
const BLOCK_DOT: usize = 4;

/// What is applied to each output value `v` of channel `co` at flat position `i` after the
/// convolution: `relu?(v + bias[co] + residual[i])` (each part optional).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct RowEpilogue<'a> {
    pub bias: Option<&'a [f32]>,
    /// Same length as the output.
    pub residual: Option<&'a [f32]>,
    pub relu: bool,
}

impl RowEpilogue<'_> {
    /// No bias, no residual, no activation.
    pub const NONE: RowEpilogue<'static> = RowEpilogue {
        bias: None,
        residual: None,
        relu: false,
    };

    fn is_identity(&self) -> bool {
        self.bias.is_none() && self.residual.is_none() && !self.relu
    }

    /// Applies the epilogue to `y`, which starts at flat output position `offset`, with `co`
    /// output channels.
    pub fn apply(&self, y: &mut [f32], offset: usize, co: usize) {
        if self.is_identity() {
            return;
        }
        if let Some(bias) = self.bias {
            for cell in y.chunks_exact_mut(co) {
                cell.iter_mut().zip(bias).for_each(|(v, b)| *v += b);
            }
        }
        if let Some(res) = self.residual {
            let len = y.len();
            y.iter_mut()
                .zip(&res[offset..offset + len])
                .for_each(|(v, r)| *v += r);
        }
        if self.relu {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    }
}

/// `conv3d`'s forward by the direct kernel, followed by `epilogue`, when the geometry and the
/// CPU suit it, else `None` (the caller then uses the GEMM kernels).
pub(super) fn conv3d_forward_direct(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    epilogue: &RowEpilogue,
) -> Option<Vec<f32>> {
    #[cfg(target_arch = "x86_64")]
    {
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma"))
        {
            return None;
        }
        if x.len() != g.batch * g.in_dims.iter().product::<usize>() * g.c_in
            || w.len() != g.kernel.iter().product::<usize>() * g.c_in * g.c_out
        {
            return None;
        }
        match (g.c_in, g.c_out) {
            (_, 8) => Some(run(x, w, g, epilogue, |x, w, g, row, y| {
                // SAFETY: AVX2 and FMA were detected above, the lengths checked.
                unsafe { row_avx2::<8, 1, BLOCK_CO8>(x, w, g, row, y) }
            })),
            (_, 4) => {
                let len = g.kernel[2] * g.c_in;
                let packed: Vec<f32> = w
                    .chunks_exact(len * avx2::CO_PAIRED)
                    .flat_map(|tap_row| avx2::pack_pairs_co4(tap_row, len))
                    .collect();
                Some(run(x, w, g, epilogue, |x, w, g, row, y| {
                    // SAFETY: AVX2 and FMA were detected above, the lengths checked.
                    unsafe { row_co4_avx2::<BLOCK_CO4>(x, w, &packed, g, row, y) }
                }))
            }
            (_, 16) => Some(run(x, w, g, epilogue, |x, w, g, row, y| {
                // SAFETY: AVX2 and FMA were detected above, the lengths checked.
                unsafe { row_avx2::<16, 2, BLOCK_CO16>(x, w, g, row, y) }
            })),
            (8, 1) => Some(run(x, w, g, epilogue, |x, w, g, row, y| {
                // SAFETY: AVX2 and FMA were detected above.
                unsafe { row_dot_avx2::<8>(x, w, g, row, y) }
            })),
            (16, 1) => Some(run(x, w, g, epilogue, |x, w, g, row, y| {
                // SAFETY: AVX2 and FMA were detected above.
                unsafe { row_dot_avx2::<16>(x, w, g, row, y) }
            })),
            _ => None,
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (x, w, g, epilogue);
        None
    }
}

/// One rayon task per output row `(b, od, oh)`; `row_kernel` fills the row's `Wo·Co` values,
/// then the epilogue runs on the row while it is in cache.
fn run(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    epilogue: &RowEpilogue,
    row_kernel: impl Fn(&[f32], &[f32], &Conv3dGeometry, usize, &mut [f32]) + Sync,
) -> Vec<f32> {
    let [do_, ho, wo] = g.out_dims;
    let row_len = wo * g.c_out;
    let mut y = vec![0f32; g.batch * do_ * ho * row_len];
    y.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(row, y_row)| {
            row_kernel(x, w, g, row, y_row);
            epilogue.apply(y_row, row * row_len, g.c_out);
        });
    y
}

/// The input rows one output row reads: for every tap pair `(a, c)` inside the input, the
/// offset of input row `(b, od·sD + a − pD, oh·sH + c − pH)` and of weights `w[a, c]`.
#[derive(Clone, Copy, Debug)]
struct TapRows {
    rows: [(usize, usize); Self::MAX],
    len: usize,
}

impl TapRows {
    /// Tap pairs of the largest kernel served (3 x 3 over D and H).
    const MAX: usize = 9;

    /// `None` for kernels with more than [`Self::MAX`] `(a, c)` pairs.
    fn new(g: &Conv3dGeometry, row: usize) -> Option<Self> {
        let [d, h, wd] = g.in_dims;
        let [do_, ho, _] = g.out_dims;
        let [kd, kh, kw] = g.kernel;
        let (oh, od, b) = (row % ho, (row / ho) % do_, row / (ho * do_));
        let mut taps = Self {
            rows: [(0, 0); Self::MAX],
            len: 0,
        };
        for a in 0..kd {
            let Some(id) = (od * g.stride[0] + a).checked_sub(g.padding[0]) else {
                continue;
            };
            if id >= d {
                continue;
            }
            for c in 0..kh {
                let Some(ih) = (oh * g.stride[1] + c).checked_sub(g.padding[1]) else {
                    continue;
                };
                if ih >= h {
                    continue;
                }
                if taps.len == Self::MAX {
                    return None;
                }
                let x_off = ((b * d + id) * h + ih) * wd * g.c_in;
                let w_off = (a * kh + c) * kw * g.c_in * g.c_out;
                taps.rows[taps.len] = (x_off, w_off);
                taps.len += 1;
            }
        }
        Some(taps)
    }

    fn iter(&self) -> impl Iterator<Item = &(usize, usize)> {
        self.rows[..self.len].iter()
    }
}

/// The output columns `[lo, hi)` whose `kW` taps all lie inside the input row (no bounds checks
/// needed there).
fn interior_columns(g: &Conv3dGeometry) -> (usize, usize) {
    let (sw, pw, kw, wd, wo) = (
        g.stride[2],
        g.padding[2],
        g.kernel[2],
        g.in_dims[2],
        g.out_dims[2],
    );
    let lo = pw.div_ceil(sw).min(wo);
    // ow·sW + kW − 1 − pW <= W − 1
    let hi = if wd + pw >= kw {
        ((wd + pw - kw) / sw + 1).min(wo)
    } else {
        0
    };
    (lo, hi.max(lo))
}

/// Input column of output column `ow` and tap `e`, if inside the row.
#[inline(always)]
fn input_column(g: &Conv3dGeometry, ow: usize, e: usize) -> Option<usize> {
    (ow * g.stride[2] + e)
        .checked_sub(g.padding[2])
        .filter(|&iw| iw < g.in_dims[2])
}

/// One output row with `Co = CO = 8·V` in register blocks of `R` cells, then of
/// [`BLOCK_TAIL`] cells, the rest (padded edges and the last few cells) by [`edge_cells`].
///
/// # Safety
/// The CPU must support AVX2 and FMA; `x` and `w` hold the geometry's input and weights.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_avx2<const CO: usize, const V: usize, const R: usize>(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    row: usize,
    y: &mut [f32],
) {
    debug_assert_eq!(CO, V * avx2::LANES);
    let Some(taps) = TapRows::new(g, row) else {
        return row_scalar(x, w, g, row, y);
    };
    let (lo, hi) = interior_columns(g);
    let ow = blocks_avx2::<V, R>(x, w, g, &taps, lo..hi, y);
    let ow = blocks_avx2::<V, BLOCK_TAIL>(x, w, g, &taps, ow..hi, y);
    edge_cells::<CO>(x, w, g, &taps, (0..lo).chain(ow..g.out_dims[2]), y);
}

/// Output cells per register block after the main blocks of a row.
const BLOCK_TAIL: usize = 4;

/// The interior cells `cols` of one row in blocks of `R` from `cols.start`; returns the first
/// cell not done.
///
/// # Safety
/// As [`row_avx2`]; `cols` interior columns ([`interior_columns`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn blocks_avx2<const V: usize, const R: usize>(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    taps: &TapRows,
    cols: std::ops::Range<usize>,
    y: &mut [f32],
) -> usize {
    use std::arch::x86_64::_mm256_setzero_ps;
    let co = V * avx2::LANES;
    let (ci, sw, pw) = (g.c_in, g.stride[2], g.padding[2]);
    let (len, step) = (g.kernel[2] * ci, sw * ci);
    let mut ow = cols.start;
    while ow + R <= cols.end {
        let mut acc = [[_mm256_setzero_ps(); V]; R];
        for &(x_off, w_off) in taps.iter() {
            // cells ow..ow + R read x_row[(ow + r)·sW − pW + k / Ci] (inside: interior columns)
            let x0 = x_off + (ow * sw - pw) * ci;
            debug_assert!(x0 + (R - 1) * step + len <= x.len() && w_off + len * co <= w.len());
            avx2::block::<V, R>(
                x.as_ptr().add(x0),
                step,
                w.as_ptr().add(w_off),
                len,
                &mut acc,
            );
        }
        debug_assert!((ow + R) * co <= y.len());
        avx2::store::<V, R>(&acc, y.as_mut_ptr().add(ow * co));
        ow += R;
    }
    ow
}

/// One output row with `Co = 4` in register blocks of `R` cells of [`avx2::block_co4`]'s paired
/// taps (`packed`: [`avx2::pack_pairs_co4`] of each tap row's weights, `kD·kH` of them, in the
/// order of `w`), the rest by [`edge_cells`].
///
/// # Safety
/// The CPU must support AVX2 and FMA; `x` and `w` hold the geometry's input and weights.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_co4_avx2<const R: usize>(
    x: &[f32],
    w: &[f32],
    packed: &[f32],
    g: &Conv3dGeometry,
    row: usize,
    y: &mut [f32],
) {
    use std::arch::x86_64::_mm256_setzero_ps;
    let Some(taps) = TapRows::new(g, row) else {
        return row_scalar(x, w, g, row, y);
    };
    let (ci, sw, pw) = (g.c_in, g.stride[2], g.padding[2]);
    let (len, step) = (g.kernel[2] * ci, sw * ci);
    let packed_len = len.div_ceil(2) * avx2::LANES;
    let (lo, hi) = interior_columns(g);
    let mut ow = lo;
    while ow + R <= hi {
        let mut acc = [_mm256_setzero_ps(); R];
        for &(x_off, w_off) in taps.iter() {
            let x0 = x_off + (ow * sw - pw) * ci;
            let p0 = w_off / (len * avx2::CO_PAIRED) * packed_len;
            debug_assert!(x0 + (R - 1) * step + len <= x.len() && p0 + packed_len <= packed.len());
            avx2::block_co4::<R>(
                x.as_ptr().add(x0),
                step,
                packed.as_ptr().add(p0),
                len,
                &mut acc,
            );
        }
        debug_assert!((ow + R) * avx2::CO_PAIRED <= y.len());
        avx2::store_co4::<R>(&acc, y.as_mut_ptr().add(ow * avx2::CO_PAIRED));
        ow += R;
    }
    edge_cells::<{ avx2::CO_PAIRED }>(x, w, g, &taps, (0..lo).chain(ow..g.out_dims[2]), y);
}

/// The cells `cols` of one row one at a time, the taps outside the input skipped (`CO` the
/// geometry's output channels, a constant so that a cell's accumulators are one register).
///
/// # Safety
/// The CPU must support AVX2 and FMA (without them `mul_add` is a library call).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn edge_cells<const CO: usize>(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    taps: &TapRows,
    cols: impl Iterator<Item = usize>,
    y: &mut [f32],
) {
    let (ci, kw) = (g.c_in, g.kernel[2]);
    debug_assert_eq!(g.c_out, CO);
    for ow in cols {
        let mut cell = [0f32; CO];
        for &(x_off, w_off) in taps.iter() {
            for e in 0..kw {
                let Some(iw) = input_column(g, ow, e) else {
                    continue;
                };
                let xs = &x[x_off + iw * ci..x_off + (iw + 1) * ci];
                let ws = &w[w_off + e * ci * CO..w_off + (e + 1) * ci * CO];
                for (&xv, wv) in xs.iter().zip(ws.chunks_exact(CO)) {
                    for (a, &wj) in cell.iter_mut().zip(wv) {
                        *a = xv.mul_add(wj, *a);
                    }
                }
            }
        }
        y[ow * CO..(ow + 1) * CO].copy_from_slice(&cell);
    }
}

/// One output row with `Co = 1` and `Ci = CI` (a multiple of 8): per cell a dot product of
/// length `kD·kH·kW·Ci`, vectorised along `Ci`, in blocks of [`BLOCK_DOT`] cells.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_dot_avx2<const CI: usize>(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    row: usize,
    y: &mut [f32],
) {
    const R: usize = BLOCK_DOT;
    let Some(taps) = TapRows::new(g, row) else {
        return row_scalar(x, w, g, row, y);
    };
    let (kw, sw, pw) = (g.kernel[2], g.stride[2], g.padding[2]);
    let wo = g.out_dims[2];
    let (lo, hi) = interior_columns(g);
    let mut ow = lo;
    while ow + R <= hi {
        let mut acc = [[0f32; CI]; R];
        for &(x_off, w_off) in taps.iter() {
            for e in 0..kw {
                let wv: &[f32; CI] = w[w_off + e * CI..w_off + (e + 1) * CI]
                    .try_into()
                    .unwrap_or(&[0.0; CI]);
                for (r, acc_r) in acc.iter_mut().enumerate() {
                    let x0 = x_off + (((ow + r) * sw + e) - pw) * CI;
                    let xv: &[f32; CI] = x[x0..x0 + CI].try_into().unwrap_or(&[0.0; CI]);
                    for ((a, &xj), &wj) in acc_r.iter_mut().zip(xv).zip(wv) {
                        *a = xj.mul_add(wj, *a);
                    }
                }
            }
        }
        for (r, acc_r) in acc.iter().enumerate() {
            y[ow + r] = acc_r.iter().sum();
        }
        ow += R;
    }
    for ow in (0..lo).chain(ow..wo) {
        let mut acc = 0f32;
        for &(x_off, w_off) in taps.iter() {
            for e in 0..kw {
                if let Some(iw) = input_column(g, ow, e) {
                    let xs = &x[x_off + iw * CI..x_off + (iw + 1) * CI];
                    let ws = &w[w_off + e * CI..w_off + (e + 1) * CI];
                    acc += xs.iter().zip(ws).map(|(a, b)| a * b).sum::<f32>();
                }
            }
        }
        y[ow] = acc;
    }
}

/// Any geometry, one cell at a time with every bound checked (kernels with more than
/// [`TapRows::MAX`] tap rows).
fn row_scalar(x: &[f32], w: &[f32], g: &Conv3dGeometry, row: usize, y: &mut [f32]) {
    let [d, h, wd] = g.in_dims;
    let [do_, ho, wo] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let (ci, co) = (g.c_in, g.c_out);
    let (oh, od, b) = (row % ho, (row / ho) % do_, row / (ho * do_));
    y.fill(0.0);
    for a in 0..kd {
        let Some(id) = (od * g.stride[0] + a)
            .checked_sub(g.padding[0])
            .filter(|&i| i < d)
        else {
            continue;
        };
        for c in 0..kh {
            let Some(ih) = (oh * g.stride[1] + c)
                .checked_sub(g.padding[1])
                .filter(|&i| i < h)
            else {
                continue;
            };
            let x_off = ((b * d + id) * h + ih) * wd * ci;
            for ow in 0..wo {
                for e in 0..kw {
                    let Some(iw) = input_column(g, ow, e) else {
                        continue;
                    };
                    let w_off = ((a * kh + c) * kw + e) * ci * co;
                    for k in 0..ci {
                        let xv = x[x_off + iw * ci + k];
                        let wr = &w[w_off + k * co..w_off + (k + 1) * co];
                        for (o, &wj) in y[ow * co..(ow + 1) * co].iter_mut().zip(wr) {
                            *o += xv * wj;
                        }
                    }
                }
            }
        }
    }
}
