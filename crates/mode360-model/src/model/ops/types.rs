//! The types and helpers every op shares: errors, argument checks, the FLOP counter, the
//! convolution geometry, and the linear-axis map of the resampling ops ([`LinearAxisMap`]; the
//! sampling tables are in [`super::sample_table`], which imports from here). Kernels and
//! composites import from here and from nowhere above them, so `ops` has no import cycles:
//! `mod.rs` -> kernels -> `composite` -> `sample_table` -> `types`.

use std::cell::Cell;

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, Device, Layout, Result, Shape, Tensor};
use thiserror::Error;

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
    /// Set by [`with_composites`]: the custom kernels are off on this thread.
    static COMPOSITES_ONLY: Cell<bool> = const { Cell::new(false) };
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

/// Whether the ops take their fast custom CPU kernels for tensors on `device`: on the CPU,
/// unless [`with_composites`] switched them off; every other device (CUDA, Metal) takes the
/// device-generic composites.
pub fn has_custom_kernels(device: &Device) -> bool {
    matches!(device, Device::Cpu) && !COMPOSITES_ONLY.with(Cell::get)
}

/// Runs `f` with the custom kernels switched off on this thread, so that every op (forward and
/// backward) takes its device-generic composite on the CPU too: the path a GPU runs, for tests
/// and benchmarks on a machine without one. Restored on return, also when `f` panics.
pub fn with_composites<T>(f: impl FnOnce() -> T) -> T {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            COMPOSITES_ONLY.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(COMPOSITES_ONLY.with(|c| c.replace(true)));
    f()
}

/// What follows a fused convolution: `relu?(conv + bias + residual)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Epilogue<'a> {
    /// `(Cout)`.
    pub bias: Option<&'a Tensor>,
    /// Shaped like the output.
    pub residual: Option<&'a Tensor>,
    pub relu: bool,
}

/// Checks that `t` has rank `rank` and is f32; returns its dims.
pub(super) fn dims_of(
    t: &Tensor,
    op: &'static str,
    arg: &'static str,
    rank: usize,
) -> std::result::Result<Vec<usize>, OpsError> {
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

/// Rank of a channels-last volume `(B, D, H, W, C)` and of a 3-D kernel `(kD, kH, kW, Cin, Cout)`.
pub(super) const VOLUME_RANK: usize = 5;
/// Rank of a cost volume `(B, D, H, W)`.
pub(super) const COST_VOLUME_RANK: usize = 4;

/// Sizes of one 3-D convolution `x (B, D, H, W, Cin) * w (kD, kH, kW, Cin, Cout) -> (B, Do, Ho, Wo, Cout)`,
/// with `Do = ⌊(D + 2 pD − kD) / sD⌋ + 1` (likewise for H and W).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Conv3dGeometry {
    pub batch: usize,
    /// `[D, H, W]` of the convolution's input.
    pub in_dims: [usize; 3],
    /// `[Do, Ho, Wo]` of the convolution's output.
    pub out_dims: [usize; 3],
    /// `[kD, kH, kW]`.
    pub kernel: [usize; 3],
    pub stride: [usize; 3],
    /// Zeros added on both sides of each spatial axis of the input.
    pub padding: [usize; 3],
    pub c_in: usize,
    pub c_out: usize,
}

