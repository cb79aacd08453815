//! Inference-only convolutions with what follows them in the cost aggregation fused in:
//!
//! ```text
//! y = relu?(conv3d(x, w) + bias + residual)            conv3d_fused
//! y = relu?(conv_transpose3d_x2(x, w) + bias + residual)   conv_transpose3d_x2_fused
//! ```
//!
//! At 48x64x128 cells and 8 channels every separate bias, ReLU or residual pass allocates and
//! writes another 12.6 MB; fused, the epilogue runs on each output row while it is in cache.
//! These ops carry no gradient: the layers call them only when nothing is tracked (see
//! [`is_inference`]) and compose the differentiable ops otherwise, with the same result.

use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor};

use super::composite;
use super::conv3d::x2_up_geometry;
use super::conv3d_direct::RowEpilogue;
use super::conv3d_gemm::{conv3d_forward_cpu, conv3d_input_grad_cpu};
pub use super::types::Epilogue;
use super::types::{
    conv_geometry_from, count_flops, cpu_slice, has_custom_kernels, Conv3dGeometry, OpsError,
};

/// Whether `conv` over `x` and `w` can take the fused CPU kernels: CPU tensors with no gradient
/// to track. (On other devices the fused ops run their composites, which are what the layers
/// compose anyway.)
pub fn is_inference(x: &Tensor, w: &Tensor) -> bool {
    has_custom_kernels(x.device()) && !x.track_op() && !w.track_op()
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    /// `conv3d(x, w)` with the op's geometry.
    Forward,
    /// The adjoint of the op's geometry (a transposed convolution), `w` already `(…, Cout, Cin)`
    /// of that convolution.
    Transposed,
}

struct FusedConvOp {
    geom: Conv3dGeometry,
    kind: Kind,
    bias: Option<Vec<f32>>,
    relu: bool,
}

impl FusedConvOp {
    fn output_shape(&self) -> Shape {
        let g = &self.geom;
        match self.kind {
            Kind::Forward => {
                let [d, h, w] = g.out_dims;
                Shape::from((g.batch, d, h, w, g.c_out))
            }
            Kind::Transposed => {
                let [d, h, w] = g.in_dims;
                Shape::from((g.batch, d, h, w, g.c_in))
            }
        }
    }

    fn compute(&self, x: &[f32], w: &[f32], residual: Option<&[f32]>) -> Result<CpuStorage> {
        let epilogue = RowEpilogue {
            bias: self.bias.as_deref(),
            residual,
            relu: self.relu,
        };
        // (the residual's shape was checked against the output when the op was applied)
        let y = match self.kind {
            Kind::Forward => conv3d_forward_cpu(x, w, &self.geom, &epilogue),
            Kind::Transposed => {
                let mut y = conv3d_input_grad_cpu(x, w, &self.geom);
                epilogue.apply(&mut y, 0, self.geom.c_in);
                y
            }
        };
        Ok(CpuStorage::F32(y))
    }
}

impl CustomOp2 for FusedConvOp {
    fn name(&self) -> &'static str {
        "conv3d_fused"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let name = CustomOp2::name(self);
        let x = cpu_slice(s1, l1, name)?;
        let w = cpu_slice(s2, l2, name)?;
        Ok((self.compute(x, w, None)?, self.output_shape()))
    }
}

impl CustomOp3 for FusedConvOp {
    fn name(&self) -> &'static str {
        "conv3d_fused"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let name = CustomOp2::name(self);
        let x = cpu_slice(s1, l1, name)?;
        let w = cpu_slice(s2, l2, name)?;
        let r = cpu_slice(s3, l3, name)?;
        Ok((self.compute(x, w, Some(r))?, self.output_shape()))
    }
}

fn apply(
    x: &Tensor,
    w: &Tensor,
    geom: Conv3dGeometry,
    kind: Kind,
    epilogue: Epilogue,
) -> Result<Tensor> {
    count_flops(geom.flops());
    let bias = epilogue
        .bias
        .map(|b| b.flatten_all()?.to_vec1::<f32>())
        .transpose()?;
    let op = FusedConvOp {
        geom,
        kind,
        bias,
        relu: epilogue.relu,
    };
    let (x, w) = (x.contiguous()?, w.contiguous()?);
    match epilogue.residual {
        Some(r) => {
            if r.dims() != op.output_shape().dims() {
                return Err(OpsError::Shape {
                    op: "conv3d_fused",
                    what: format!(
                        "residual {:?} for an output {:?}",
                        r.dims(),
                        op.output_shape().dims()
                    ),
                }
                .into());
            }
            x.apply_op3(&w, &r.contiguous()?, op)
        }
        None => x.apply_op2(&w, op),
    }
}

/// `relu?(conv3d(x, w, stride, padding) + bias + residual)`. The CPU kernel is for inference
/// only (no gradient; check [`is_inference`] first); other devices run the composite.
pub fn conv3d_fused(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    epilogue: Epilogue,
) -> Result<Tensor> {
    let geom = conv_geometry_from(x, w, stride, padding, "conv3d_fused")?;
    if !has_custom_kernels(x.device()) {
        count_flops(geom.flops());
        return composite::conv3d_fused_composite(x, w, stride, padding, epilogue);
    }
    apply(x, w, geom, Kind::Forward, epilogue)
}

/// `relu?(conv_transpose3d(x, w, 2, 1, 1) + bias + residual)`: the hourglasses' exact x2
/// upsampling (kernel 3); the CPU kernel for inference only, other devices the composite.
pub fn conv_transpose3d_x2_fused(x: &Tensor, w: &Tensor, epilogue: Epilogue) -> Result<Tensor> {
    let geom = x2_up_geometry(x, w, "conv_transpose3d_x2_fused")?;
    if !has_custom_kernels(x.device()) {
        count_flops(geom.flops());
        return composite::conv_transpose3d_x2_fused_composite(x, w, epilogue);
    }
    // (kD, kH, kW, Cin, Cout) -> (kD, kH, kW, Cout, Cin): the convolution whose adjoint this is
    let w_conv = w.transpose(3, 4)?;
    apply(x, &w_conv, geom, Kind::Transposed, epilogue)
}
