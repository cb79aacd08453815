//! Channels-last 3-D convolution, its adjoint (transposed convolution) and its weight gradient,
//! as candle custom ops over the `gemm` crate.
//!
//! With `xp` the zero-padded input, a convolution is
//! `y[b, od, oh, ow, co] = Σ_{a, c, e, ci} xp[b, od·sD + a, oh·sH + c, ow·sW + e, ci] · w[a, c, e, ci, co]`.
//! For one output row `(b, od, oh)` and one tap pair `(a, c)`, the `kW·Ci` values
//! `xp[b, od·sD + a, oh·sH + c, ow·sW + e, ci]` over `(e, ci)` are contiguous in memory, so the row is
//! `Σ_{a, c} A_{a,c} · W_{a,c}` with `A_{a,c}` a `(Wo × kW·Ci)` view of the padded input (row stride
//! `sW·Ci`, rows overlapping) and `W_{a,c}` the contiguous `(kW·Ci × Co)` slice of the weights:
//! an implicit GEMM with no im2col copy.

use candle_core::{CpuStorage, CustomOp2, Layout, Result, Shape, Tensor};
use gemm::Parallelism;
use rayon::prelude::*;

use super::composite;
use super::conv3d_direct::{conv3d_forward_direct, RowEpilogue};
use super::types::{
    conv_geometry_from, count_flops, cpu_slice, dims_of, has_custom_kernels, Conv3dGeometry,
    OpsError, SPATIAL_AXES_3D, VOLUME_RANK,
};

/// 3-D convolution, channels-last: x `(B, D, H, W, Cin)`, w `(kD, kH, kW, Cin, Cout)` ->
/// `(B, Do, Ho, Wo, Cout)`, `Do = ⌊(D + 2 pD − kD) / sD⌋ + 1`. No bias (add it with
/// `broadcast_add`). Gradients flow to `x` and `w`.
pub fn conv3d(x: &Tensor, w: &Tensor, stride: [usize; 3], padding: [usize; 3]) -> Result<Tensor> {
    let geom = conv_geometry_from(x, w, stride, padding, "conv3d")?;
    count_flops(geom.flops());
    if !has_custom_kernels(x.device()) {
        return composite::conv3d_composite(x, w, stride, padding);
    }
    // (B, D, H, W, Cin) * (kD, kH, kW, Cin, Cout) -> (B, Do, Ho, Wo, Cout)
    x.contiguous()?
        .apply_op2(&w.contiguous()?, Conv3dForwardOp { geom })
}

/// The adjoint of [`conv3d`] in `x`: dy `(B, Do, Ho, Wo, Cout)`, w `(kD, kH, kW, Cin, Cout)` ->
/// `(B, D, H, W, Cin)` with `[D, H, W] = in_dims`, i.e.
/// `dx[b, i, ci] = Σ_{o, t : o·s + t = i + p} dy[b, o, co] · w[t, ci, co]`.
/// This is `conv3d`'s input gradient and a transposed convolution.
pub fn conv3d_input_grad(
    dy: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    in_dims: [usize; 3],
) -> Result<Tensor> {
    const OP: &str = "conv3d_input_grad";
    let dy_dims = dims_of(dy, OP, "dy", VOLUME_RANK)?;
    let w_dims = dims_of(w, OP, "w", VOLUME_RANK)?;
    let geom = Conv3dGeometry::new(
        dy_dims[0],
        in_dims,
        [w_dims[0], w_dims[1], w_dims[2]],
        stride,
        padding,
        w_dims[3],
        w_dims[4],
    )?;
    if dy_dims[1..4] != geom.out_dims || dy_dims[4] != geom.c_out {
        return Err(OpsError::Shape {
            op: OP,
            what: format!(
                "dy {dy_dims:?} does not match the convolution output {:?} of input {in_dims:?} \
                 with weights {w_dims:?}",
                geom.output_shape().dims()
            ),
        }
        .into());
    }
    if !has_custom_kernels(dy.device()) {
        count_flops(geom.flops());
        return composite::conv3d_input_grad_composite(dy, w, stride, padding, in_dims);
    }
    count_flops(geom.flops());
    // (B, Do, Ho, Wo, Cout) x (kD, kH, kW, Cin, Cout) -> (B, D, H, W, Cin)
    dy.contiguous()?
        .apply_op2(&w.contiguous()?, Conv3dInputGradOp { geom })
}

