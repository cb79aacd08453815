//! The GEMM kernels of the 3-D convolution ops ([`super::conv3d`]): forward, input gradient
//! (transposed convolution) and weight gradient, channels-last, over the `gemm` crate.
//!
//! With `xp` the zero-padded input, a convolution is
//! `y[b, od, oh, ow, co] = Σ_{a, c, e, ci} xp[b, od·sD + a, oh·sH + c, ow·sW + e, ci] · w[a, c, e, ci, co]`.
//! For one output row `(b, od, oh)` and one tap pair `(a, c)`, the `kW·Ci` values
//! `xp[b, od·sD + a, oh·sH + c, ow·sW + e, ci]` over `(e, ci)` are contiguous in memory, so the row is
//! `Σ_{a, c} A_{a,c} · W_{a,c}` with `A_{a,c}` a `(Wo × kW·Ci)` view of the padded input (row stride
//! `sW·Ci`, rows overlapping) and `W_{a,c}` the contiguous `(kW·Ci × Co)` slice of the weights:
//! an implicit GEMM with no im2col copy. Narrow layers take the direct kernel instead
//! ([`super::conv3d_direct`]).

use gemm::Parallelism;
use rayon::prelude::*;

use super::conv3d_direct::{conv3d_forward_direct, RowEpilogue};
use super::types::{add_into, Conv3dGeometry, SPATIAL_AXES_3D};

/// `dst (m × n) += lhs (m × k) · rhs (k × n)` over strided views; `dst` has unit column stride.
/// Strides are in elements; the views must lie inside the slices (checked).
#[allow(clippy::too_many_arguments)]
fn gemm_accumulate(
    [m, n, k]: [usize; 3],
    dst: &mut [f32],
    dst_row_stride: usize,
    lhs: &[f32],
    [lhs_row_stride, lhs_col_stride]: [usize; 2],
    rhs: &[f32],
    [rhs_row_stride, rhs_col_stride]: [usize; 2],
) {
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    let last = |rows: usize, cols: usize, rs: usize, cs: usize| (rows - 1) * rs + (cols - 1) * cs;
    assert!(
        last(m, n, dst_row_stride, 1) < dst.len()
            && last(m, k, lhs_row_stride, lhs_col_stride) < lhs.len()
            && last(k, n, rhs_row_stride, rhs_col_stride) < rhs.len(),
        "gemm view out of bounds (internal indexing bug)"
    );
    // SAFETY: the three views were checked to lie inside their slices just above; `dst` is
    // borrowed mutably, so it aliases neither `lhs` nor `rhs`; each dst element is written once.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            dst_row_stride as isize,
            true,
            lhs.as_ptr(),
            lhs_col_stride as isize,
            lhs_row_stride as isize,
            rhs.as_ptr(),
            rhs_col_stride as isize,
            rhs_row_stride as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}

/// Copies `x (B, D, H, W, C)` into a zero-filled `(B, D + 2pD, H + 2pH, W + 2pW, C)` buffer.
fn pad_volume(
    x: &[f32],
    batch: usize,
    dims: [usize; 3],
    padding: [usize; 3],
    c: usize,
) -> Vec<f32> {
    let [d, h, w] = dims;
    let [pd, ph, pw] = padding;
    let (dp, hp, wp) = (d + 2 * pd, h + 2 * ph, w + 2 * pw);
    let mut out = vec![0f32; batch * dp * hp * wp * c];
    let row = w * c;
    out.par_chunks_mut(hp * wp * c)
        .enumerate()
        .for_each(|(plane, out_plane)| {
            let (b, zp) = (plane / dp, plane % dp);
            if zp < pd || zp >= pd + d {
                return;
            }
            let z = zp - pd;
            for y in 0..h {
                let src = ((b * d + z) * h + y) * row;
                let dst = ((y + ph) * wp + pw) * c;
                out_plane[dst..dst + row].copy_from_slice(&x[src..src + row]);
            }
        });
    out
}

