//! Tensor operations candle 0.11 lacks, with gradients through candle's autograd.
//!
//! Every op has two implementations:
//! - a fast CPU kernel written as a candle `CustomOp` (`cpu_fwd` over the `gemm` crate and rayon,
//!   `bwd` built from further ops of this module, so higher derivatives work too);
//! - a composite built only from candle ops (matmul, index_select, pad, narrow, reshape), used
//!   automatically when the tensor does not live on the CPU device (CUDA, Metal), or on the CPU
//!   inside [`with_composites`] (how the tests check the GPU's path on a machine without one).
//!   The table gather and its adjoint also have CUDA kernels (`table_cuda`, the `cuda` feature):
//!   their composites' gradient (`index_add`) is serial over the table on a GPU.
//!
//! Every public op below has its composite in [`composite`] (`…_composite`), and the choice
//! between the two is made in the op itself by [`has_custom_kernels`]; the backward passes of
//! the kernels dispatch the same way, so a composite's gradient never meets a CPU kernel.
//!
//! Layouts are channels-last: volumes are `(B, D, H, W, C)`, images `(B, H, W, C)`.
//!
//! | op | input | output |
//! |----|-------|--------|
//! | [`conv3d`] | x `(B, D, H, W, Cin)`, w `(kD, kH, kW, Cin, Cout)` | `(B, Do, Ho, Wo, Cout)` |
//! | [`conv_transpose3d`] | x `(B, D, H, W, Cin)`, w `(kD, kH, kW, Cin, Cout)` | `(B, Do, Ho, Wo, Cout)` |
//! | [`conv3d_fused`], [`conv_transpose3d_x2_fused`] | as above, plus bias, residual, ReLU (inference only) | as above |
//! | [`table_sample`] | features `(B, H, W, C)`, [`SampleTable`] of N taps | `(B, N, C)` |
//! | [`append_channels`] | a `(…, C1)`, b `(…, C2)` | `(…, C1 + C2)` (`cat` on the last axis) |
//! | [`add_bias`] | y `(…, C)`, b `(C)` | `(…, C)` (`broadcast_add`) |
//! | [`sweep_variance`] | features `(M B, H, W, C)`, M tables of N samples | `(B, N, C)` |
//! | [`upsample_trilinear`] | cost volume `(B, D, H, W)` | `(B, Do, Ho, Wo)` |
//! | [`resample_linear_axis`] | any tensor, one axis | same rank, that axis resized |
//! | [`fine_mix`] | up `(…)`, part `(…, Cf)`, w `(2, Cf)` | `(…)` (the fine head's per-cell layers) |
//! | [`soft_argmin_index`] | cost `(B, N, H, W)` | `(B, H, W)` (softmax over `N`, expected index in [0, 1]) |

mod append;
mod bias;
pub mod composite;
mod conv3d;
mod conv3d_direct;
mod conv3d_gemm;
mod fine_mix;
mod fused;
mod linear_axis;
mod sample_table;
mod soft_argmin;
mod sweep;
mod table;
#[cfg(feature = "cuda")]
mod table_cuda;
mod types;

pub use append::append_channels;
pub use bias::add_bias;
pub use composite::{
    conv3d_composite, conv3d_fused_composite, conv3d_input_grad_composite,
    conv3d_weight_grad_composite, conv_transpose3d_composite, conv_transpose3d_x2_fused_composite,
    fine_mix_composite, resample_linear_axis_composite, soft_argmin_index_composite,
    sweep_variance_composite, table_sample_composite, upsample_trilinear_composite,
};
pub use conv3d::{conv3d, conv3d_input_grad, conv3d_weight_grad, conv_transpose3d};
pub use fine_mix::fine_mix;
pub use fused::{conv3d_fused, conv_transpose3d_x2_fused, is_inference, Epilogue};
pub use linear_axis::{resample_linear_axis, upsample_trilinear};
pub use sample_table::SampleTable;
pub use soft_argmin::soft_argmin_index;
pub use sweep::{
    sweep_variance, sweep_variance_appended, sweep_variance_appended_window,
    sweep_variance_visible, view_scale, MIN_VIEWS,
};
pub use table::table_sample;
pub use types::{
    count_flops, flop_count, has_custom_kernels, with_composites, Conv3dGeometry, LinearAxisMap,
    OpsError, SPATIAL_AXES_3D,
};
