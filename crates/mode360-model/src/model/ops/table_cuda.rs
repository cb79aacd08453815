//! CUDA kernels of the table ops (the `cuda` feature): the sweep's bilinear gather and its
//! adjoint, the ops whose composites are slow on a GPU.
//!
//! The composite gathers with `index_select`, whose gradient is candle's `index_add`; its CUDA
//! kernel runs one thread per (row, channel) and walks every index in turn, so the adjoint of a
//! table of millions of taps ran on a handful of threads (a training step at 256 took 10 to
//! 20 s on an H200). Here both directions run one thread per output element:
//! - gather: `out[b, n, c] = Σ_{k<4} w[n][k] · f[b, index[n][k], c]`;
//! - adjoint: `grad_f[b, index[n][k], c] += w[n][k] · g[b, n, c]` with `atomicAdd`.
//!
//! The kernels are compiled once per process with NVRTC and loaded into each device on first
//! use.

use std::sync::OnceLock;

use candle_core::cuda_backend::cudarc::driver::{LaunchConfig, PushKernelArg};
use candle_core::cuda_backend::cudarc::nvrtc;
use candle_core::cuda_backend::{CudaStorage, WrapErr};
use candle_core::{Layout, Result, Storage};

use super::sample_table::{DeviceTable, SampleTable};
use super::types::OpsError;

/// Module name under which the device keeps the kernels.
const MODULE: &str = "mode360_table";

/// CUDA C source of both kernels; `TAPS` is [`SampleTable::TAPS`].
const SOURCE: &str = r#"
#define TAPS 4
typedef unsigned long long u64;

// Element i of a (batch, samples, channels) array: its sample `n`, and the offset of its batch
// item and channel in a (batch, pixels, channels) array.
__device__ inline void element(u64 i, u64 samples, u64 pixels, u64 channels, u64 *n,
                               u64 *image_offset) {
    const u64 c = i % channels;
    const u64 b = i / (channels * samples);
    *n = (i / channels) % samples;
    *image_offset = b * pixels * channels + c;
}

extern "C" __global__ void table_gather(const float *f, const unsigned int *index,
                                        const float *weight, float *out, u64 batch,
                                        u64 samples, u64 pixels, u64 channels) {
    const u64 total = batch * samples * channels;
    for (u64 i = blockIdx.x * (u64)blockDim.x + threadIdx.x; i < total;
         i += (u64)blockDim.x * gridDim.x) {
        u64 n, offset;
        element(i, samples, pixels, channels, &n, &offset);
        float acc = 0.0f;
        for (int k = 0; k < TAPS; ++k) {
            acc += weight[n * TAPS + k] * f[offset + (u64)index[n * TAPS + k] * channels];
        }
        out[i] = acc;
    }
}

extern "C" __global__ void table_adjoint(const float *g, const unsigned int *index,
                                         const float *weight, float *out, u64 batch,
                                         u64 samples, u64 pixels, u64 channels) {
    const u64 total = batch * samples * channels;
    for (u64 i = blockIdx.x * (u64)blockDim.x + threadIdx.x; i < total;
         i += (u64)blockDim.x * gridDim.x) {
        u64 n, offset;
        element(i, samples, pixels, channels, &n, &offset);
        const float v = g[i];
        for (int k = 0; k < TAPS; ++k) {
            atomicAdd(out + offset + (u64)index[n * TAPS + k] * channels,
                      weight[n * TAPS + k] * v);
        }
    }
}
"#;

/// The PTX of [`SOURCE`], compiled on first use.
fn ptx() -> Result<&'static str> {
    static PTX: OnceLock<std::result::Result<String, String>> = OnceLock::new();
    PTX.get_or_init(|| {
        nvrtc::compile_ptx(SOURCE)
            .map(|p| p.to_src())
            .map_err(|e| e.to_string())
    })
    .as_deref()
    .map_err(|e| {
        OpsError::Shape {
            op: "table_cuda",
            what: format!("NVRTC could not compile the table kernels: {e}"),
        }
        .into()
    })
}

/// Which kernel to run.
#[derive(Clone, Copy, Debug)]
pub(super) enum TableKernel {
    /// `(B, pixels, C)` -> `(B, N, C)`.
    Gather,
    /// `(B, N, C)` -> `(B, pixels, C)`, zero-initialised and accumulated.
    Adjoint,
}

impl TableKernel {
    fn name(self) -> &'static str {
        match self {
            Self::Gather => "table_gather",
            Self::Adjoint => "table_adjoint",
        }
    }
}

/// Runs `kernel` on the contiguous f32 input `storage` (`layout`), for `batch` items of a table
/// of `table.len()` samples over `pixels` pixels of `channels` channels; returns the output
/// storage (`(B, N, C)` for the gather, `(B, pixels, C)` for the adjoint).
pub(super) fn run(
    kernel: TableKernel,
    table: &SampleTable,
    storage: &CudaStorage,
    layout: &Layout,
    batch: usize,
    pixels: usize,
    channels: usize,
) -> Result<CudaStorage> {
    let op = kernel.name();
    let Some((start, end)) = layout.contiguous_offsets() else {
        return Err(OpsError::Shape {
            op,
            what: "input must be contiguous".to_string(),
        }
        .into());
    };
    let input = storage.as_cuda_slice::<f32>()?.slice(start..end);
    let device = storage.device.clone();
    let samples = table.len();
    let DeviceTable { index, weight } =
        table.on_device(&candle_core::Device::Cuda(device.clone()))?;
    let (index_storage, _) = index.storage_and_layout();
    let (weight_storage, _) = weight.storage_and_layout();
    let (Storage::Cuda(index_storage), Storage::Cuda(weight_storage)) =
        (&*index_storage, &*weight_storage)
    else {
        return Err(OpsError::Shape {
            op,
            what: "the sample table is not on the CUDA device".to_string(),
        }
        .into());
    };
    let index = index_storage.as_cuda_slice::<u32>()?;
    let weight = weight_storage.as_cuda_slice::<f32>()?;
    let out_len = match kernel {
        TableKernel::Gather => batch * samples * channels,
        TableKernel::Adjoint => batch * pixels * channels,
    };
    let out = device.alloc_zeros::<f32>(out_len)?;
    let threads = batch * samples * channels;
    if threads > 0 {
        let func = device.get_or_load_custom_func(op, MODULE, ptx()?)?;
        let mut builder = func.builder();
        builder.arg(&input);
        builder.arg(index);
        builder.arg(weight);
        builder.arg(&out);
        let dims = [batch, samples, pixels, channels].map(|d| d as u64);
        for d in &dims {
            builder.arg(d);
        }
        let cfg = LaunchConfig::for_num_elems(threads.min(u32::MAX as usize) as u32);
        // SAFETY: the kernel reads `input` (batch·pixels·C for the gather, batch·N·C for the
        // adjoint), `index` and `weight` (4 N each, indices below `pixels`: checked by
        // `SampleTable::check_pixels` before the op is built) and writes `out` within `out_len`.
        unsafe { builder.launch(cfg) }.w()?;
    }
    Ok(CudaStorage::wrap_cuda_slice(out, device))
}