/// Inverse of [`pad_volume`]: the centre `(B, D, H, W, C)` of a padded buffer.
fn crop_volume(
    xp: &[f32],
    batch: usize,
    dims: [usize; 3],
    padding: [usize; 3],
    c: usize,
) -> Vec<f32> {
    let [d, h, w] = dims;
    let [pd, ph, pw] = padding;
    let (dp, hp, wp) = (d + 2 * pd, h + 2 * ph, w + 2 * pw);
    let mut out = vec![0f32; batch * d * h * w * c];
    let row = w * c;
    out.par_chunks_mut(h * row)
        .enumerate()
        .for_each(|(plane, out_plane)| {
            let (b, z) = (plane / d, plane % d);
            for y in 0..h {
                let src = (((b * dp + z + pd) * hp + y + ph) * wp + pw) * c;
                out_plane[y * row..(y + 1) * row].copy_from_slice(&xp[src..src + row]);
            }
        });
    out
}

fn padded_input<'a>(x: &'a [f32], g: &Conv3dGeometry) -> std::borrow::Cow<'a, [f32]> {
    if g.padding == [0; 3] {
        std::borrow::Cow::Borrowed(x)
    } else {
        std::borrow::Cow::Owned(pad_volume(x, g.batch, g.in_dims, g.padding, g.c_in))
    }
}

/// Forward kernel, followed by `epilogue`: the direct kernel where it serves the geometry
/// (epilogue fused per row), else the GEMM kernels (by planes for unit strides, by rows
/// otherwise) and the epilogue over the output.
pub(super) fn conv3d_forward_cpu(
    x: &[f32],
    w: &[f32],
    g: &Conv3dGeometry,
    epilogue: &RowEpilogue,
) -> Vec<f32> {
    if let Some(y) = conv3d_forward_direct(x, w, g, epilogue) {
        return y;
    }
    let mut y = if g.stride == [1; 3] {
        conv3d_forward_planes_cpu(x, w, g)
    } else {
        conv3d_forward_rows_cpu(x, w, g)
    };
    epilogue.apply(&mut y, 0, g.c_out);
    y
}

/// [`conv3d_forward_cpu`] for any stride by rows: one rayon task per output row
/// `(b, od, oh)`, `kD·kH` GEMMs of `(Wo × kW·Ci) · (kW·Ci × Co)` each.
fn conv3d_forward_rows_cpu(x: &[f32], w: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    let xp = padded_input(x, g);
    let [dp, hp, wp] = g.padded_dims();
    let [do_, ho, wo] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let [sd, sh, sw] = g.stride;
    let (ci, co) = (g.c_in, g.c_out);
    let mut y = vec![0f32; g.batch * do_ * ho * wo * co];
    y.par_chunks_mut(wo * co)
        .enumerate()
        .for_each(|(row, y_row)| {
            let (oh, od, b) = (row % ho, (row / ho) % do_, row / (ho * do_));
            for a in 0..kd {
                for c in 0..kh {
                    let (id, ih) = (od * sd + a, oh * sh + c);
                    let x_off = ((b * dp + id) * hp + ih) * wp * ci;
                    let w_off = (a * kh + c) * kw * ci * co;
                    // (Wo, Co) += (Wo, kW·Ci) · (kW·Ci, Co)
                    gemm_accumulate(
                        [wo, co, kw * ci],
                        y_row,
                        co,
                        &xp[x_off..],
                        [sw * ci, 1],
                        &w[w_off..],
                        [co, 1],
                    );
                }
            }
        });
    y
}