impl Conv3dGeometry {
    /// Validates the sizes and computes the output dims.
    pub fn new(
        batch: usize,
        in_dims: [usize; 3],
        kernel: [usize; 3],
        stride: [usize; 3],
        padding: [usize; 3],
        c_in: usize,
        c_out: usize,
    ) -> std::result::Result<Self, OpsError> {
        const OP: &str = "conv3d";
        let mut out_dims = [0; SPATIAL_AXES_3D];
        for axis in 0..SPATIAL_AXES_3D {
            if stride[axis] == 0 || kernel[axis] == 0 || in_dims[axis] == 0 {
                return Err(OpsError::Shape {
                    op: OP,
                    what: format!(
                        "axis {axis}: stride {}, kernel {} and input size {} must all be positive",
                        stride[axis], kernel[axis], in_dims[axis]
                    ),
                });
            }
            let padded = in_dims[axis] + 2 * padding[axis];
            if padded < kernel[axis] {
                return Err(OpsError::Shape {
                    op: OP,
                    what: format!(
                        "axis {axis}: padded input {padded} is smaller than the kernel {}",
                        kernel[axis]
                    ),
                });
            }
            out_dims[axis] = (padded - kernel[axis]) / stride[axis] + 1;
        }
        if batch == 0 || c_in == 0 || c_out == 0 {
            return Err(OpsError::Shape {
                op: OP,
                what: format!("batch {batch}, Cin {c_in} and Cout {c_out} must all be positive"),
            });
        }
        Ok(Self {
            batch,
            in_dims,
            out_dims,
            kernel,
            stride,
            padding,
            c_in,
            c_out,
        })
    }

    /// `[D + 2 pD, H + 2 pH, W + 2 pW]`.
    pub fn padded_dims(&self) -> [usize; 3] {
        std::array::from_fn(|axis| self.in_dims[axis] + 2 * self.padding[axis])
    }

    /// The output padding a transposed convolution needs to give back `in_dims` from `out_dims`:
    /// `(D + 2 pD − kD) mod sD` per axis.
    pub fn output_padding(&self) -> [usize; 3] {
        let padded = self.padded_dims();
        std::array::from_fn(|axis| (padded[axis] - self.kernel[axis]) % self.stride[axis])
    }

    /// Multiply-adds of the forward pass times two: `2 B Do Ho Wo kD kH kW Cin Cout`.
    pub fn flops(&self) -> f64 {
        2.0 * (self.batch
            * self.out_dims.iter().product::<usize>()
            * self.kernel.iter().product::<usize>()
            * self.c_in
            * self.c_out) as f64
    }

    pub(super) fn input_shape(&self) -> Shape {
        let [d, h, w] = self.in_dims;
        Shape::from((self.batch, d, h, w, self.c_in))
    }

    pub(super) fn output_shape(&self) -> Shape {
        let [d, h, w] = self.out_dims;
        Shape::from((self.batch, d, h, w, self.c_out))
    }

    pub(super) fn weight_shape(&self) -> Shape {
        let [kd, kh, kw] = self.kernel;
        Shape::from((kd, kh, kw, self.c_in, self.c_out))
    }
}

pub(super) fn conv_geometry_from(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    op: &'static str,
) -> std::result::Result<Conv3dGeometry, OpsError> {
    let x_dims = dims_of(x, op, "x", VOLUME_RANK)?;
    let w_dims = dims_of(w, op, "w", VOLUME_RANK)?;
    if x_dims[4] != w_dims[3] {
        return Err(OpsError::Shape {
            op,
            what: format!(
                "x {x_dims:?} has {} channels, w {w_dims:?} expects {}",
                x_dims[4], w_dims[3]
            ),
        });
    }
    Conv3dGeometry::new(
        x_dims[0],
        [x_dims[1], x_dims[2], x_dims[3]],
        [w_dims[0], w_dims[1], w_dims[2]],
        stride,
        padding,
        w_dims[3],
        w_dims[4],
    )
}

/// The contiguous f32 data of a custom op argument.
pub(super) fn cpu_slice<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
    op: &'static str,
) -> Result<&'a [f32]> {
    let CpuStorage::F32(data) = storage else {
        return Err(OpsError::DType {
            op,
            arg: "input",
            dtype: format!("{:?}", storage.dtype()),
        }
        .into());
    };
    let Some((start, end)) = layout.contiguous_offsets() else {
        return Err(OpsError::Shape {
            op,
            what: "argument is not contiguous".to_string(),
        }
        .into());
    };
    Ok(&data[start..end])
}

