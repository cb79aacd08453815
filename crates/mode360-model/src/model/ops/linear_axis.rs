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

use super::composite;
use super::types::{
    cpu_slice, dims_of, has_custom_kernels, LinearAxisMap, OpsError, COST_VOLUME_RANK,
};
/// Fewest output elements per rayon task.
const MIN_ELEMENTS_PER_TASK: usize = 4096;

/// Linearly resamples axis `dim` of `x` to `out_len` samples (`align_corners = false`), with
/// gradient. Every other axis is unchanged; the same length returns `x` itself.
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
    let in_len = x.dim(dim)?;
    if in_len == out_len {
        // `src = j`: every weight is on `in[j]`, so the op is the identity (the fine head's
        // cost arrives at the output's rows and columns)
        return Ok(x.clone());
    }
    let map = LinearAxisMap::new(in_len, out_len)?;
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
        if inner == 1 {
            // the last axis: one chunk per line (a chunk per value cost more than its sum)
            out.par_chunks_mut(out_len.max(1))
                .enumerate()
                .with_min_len((MIN_ELEMENTS_PER_TASK / out_len.max(1)).max(1))
                .for_each(|(outer_idx, line)| {
                    let src = &x[outer_idx * in_len..(outer_idx + 1) * in_len];
                    for (j, o) in line.iter_mut().enumerate() {
                        for e in rows.start[j]..rows.start[j + 1] {
                            *o += rows.weight[e] * src[rows.src[e] as usize];
                        }
                    }
                });
        } else {
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
        }
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