/// Forward kernel for unit strides: one rayon task per output plane `(b, od)`. With unit
/// strides the input offset of output `(oh, ow)` and tap `(c, e)` is
/// `((oh + c) Wp + ow + e) Ci`, linear in the flat index `j = oh Wp + ow`, so per `(a, c)` the
/// whole plane is one GEMM `(M × kW·Ci) · (kW·Ci × Co)` with `M = (Ho − 1) Wp + Wo` rows of
/// stride `Ci` (the `Wp − Wo` rows between two output rows are computed and dropped). Small
/// channel counts then still give the GEMM long, efficient panels.
fn conv3d_forward_planes_cpu(x: &[f32], w: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    let xp = padded_input(x, g);
    let [dp, hp, wp] = g.padded_dims();
    let [do_, ho, wo] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let (ci, co) = (g.c_in, g.c_out);
    let m = (ho - 1) * wp + wo;
    let mut y = vec![0f32; g.batch * do_ * ho * wo * co];
    y.par_chunks_mut(ho * wo * co)
        .enumerate()
        .for_each(|(plane, y_plane)| {
            let (od, b) = (plane % do_, plane / do_);
            let mut scratch = vec![0f32; m * co];
            for a in 0..kd {
                for c in 0..kh {
                    let x_off = ((b * dp + od + a) * hp + c) * wp * ci;
                    let w_off = (a * kh + c) * kw * ci * co;
                    // (M, Co) += (M, kW·Ci) · (kW·Ci, Co)
                    gemm_accumulate(
                        [m, co, kw * ci],
                        &mut scratch,
                        co,
                        &xp[x_off..],
                        [ci, 1],
                        &w[w_off..],
                        [co, 1],
                    );
                }
            }
            for (oh, y_row) in y_plane.chunks_mut(wo * co).enumerate() {
                y_row.copy_from_slice(&scratch[oh * wp * co..(oh * wp + wo) * co]);
            }
        });
    y
}

/// Input-gradient (transposed convolution) kernel: one rayon task per padded input row
/// `(b, id, ih)`, gathering every `(od, oh, a, c)` with `od·sD + a = id`, `oh·sH + c = ih`; per
/// kW tap one GEMM `(Wo × Co) · (Co × Ci)` accumulated into the row at stride `sW·Ci`.
pub(super) fn conv3d_input_grad_cpu(dy: &[f32], w: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    if is_exact_x2(g) {
        return conv3d_input_grad_x2_cpu(dy, w, g);
    }
    let [dp, hp, wp] = g.padded_dims();
    let [do_, ho, wo] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let [sd, sh, sw] = g.stride;
    let (ci, co) = (g.c_in, g.c_out);
    /// `o` with `o·s + t = i` and `o < n`, if any.
    fn source(i: usize, t: usize, s: usize, n: usize) -> Option<usize> {
        let r = i.checked_sub(t)?;
        (r % s == 0 && r / s < n).then_some(r / s)
    }
    let mut dxp = vec![0f32; g.batch * dp * hp * wp * ci];
    dxp.par_chunks_mut(wp * ci)
        .enumerate()
        .for_each(|(row, dx_row)| {
            let (ih, id, b) = (row % hp, (row / hp) % dp, row / (hp * dp));
            for a in 0..kd {
                let Some(od) = source(id, a, sd, do_) else {
                    continue;
                };
                for c in 0..kh {
                    let Some(oh) = source(ih, c, sh, ho) else {
                        continue;
                    };
                    let dy_off = ((b * do_ + od) * ho + oh) * wo * co;
                    for e in 0..kw {
                        let w_off = ((a * kh + c) * kw + e) * ci * co;
                        // (Wo, Ci) at stride sW·Ci += (Wo, Co) · (Co, Ci)ᵀ-view of w[a, c, e]
                        gemm_accumulate(
                            [wo, ci, co],
                            &mut dx_row[e * ci..],
                            sw * ci,
                            &dy[dy_off..],
                            [co, 1],
                            &w[w_off..],
                            [1, co],
                        );
                    }
                }
            }
        });
    if g.padding == [0; 3] {
        dxp
    } else {
        crop_volume(&dxp, g.batch, g.in_dims, g.padding, ci)
    }
}

/// The x2 case of the hourglasses: kernel 3, stride 2, padding 1 on every axis and an input
/// exactly twice the output (even sizes).
pub(super) fn is_exact_x2(g: &Conv3dGeometry) -> bool {
    g.kernel == [3; 3]
        && g.stride == [2; 3]
        && g.padding == [1; 3]
        && (0..SPATIAL_AXES_3D).all(|a| g.in_dims[a] == 2 * g.out_dims[a])
}