/// A sparse `(n_out × n_in)` matrix stored as rows of `(source index, weight)`.
#[derive(Debug)]
pub(super) struct AxisRows {
    /// `n_out + 1` offsets into `src` and `weight`.
    pub(super) start: Vec<usize>,
    pub(super) src: Vec<u32>,
    pub(super) weight: Vec<f32>,
}

impl AxisRows {
    pub(super) fn out_len(&self) -> usize {
        self.start.len() - 1
    }

    /// The transposed matrix, `(n_in × n_out)`.
    fn transpose(&self, in_len: usize) -> Self {
        let mut start = vec![0usize; in_len + 1];
        for &i in &self.src {
            start[i as usize + 1] += 1;
        }
        for i in 0..in_len {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut src = vec![0u32; self.src.len()];
        let mut weight = vec![0f32; self.src.len()];
        for j in 0..self.out_len() {
            for e in self.start[j]..self.start[j + 1] {
                let slot = &mut fill[self.src[e] as usize];
                src[*slot] = j as u32;
                weight[*slot] = self.weight[e];
                *slot += 1;
            }
        }
        Self { start, src, weight }
    }
}

/// The linear interpolation weights mapping an axis of `n_in` samples to `n_out`
/// (`align_corners = false`), and their transpose for the backward pass.
#[derive(Debug)]
pub struct LinearAxisMap {
    in_len: usize,
    lower: Vec<u32>,
    upper: Vec<u32>,
    upper_weight: Vec<f32>,
    pub(super) forward: AxisRows,
    pub(super) backward: AxisRows,
}

impl LinearAxisMap {
    /// The map from `in_len` samples to `out_len`; both must be positive.
    pub fn new(in_len: usize, out_len: usize) -> std::result::Result<Self, OpsError> {
        if in_len == 0 || out_len == 0 || in_len > u32::MAX as usize {
            return Err(OpsError::Shape {
                op: "resample_linear_axis",
                what: format!("cannot resample an axis of {in_len} samples to {out_len}"),
            });
        }
        let scale = in_len as f64 / out_len as f64;
        let mut lower = Vec::with_capacity(out_len);
        let mut upper = Vec::with_capacity(out_len);
        let mut upper_weight = Vec::with_capacity(out_len);
        for j in 0..out_len {
            let src = ((j as f64 + 0.5) * scale - 0.5).max(0.0);
            let i0 = (src.floor() as usize).min(in_len - 1);
            let i1 = (i0 + 1).min(in_len - 1);
            lower.push(i0 as u32);
            upper.push(i1 as u32);
            upper_weight.push((src - i0 as f64) as f32);
        }
        let forward = AxisRows {
            start: (0..=out_len).map(|j| 2 * j).collect(),
            src: lower
                .iter()
                .zip(&upper)
                .flat_map(|(&a, &b)| [a, b])
                .collect(),
            weight: upper_weight.iter().flat_map(|&l| [1.0 - l, l]).collect(),
        };
        let backward = forward.transpose(in_len);
        Ok(Self {
            in_len,
            lower,
            upper,
            upper_weight,
            forward,
            backward,
        })
    }

    pub fn in_len(&self) -> usize {
        self.in_len
    }

    pub fn out_len(&self) -> usize {
        self.lower.len()
    }

    /// `i0` per output index.
    pub fn lower_indices(&self) -> &[u32] {
        &self.lower
    }

    /// `i1` per output index.
    pub fn upper_indices(&self) -> &[u32] {
        &self.upper
    }

    /// `λ` (the weight of `i1`) per output index.
    pub fn upper_weights(&self) -> &[f32] {
        &self.upper_weight
    }
}

/// `a + b` elementwise, into `a` (per-task accumulators of a rayon fold: weight and bias
/// gradients).
pub(super) fn add_into(mut a: Vec<f32>, b: Vec<f32>) -> Vec<f32> {
    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
    a
}
