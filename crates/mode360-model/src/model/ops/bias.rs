//! `add_bias`: a per-channel bias added to a channels-last tensor, `y (…, C) + b (C)`, what
//! `y.broadcast_add(b)` computes.
//!
//! ```text
//! out[n, c] = y[n, c] + b[c]
//! ∂L/∂y = g,   ∂L/∂b[c] = Σ_n g[n, c]
//! ```
//!
//! candle's gradient of the broadcast is a `sum_keepdim` over every leading axis, which its CPU
//! backend runs value by value through a strided index: with a bias on every 3-D convolution
//! of the aggregation (3 million values each at 256) and on the 2-D feature layers, those sums
//! took an eighth of a one-thread training step (perf, after [`super::soft_argmin_index`]).
//! Here the bias gradient is a column sum over contiguous rows in rayon tasks.

use candle_core::{CpuStorage, CustomOp2, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

use super::types::{add_into, cpu_slice, has_custom_kernels, OpsError};

const OP: &str = "add_bias";

/// Rows `(C)` per rayon task in the bias gradient's column sums.
const ROWS_PER_TASK: usize = 1 << 12;

/// `y (…, C) + b (C)`; gradients flow to both.
pub fn add_bias(y: &Tensor, b: &Tensor) -> Result<Tensor> {
    let c = y.dims().last().copied();
    if b.rank() != 1 || c != Some(b.dim(0)?) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!(
                "a bias {:?} for a tensor {:?}: expected one value per channel of its last axis",
                b.dims(),
                y.dims()
            ),
        }
        .into());
    }
    if !has_custom_kernels(y.device()) || y.dtype() != DType::F32 || b.dtype() != DType::F32 {
        return y.broadcast_add(b);
    }
    y.contiguous()?.apply_op2(&b.contiguous()?, AddBiasOp)
}

struct AddBiasOp;

impl CustomOp2 for AddBiasOp {
    fn name(&self) -> &'static str {
        OP
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (y, b) = (cpu_slice(s1, l1, OP)?, cpu_slice(s2, l2, OP)?);
        let c = b.len().max(1);
        let mut out = y.to_vec();
        out.par_chunks_mut(ROWS_PER_TASK * c).for_each(|chunk| {
            for row in chunk.chunks_exact_mut(c) {
                row.iter_mut().zip(b).for_each(|(v, &bias)| *v += bias);
            }
        });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        y: &Tensor,
        b: &Tensor,
        _out: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let db = if b.track_op() {
            let c = b.dim(0)?;
            let g = grad.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
            let sums = g
                .par_chunks(ROWS_PER_TASK * c.max(1))
                .fold(
                    || vec![0f32; c],
                    |mut acc, chunk| {
                        for row in chunk.chunks_exact(c.max(1)) {
                            acc.iter_mut().zip(row).for_each(|(a, &v)| *a += v);
                        }
                        acc
                    },
                )
                .reduce(|| vec![0f32; c], add_into);
            Some(Tensor::from_vec(sums, c, b.device())?)
        } else {
            None
        };
        let dy = y.track_op().then(|| grad.clone());
        Ok((dy, db))
    }
}