/// The gradient of [`conv3d`] in `w`: x `(B, D, H, W, Cin)`, dy `(B, Do, Ho, Wo, Cout)` ->
/// `(kD, kH, kW, Cin, Cout)`, `dw[t, ci, co] = Σ_{b, o} xp[b, o·s + t, ci] · dy[b, o, co]`.
pub fn conv3d_weight_grad(
    x: &Tensor,
    dy: &Tensor,
    kernel: [usize; 3],
    stride: [usize; 3],
    padding: [usize; 3],
) -> Result<Tensor> {
    const OP: &str = "conv3d_weight_grad";
    let x_dims = dims_of(x, OP, "x", VOLUME_RANK)?;
    let dy_dims = dims_of(dy, OP, "dy", VOLUME_RANK)?;
    let geom = Conv3dGeometry::new(
        x_dims[0],
        [x_dims[1], x_dims[2], x_dims[3]],
        kernel,
        stride,
        padding,
        x_dims[4],
        dy_dims[4],
    )?;
    if dy.dims() != geom.output_shape().dims() {
        return Err(OpsError::Shape {
            op: OP,
            what: format!(
                "dy {dy_dims:?} does not match the convolution output {:?} of x {x_dims:?}",
                geom.output_shape().dims()
            ),
        }
        .into());
    }
    count_flops(geom.flops());
    if !has_custom_kernels(x.device()) {
        return composite::conv3d_weight_grad_composite(x, dy, kernel, stride, padding);
    }
    // (B, D, H, W, Cin) x (B, Do, Ho, Wo, Cout) -> (kD, kH, kW, Cin, Cout)
    x.contiguous()?
        .apply_op2(&dy.contiguous()?, Conv3dWeightGradOp { geom })
}

/// Transposed 3-D convolution, channels-last: x `(B, D, H, W, Cin)`, w `(kD, kH, kW, Cin, Cout)`
/// -> `(B, Do, Ho, Wo, Cout)` with `Do = (D − 1) sD − 2 pD + kD + opD` and `output_padding < stride`.
///
/// It is the exact adjoint of a convolution: `conv_transpose3d(x, w, s, p, op)` equals
/// [`conv3d_input_grad`]`(x, w.transpose(3, 4), s, p, [Do, Ho, Wo])`, so
/// `conv3d(·, w.transpose(3, 4), s, p)` maps its output size back to `(D, H, W)`. For a x2
/// upsampling use `k = 3, s = 2, p = 1` and `op = target − (2 D − 1)` (1 for an even target).
pub fn conv_transpose3d(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    output_padding: [usize; 3],
) -> Result<Tensor> {
    const OP: &str = "conv_transpose3d";
    let x_dims = dims_of(x, OP, "x", VOLUME_RANK)?;
    let w_dims = dims_of(w, OP, "w", VOLUME_RANK)?;
    if x_dims[4] != w_dims[3] {
        return Err(OpsError::Shape {
            op: OP,
            what: format!(
                "x {x_dims:?} has {} channels, w {w_dims:?} expects {}",
                x_dims[4], w_dims[3]
            ),
        }
        .into());
    }
    let out_dims = transposed_out_dims(&x_dims, &w_dims, stride, padding, output_padding)?;
    // (kD, kH, kW, Cin, Cout) -> (kD, kH, kW, Cout, Cin): the convolution whose adjoint this is
    let w_conv = w.transpose(3, 4)?;
    conv3d_input_grad(x, &w_conv, stride, padding, out_dims)
}

/// The geometry of the convolution whose adjoint is the exact x2 upsampling of `x` by `w`
/// (kernel 3, stride 2, padding 1, even target): input `2 D`, output `D`, `Cin` = `w`'s `Cout`.
pub(super) fn x2_up_geometry(
    x: &Tensor,
    w: &Tensor,
    op: &'static str,
) -> std::result::Result<Conv3dGeometry, OpsError> {
    let x_dims = dims_of(x, op, "x", VOLUME_RANK)?;
    let w_dims = dims_of(w, op, "w", VOLUME_RANK)?;
    if w_dims[..3] != [3, 3, 3] || x_dims[4] != w_dims[3] {
        return Err(OpsError::Shape {
            op,
            what: format!(
                "x {x_dims:?} and w {w_dims:?}: expected a 3x3x3 kernel over x's channels"
            ),
        });
    }
    let geom = Conv3dGeometry::new(
        x_dims[0],
        [2 * x_dims[1], 2 * x_dims[2], 2 * x_dims[3]],
        [3; 3],
        [2; 3],
        [1; 3],
        w_dims[4],
        w_dims[3],
    )?;
    debug_assert!(is_exact_x2(&geom));
    Ok(geom)
}