/// Per axis of the x2 case, the `(tap, source offset)` pairs that reach input parity `p`:
/// `i + 1 = 2 o + t`, so `i = 2 m` takes `t = 1, o = m` and `i = 2 m + 1` takes `t = 0,
/// o = m + 1` and `t = 2, o = m`.
const X2_TAPS: [&[(usize, usize)]; 2] = [&[(1, 0)], &[(0, 1), (2, 0)]];

/// [`conv3d_input_grad_cpu`] for [`is_exact_x2`] geometries, by parity classes: the inputs
/// of one parity `(pd, ph, pw)` form a `(D/2, H/2, W/2)` grid that gathers `dy` at unit
/// stride through one or two taps per axis, so each class is a sum of unit-stride GEMMs over
/// whole planes of `dy` (padded by one zero at the end of each axis), flattened as in
/// [`conv3d_forward_planes_cpu`]. One rayon task per `(b, input plane)`.
fn conv3d_input_grad_x2_cpu(dy: &[f32], w: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    let [do_, ho, wo] = g.out_dims;
    let [d, h, wd] = g.in_dims;
    let [_, kh, kw] = g.kernel;
    let (ci, co) = (g.c_in, g.c_out);
    // dy padded by one zero at the end of every axis: (B, Do + 1, Ho + 1, Wo + 1, Co)
    let (dq, hq, wq) = (do_ + 1, ho + 1, wo + 1);
    let mut dyp = vec![0f32; g.batch * dq * hq * wq * co];
    dyp.par_chunks_mut(hq * wq * co)
        .enumerate()
        .for_each(|(plane, out)| {
            let (b, z) = (plane / dq, plane % dq);
            if z == do_ {
                return;
            }
            for y in 0..ho {
                let src = ((b * do_ + z) * ho + y) * wo * co;
                out[y * wq * co..(y * wq + wo) * co].copy_from_slice(&dy[src..src + wo * co]);
            }
        });
    let m = (ho - 1) * wq + wo;
    let mut dx = vec![0f32; g.batch * d * h * wd * ci];
    dx.par_chunks_mut(h * wd * ci)
        .enumerate()
        .for_each(|(plane, dx_plane)| {
            let (i_d, b) = (plane % d, plane / d);
            let (md, pd) = (i_d / 2, i_d % 2);
            let mut scratch = vec![0f32; m * ci];
            for ph in 0..2 {
                for pw in 0..2 {
                    scratch.fill(0.0);
                    for &(ta, od) in X2_TAPS[pd] {
                        for &(tc, oh) in X2_TAPS[ph] {
                            for &(te, ow) in X2_TAPS[pw] {
                                let dy_off = (((b * dq + md + od) * hq + oh) * wq + ow) * co;
                                let w_off = ((ta * kh + tc) * kw + te) * ci * co;
                                // (M, Ci) += (M, Co) · (Co, Ci)ᵀ-view of w[ta, tc, te]
                                gemm_accumulate(
                                    [m, ci, co],
                                    &mut scratch,
                                    ci,
                                    &dyp[dy_off..],
                                    [co, 1],
                                    &w[w_off..],
                                    [1, co],
                                );
                            }
                        }
                    }
                    for mh in 0..ho {
                        let row = &mut dx_plane[(2 * mh + ph) * wd * ci..][..wd * ci];
                        for mw in 0..wo {
                            let src = &scratch[(mh * wq + mw) * ci..][..ci];
                            row[(2 * mw + pw) * ci..][..ci].copy_from_slice(src);
                        }
                    }
                }
            }
        });
    dx
}

