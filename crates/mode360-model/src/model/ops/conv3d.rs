//! Channels-last 3-D convolution, its adjoint (transposed convolution) and its weight gradient,
//! as candle custom ops: argument checks, FLOP counting, the choice between the CPU kernels
//! ([`super::conv3d_gemm`], [`super::conv3d_direct`]) and the composite, and the gradients.

use super::composite;
use super::conv3d_direct::RowEpilogue;
use super::conv3d_gemm::{
    conv3d_forward_cpu, conv3d_input_grad_cpu, conv3d_weight_grad_cpu, is_exact_x2,
};
use super::types::{
    conv_geometry_from, count_flops, cpu_slice, dims_of, has_custom_kernels, Conv3dGeometry,
    OpsError, SPATIAL_AXES_3D, VOLUME_RANK,
};
use candle_core::{CpuStorage, CustomOp2, Layout, Result, Shape, Tensor};

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
        let y = conv3d_forward_cpu(x, w, &self.geom, &RowEpilogue::NONE);
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
        // only the gradients something upstream learns from (the fine head reads the volume
        // detached: its input gradient would cost twice its weight gradient, for nothing)
        let dx = needs_grad(x)
            .then(|| conv3d_input_grad(dy, w, g.stride, g.padding, g.in_dims))
            .transpose()?;
        let dw = needs_grad(w)
            .then(|| conv3d_weight_grad(x, dy, g.kernel, g.stride, g.padding))
            .transpose()?;
        Ok((dx, dw))
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
        let g_dy = needs_grad(dy)
            .then(|| conv3d(g_dx, w, g.stride, g.padding))
            .transpose()?;
        let g_w = needs_grad(w)
            .then(|| conv3d_weight_grad(g_dx, dy, g.kernel, g.stride, g.padding))
            .transpose()?;
        Ok((g_dy, g_w))
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
        let g_x = needs_grad(x)
            .then(|| conv3d_input_grad(dy, g_dw, g.stride, g.padding, g.in_dims))
            .transpose()?;
        let g_dy = needs_grad(dy)
            .then(|| conv3d(x, g_dw, g.stride, g.padding))
            .transpose()?;
        Ok((g_x, g_dy))
    }
}

/// Whether a gradient with respect to `t` reaches anything that learns: `t` is a variable or
/// was computed from one (candle records the op only then). A detached or constant input
/// gets none, which candle's backward pass reads as no contribution.
fn needs_grad(t: &Tensor) -> bool {
    t.track_op()
}