/// `(D − 1) s − 2 p + k + op` per axis, checked.
fn transposed_out_dims(
    x_dims: &[usize],
    w_dims: &[usize],
    stride: [usize; 3],
    padding: [usize; 3],
    output_padding: [usize; 3],
) -> std::result::Result<[usize; 3], OpsError> {
    const OP: &str = "conv_transpose3d";
    let mut out = [0; SPATIAL_AXES_3D];
    for axis in 0..SPATIAL_AXES_3D {
        let (n, s, p, k, op) = (
            x_dims[axis + 1],
            stride[axis],
            padding[axis],
            w_dims[axis],
            output_padding[axis],
        );
        if s == 0 || op >= s {
            return Err(OpsError::Shape {
                op: OP,
                what: format!("axis {axis}: output_padding {op} must be smaller than stride {s}"),
            });
        }
        let full = n.saturating_sub(1) * s + k + op;
        if n == 0 || full <= 2 * p {
            return Err(OpsError::Shape {
                op: OP,
                what: format!(
                    "axis {axis}: input {n}, stride {s}, kernel {k}, padding {p} give no output"
                ),
            });
        }
        out[axis] = full - 2 * p;
    }
    Ok(out)
}

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

/// Forward kernel: one rayon task per output row `(b, od, oh)`, `kD·kH` GEMMs of
/// `(Wo × kW·Ci) · (kW·Ci × Co)` each.
pub(super) fn conv3d_forward_cpu(x: &[f32], w: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
    if let Some(y) = conv3d_forward_direct(x, w, g, &RowEpilogue::NONE) {
        return y;
    }
    if g.stride == [1; 3] {
        return conv3d_forward_planes_cpu(x, w, g);
    }
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
fn is_exact_x2(g: &Conv3dGeometry) -> bool {
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

/// Weight-gradient kernel: rayon fold over output rows with one `(kD, kH, kW, Ci, Co)`
/// accumulator per task; per `(a, c)` one GEMM `(kW·Ci × Wo) · (Wo × Co)`.
pub(super) fn conv3d_weight_grad_cpu(x: &[f32], dy: &[f32], g: &Conv3dGeometry) -> Vec<f32> {
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
        .reduce(
            || vec![0f32; w_len],
            |mut a, b| {
                a.iter_mut().zip(b.iter()).for_each(|(x, y)| *x += y);
                a
            },
        )
}

/// `(x, w) -> conv3d(x, w)`.
struct Conv3dForwardOp {
    geom: Conv3dGeometry,
}

impl CustomOp2 for Conv3dForwardOp {
    fn name(&self) -> &'static str {
        "conv3d"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let x = cpu_slice(s1, l1, self.name())?;
        let w = cpu_slice(s2, l2, self.name())?;
        let y = conv3d_forward_cpu(x, w, &self.geom);
        Ok((CpuStorage::F32(y), self.geom.output_shape()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _y: &Tensor,
        dy: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let g = &self.geom;
        let dx = conv3d_input_grad(dy, w, g.stride, g.padding, g.in_dims)?;
        let dw = conv3d_weight_grad(x, dy, g.kernel, g.stride, g.padding)?;
        Ok((Some(dx), Some(dw)))
    }
}

/// `(dy, w) -> conv3d_input_grad(dy, w)`; linear in each argument, so its gradients are a
/// convolution (for `dy`) and a weight gradient (for `w`).
struct Conv3dInputGradOp {
    geom: Conv3dGeometry,
}

impl CustomOp2 for Conv3dInputGradOp {
    fn name(&self) -> &'static str {
        "conv3d_input_grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let dy = cpu_slice(s1, l1, self.name())?;
        let w = cpu_slice(s2, l2, self.name())?;
        let dx = conv3d_input_grad_cpu(dy, w, &self.geom);
        Ok((CpuStorage::F32(dx), self.geom.input_shape()))
    }

    fn bwd(
        &self,
        dy: &Tensor,
        w: &Tensor,
        _dx: &Tensor,
        g_dx: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let g = &self.geom;
        let g_dy = conv3d(g_dx, w, g.stride, g.padding)?;
        let g_w = conv3d_weight_grad(g_dx, dy, g.kernel, g.stride, g.padding)?;
        Ok((Some(g_dy), Some(g_w)))
    }
}

/// `(x, dy) -> conv3d_weight_grad(x, dy)`.
struct Conv3dWeightGradOp {
    geom: Conv3dGeometry,
}

impl CustomOp2 for Conv3dWeightGradOp {
    fn name(&self) -> &'static str {
        "conv3d_weight_grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let x = cpu_slice(s1, l1, self.name())?;
        let dy = cpu_slice(s2, l2, self.name())?;
        let dw = conv3d_weight_grad_cpu(x, dy, &self.geom);
        Ok((CpuStorage::F32(dw), self.geom.weight_shape()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        dy: &Tensor,
        _dw: &Tensor,
        g_dw: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let g = &self.geom;
        let g_x = conv3d_input_grad(dy, g_dw, g.stride, g.padding, g.in_dims)?;
        let g_dy = conv3d(x, g_dw, g.stride, g.padding)?;
        Ok((Some(g_x), Some(g_dy)))
    }
}