/// Weight-gradient kernel: by planes where the strides in `H` and `W` are 1
/// ([`conv3d_weight_grad_planes_cpu`]), else by rows: a rayon fold over output rows with one
/// `(kD, kH, kW, Ci, Co)` accumulator per task; per `(a, c)` one GEMM
/// `(kW·Ci × Wo) · (Wo × Co)`.
pub(super) fn conv3d_weight_grad_cpu(x: &[f32], dy: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    if g.stride[1] == 1 && g.stride[2] == 1 {
        return conv3d_weight_grad_planes_cpu(x, dy, g);
    }
    let xp = padded_input(x, g);
    let [dp, hp, wp] = g.padded_dims();
    let [do_, ho, wo] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let [sd, sh, sw] = g.stride;
    let (ci, co) = (g.c_in, g.c_out);
    let w_len = kd * kh * kw * ci * co;
    let rows = g.batch * do_ * ho;
    (0..rows)
        .into_par_iter()
        .fold(
            || vec![0f32; w_len],
            |mut acc, row| {
                let (oh, od, b) = (row % ho, (row / ho) % do_, row / (ho * do_));
                let dy_row = &dy[row * wo * co..(row + 1) * wo * co];
                for a in 0..kd {
                    for c in 0..kh {
                        let (id, ih) = (od * sd + a, oh * sh + c);
                        let x_off = ((b * dp + id) * hp + ih) * wp * ci;
                        let w_off = (a * kh + c) * kw * ci * co;
                        // (kW·Ci, Co) += (Wo, kW·Ci)ᵀ · (Wo, Co)
                        gemm_accumulate(
                            [kw * ci, co, wo],
                            &mut acc[w_off..],
                            co,
                            &xp[x_off..],
                            [1, sw * ci],
                            dy_row,
                            [co, 1],
                        );
                    }
                }
                acc
            },
        )
        .reduce(|| vec![0f32; w_len], add_into)
}

/// [`conv3d_weight_grad_cpu`] for unit strides in `H` and `W` (any in `D`): a rayon fold over
/// output planes `(b, od)`. As in [`conv3d_forward_planes_cpu`], the input offset of output
/// `(oh, ow)` and tap `(c, e)` is linear in the flat index `j = oh Wp + ow`, so with `dy`'s
/// plane copied into that layout (`M = (Ho − 1) Wp + Wo` rows, zeros in the `Wp − Wo` rows
/// between two output rows, which then add nothing) each `(a, c)` is one GEMM
/// `(kW·Ci × M) · (M × Co)`: long panels where the rows' GEMMs had only `Wo` (a fine-head
/// layer of 4 outputs took 55,000 small GEMMs a step by rows).
fn conv3d_weight_grad_planes_cpu(x: &[f32], dy: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    let xp = padded_input(x, g);
    let [dp, hp, wp] = g.padded_dims();
    let [do_, ho, wo] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let sd = g.stride[0];
    let (ci, co) = (g.c_in, g.c_out);
    let w_len = kd * kh * kw * ci * co;
    let m = (ho - 1) * wp + wo;
    (0..g.batch * do_)
        .into_par_iter()
        .fold(
            || (vec![0f32; w_len], vec![0f32; m * co]),
            |(mut acc, mut dyq), plane| {
                let (od, b) = (plane % do_, plane / do_);
                let dy_plane = &dy[plane * ho * wo * co..(plane + 1) * ho * wo * co];
                for (oh, dy_row) in dy_plane.chunks(wo * co).enumerate() {
                    dyq[oh * wp * co..(oh * wp + wo) * co].copy_from_slice(dy_row);
                }
                for a in 0..kd {
                    for c in 0..kh {
                        let x_off = ((b * dp + od * sd + a) * hp + c) * wp * ci;
                        let w_off = (a * kh + c) * kw * ci * co;
                        // (kW·Ci, Co) += (M, kW·Ci)ᵀ · (M, Co)
                        gemm_accumulate(
                            [kw * ci, co, m],
                            &mut acc[w_off..],
                            co,
                            &xp[x_off..],
                            [1, ci],
                            &dyq,
                            [co, 1],
                        );
                    }
                }
                (acc, dyq)
            },
        )
        .map(|(acc, _)| acc)
        .reduce(|| vec![0f32; w_len], add_into)
}
