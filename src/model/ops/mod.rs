//! Tensor operations candle 0.11 lacks, with gradients through candle's autograd.
//!
//! Every op has two implementations:
//! - a fast CPU kernel written as a candle `CustomOp` (`cpu_fwd` over the `gemm` crate and rayon,
//!   `bwd` built from further ops of this module, so higher derivatives work too);
//! - a composite built only from candle ops (matmul, index_select, pad, narrow, reshape), used
//!   automatically when the tensor does not live on the CPU device (CUDA, Metal).
//!
//! Layouts are channels-last: volumes are `(B, D, H, W, C)`, images `(B, H, W, C)`.
//!
//! | op | input | output |
//! |----|-------|--------|
//! | [`conv3d`] | x `(B, D, H, W, Cin)`, w `(kD, kH, kW, Cin, Cout)` | `(B, Do, Ho, Wo, Cout)` |
//! | [`conv_transpose3d`] | x `(B, D, H, W, Cin)`, w `(kD, kH, kW, Cin, Cout)` | `(B, Do, Ho, Wo, Cout)` |
//! | [`conv3d_fused`], [`conv_transpose3d_x2_fused`] | as above, plus bias, residual, ReLU (inference only) | as above |
//! | [`table_sample`] | features `(B, H, W, C)`, [`SampleTable`] of N taps | `(B, N, C)` |
//! | [`sweep_variance`] | features `(M B, H, W, C)`, M tables of N samples | `(B, N, C)` |
//! | [`upsample_trilinear`] | cost volume `(B, D, H, W)` | `(B, Do, Ho, Wo)` |
//! | [`resample_linear_axis`] | any tensor, one axis | same rank, that axis resized |

pub mod composite;
mod conv3d;
mod conv3d_direct;
mod fused;
mod linear_axis;
mod sweep;
mod table;

use std::cell::Cell;

use candle_core::{Device, Tensor};
use thiserror::Error;

pub use composite::{
    conv3d_composite, conv3d_input_grad_composite, conv3d_weight_grad_composite,
    conv_transpose3d_composite, resample_linear_axis_composite, table_sample_composite,
    upsample_trilinear_composite,
};
pub use conv3d::{conv3d, conv3d_input_grad, conv3d_weight_grad, conv_transpose3d, Conv3dGeometry};
pub use fused::{conv3d_fused, conv_transpose3d_x2_fused, is_inference, Epilogue};
pub use linear_axis::{resample_linear_axis, upsample_trilinear, LinearAxisMap};
pub use sweep::sweep_variance;
pub use table::{table_sample, SampleTable};

/// Number of spatial axes of a 3-D convolution (D, H, W).
pub const SPATIAL_AXES_3D: usize = 3;

/// Bad arguments to one of the ops (shapes, strides, table indices).
#[derive(Debug, Error)]
pub enum OpsError {
    #[error("{op}: `{arg}` must have rank {expected}, got shape {shape:?}")]
    Rank {
        op: &'static str,
        arg: &'static str,
        expected: usize,
        shape: Vec<usize>,
    },
    #[error("{op}: {what}")]
    Shape { op: &'static str, what: String },
    #[error("{op}: `{arg}` must be f32, got {dtype}")]
    DType {
        op: &'static str,
        arg: &'static str,
        dtype: String,
    },
    #[error("{op}: sample table index {index} out of range for {pixels} feature pixels")]
    TableIndex {
        op: &'static str,
        index: u32,
        pixels: usize,
    },
}

impl From<OpsError> for candle_core::Error {
    fn from(e: OpsError) -> Self {
        candle_core::Error::wrap(e)
    }
}

thread_local! {
    /// Floating-point operations issued from this thread by the convolutions and matrix
    /// products of the model (multiply-adds count two), for the benchmark's GFLOP/s. Per
    /// thread, so that concurrent passes on other threads do not count.
    static FLOPS: Cell<u64> = const { Cell::new(0) };
}

/// Floating-point operations this thread issued so far (see [`count_flops`]); take differences.
pub fn flop_count() -> u64 {
    FLOPS.with(Cell::get)
}

/// Adds `flops` to this thread's counter read by [`flop_count`].
pub fn count_flops(flops: f64) {
    FLOPS.with(|f| f.set(f.get().wrapping_add(flops as u64)));
}

/// Whether the fast custom CPU kernels can run on tensors on `device`.
pub fn has_custom_kernels(device: &Device) -> bool {
    matches!(device, Device::Cpu)
}

/// Checks that `t` has rank `rank` and is f32; returns its dims.
fn dims_of(
    t: &Tensor,
    op: &'static str,
    arg: &'static str,
    rank: usize,
) -> Result<Vec<usize>, OpsError> {
    if t.dtype() != candle_core::DType::F32 {
        return Err(OpsError::DType {
            op,
            arg,
            dtype: format!("{:?}", t.dtype()),
        });
    }
    let dims = t.dims().to_vec();
    if dims.len() != rank {
        return Err(OpsError::Rank {
            op,
            arg,
            expected: rank,
            shape: dims,
        });
    }
    Ok(dims)
}
