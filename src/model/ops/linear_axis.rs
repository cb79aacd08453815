//! Linear resampling along one axis, and trilinear upsampling of a cost volume as three of them.
//!
//! Semantics are PyTorch's `F.interpolate(mode='linear'|'trilinear', align_corners=False)` with
//! an explicit output size: for output index `j` of `n_out` from `n_in`,
//! `src = max(0, (j + 0.5) · n_in / n_out − 0.5)`, `i0 = ⌊src⌋`, `i1 = min(i0 + 1, n_in − 1)`,
//! `λ = src − i0`, and `out[j] = (1 − λ) · in[i0] + λ · in[i1]`.
//! The backward pass applies the transposed map (a gather over compressed rows).

use std::sync::Arc;

use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

use super::conv3d::cpu_slice;
use super::{composite, dims_of, has_custom_kernels, OpsError};

/// Rank of a cost volume `(B, D, H, W)`.
const COST_VOLUME_RANK: usize = 4;
/// Fewest output elements per rayon task.
const MIN_ELEMENTS_PER_TASK: usize = 4096;

/// A sparse `(n_out × n_in)` matrix stored as rows of `(source index, weight)`.
#[derive(Debug)]
struct AxisRows {
    /// `n_out + 1` offsets into `src` and `weight`.
    start: Vec<usize>,
    src: Vec<u32>,
    weight: Vec<f32>,
}

impl AxisRows {
    fn out_len(&self) -> usize {
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
    forward: AxisRows,
    backward: AxisRows,
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

/// Linearly resamples axis `dim` of `x` to `out_len` samples (`align_corners = false`), with
/// gradient. Every other axis is unchanged.
pub fn resample_linear_axis(x: &Tensor, dim: usize, out_len: usize) -> Result<Tensor> {
    const OP: &str = "resample_linear_axis";
    if x.dtype() != candle_core::DType::F32 {
        return Err(OpsError::DType {
            op: OP,
            arg: "x",
            dtype: format!("{:?}", x.dtype()),
        }
        .into());
    }
    if dim >= x.rank() {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("axis {dim} out of range for shape {:?}", x.dims()),
        }
        .into());
    }
    let map = LinearAxisMap::new(x.dim(dim)?, out_len)?;
    if !has_custom_kernels(x.device()) {
        return composite::resample_linear_axis_composite(x, dim, &map);
    }
    x.contiguous()?.apply_op1(LinearAxisOp {
        map: Arc::new(map),
        dim,
        transposed: false,
    })
}

/// Trilinear upsampling (or downsampling) of a cost volume `(B, D, H, W)` to
/// `(B, out_d, out_h, out_w)`, like PyTorch's `F.interpolate(mode='trilinear',
/// align_corners=False)`; separable, so applied as three [`resample_linear_axis`].
pub fn upsample_trilinear(x: &Tensor, out_d: usize, out_h: usize, out_w: usize) -> Result<Tensor> {
    dims_of(x, "upsample_trilinear", "x", COST_VOLUME_RANK)?;
    // (B, D, H, W) -> (B, D, H, Wo) -> (B, D, Ho, Wo) -> (B, Do, Ho, Wo)
    let t = resample_linear_axis(x, 3, out_w)?;
    let t = resample_linear_axis(&t, 2, out_h)?;
    resample_linear_axis(&t, 1, out_d)
}

/// `x -> map · x` along `dim` (or `mapᵀ · x` when `transposed`).
struct LinearAxisOp {
    map: Arc<LinearAxisMap>,
    dim: usize,
    transposed: bool,
}

impl CustomOp1 for LinearAxisOp {
    fn name(&self) -> &'static str {
        "resample_linear_axis"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let x = cpu_slice(storage, layout, self.name())?;
        let (rows, in_len) = if self.transposed {
            (&self.map.backward, self.map.out_len())
        } else {
            (&self.map.forward, self.map.in_len())
        };
        let dims = layout.shape().dims();
        if dims.get(self.dim) != Some(&in_len) {
            return Err(OpsError::Shape {
                op: self.name(),
                what: format!("axis {} of {dims:?} is not {in_len} long", self.dim),
            }
            .into());
        }
        let out_len = rows.out_len();
        let inner: usize = dims[self.dim + 1..].iter().product();
        let outer: usize = dims[..self.dim].iter().product();
        let mut out = vec![0f32; outer * out_len * inner];
        // (outer, n_in, inner) -> (outer, n_out, inner), one chunk of `inner` per (o, j)
        out.par_chunks_mut(inner.max(1))
            .enumerate()
            .with_min_len((MIN_ELEMENTS_PER_TASK / inner.max(1)).max(1))
            .for_each(|(k, o)| {
                let (outer_idx, j) = (k / out_len, k % out_len);
                let base = outer_idx * in_len * inner;
                for e in rows.start[j]..rows.start[j + 1] {
                    let (i, w) = (rows.src[e] as usize, rows.weight[e]);
                    let src = &x[base + i * inner..base + (i + 1) * inner];
                    for (o, v) in o.iter_mut().zip(src) {
                        *o += w * v;
                    }
                }
            });
        let mut out_dims = dims.to_vec();
        out_dims[self.dim] = out_len;
        Ok((CpuStorage::F32(out), Shape::from(out_dims)))
    }

    fn bwd(&self, _x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> Result<Option<Tensor>> {
        let grad = grad_y.contiguous()?.apply_op1(LinearAxisOp {
            map: self.map.clone(),
            dim: self.dim,
            transposed: !self.transposed,
        })?;
        Ok(Some(grad))
    }
}
