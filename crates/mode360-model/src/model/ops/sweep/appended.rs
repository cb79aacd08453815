//! The sweep's variance with one more channel appended to every sample, written a task at a
//! time so that the volume without the channel never sits beside the result, and its window
//! over a range of samples for inference in slabs.

use candle_core::{CpuStorage, CustomOp2, Layout, Result, Shape, Tensor};
use rayon::prelude::*;
use std::sync::Arc;

use super::super::sample_table::SampleTable;
use super::super::types::{cpu_slice, OpsError};
use super::{sweep_shape, sweep_variance_impl, SweepShape, SweepVarianceGradOp, SAMPLES_PER_TASK};

/// [`sweep_variance`] (with `view_scale`: [`sweep_variance_visible`]) and one more channel
/// appended to every sample, `extra (B, N, 1)` -> `(B, N, C + 1)`: what
/// `append_channels(&sweep_variance(..), extra)` computes, without the `(B, N, C)` volume
/// beside the result (96 MiB of the cost volume at 256). Gradients flow to both.
pub fn sweep_variance_appended(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&Arc<[f32]>>,
    extra: &Tensor,
) -> Result<Tensor> {
    let shape = sweep_shape(features, tables, view_scale)?;
    let n = tables.first().map_or(0, SampleTable::len);
    let fused =
        shape.filter(|sh| matches!(sh.channels, 4 | 8 | 16) && extra.dims() == [sh.batch, n, 1]);
    match fused {
        Some(shape) => features
            .contiguous()?
            .apply_op2(&extra.contiguous()?, SweepVarianceAppendOp(shape)),
        None => super::super::append_channels(
            &sweep_variance_impl(features, tables, view_scale)?,
            extra,
        ),
    }
}

/// [`sweep_variance_appended`] over the tables' samples `window` only, `extra (B, len, 1)` ->
/// `(B, len, C + 1)`: sample `j` of the result is sample `window.start + j` of the whole op's,
/// bit for bit. For inference in slabs (the cost volume a few spheres at a time, so that the
/// whole volume is never held): it has no gradient, and it needs the fused CPU kernel
/// (4, 8 or 16 channels): elsewhere it is an error, and [`sweep_variance_appended`] serves.
pub fn sweep_variance_appended_window(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&Arc<[f32]>>,
    extra: &Tensor,
    window: std::ops::Range<usize>,
) -> Result<Tensor> {
    const OP: &str = "sweep_variance_appended_window";
    let n = tables.first().map_or(0, SampleTable::len);
    let shape = sweep_shape(features, tables, view_scale)?
        .filter(|sh| matches!(sh.channels, 4 | 8 | 16))
        .ok_or_else(|| OpsError::Shape {
            op: OP,
            what: "needs the fused CPU kernel (4, 8 or 16 channels on the CPU)".to_string(),
        })?;
    if window.start > window.end || window.end > n || extra.dims() != [shape.batch, window.len(), 1]
    {
        return Err(OpsError::Shape {
            op: OP,
            what: format!(
                "window {window:?} of {n} samples with extra {:?}",
                extra.dims()
            ),
        }
        .into());
    }
    let shape = SweepShape {
        first: window.start,
        samples: window.len(),
        ..shape
    };
    features
        .contiguous()?
        .apply_op2(&extra.contiguous()?, SweepVarianceAppendOp(shape))
}

/// `(features (M B, H, W, C), extra (B, N, 1))` -> `(B, N, C + 1)`: the variance and `extra`,
/// written side by side a task at a time.
struct SweepVarianceAppendOp(SweepShape);

impl SweepShape {
    /// Batch item `b`'s variance `(N, C)` and `extra_b` `(N)` side by side into `out_b`
    /// `(N, C + 1)` (`C` = 4, 8 or 16 channels, checked by the caller).
    fn variance_appended(&self, f: &[f32], b: usize, extra_b: &[f32], out_b: &mut [f32]) {
        match self.channels {
            4 => self.variance_appended_n::<4>(f, b, extra_b, out_b),
            8 => self.variance_appended_n::<8>(f, b, extra_b, out_b),
            _ => self.variance_appended_n::<16>(f, b, extra_b, out_b),
        }
    }

    fn variance_appended_n<const C: usize>(
        &self,
        f: &[f32],
        b: usize,
        extra_b: &[f32],
        out_b: &mut [f32],
    ) {
        let planes = self.planes::<C>(f, b);
        let tables: Vec<&SampleTable> = self.tables.iter().collect();
        out_b
            .par_chunks_mut(SAMPLES_PER_TASK * (C + 1))
            .enumerate()
            .for_each_init(
                || vec![0f32; SAMPLES_PER_TASK * C],
                |var, (t, out_t)| {
                    let var_t = &mut var[..out_t.len() / (C + 1) * C];
                    self.run_task::<C>(&planes, &tables, t, None, Some(&mut *var_t));
                    let first = t * SAMPLES_PER_TASK;
                    let rows = out_t.chunks_exact_mut(C + 1).zip(var_t.chunks_exact(C));
                    for (j, (o, v)) in rows.enumerate() {
                        o[..C].copy_from_slice(v);
                        o[C] = extra_b[first + j];
                    }
                },
            );
    }
}

impl CustomOp2 for SweepVarianceAppendOp {
    fn name(&self) -> &'static str {
        "sweep_variance_appended"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let f = cpu_slice(s1, l1, self.name())?;
        let e = cpu_slice(s2, l2, self.name())?;
        let sh = &self.0;
        let (n, c) = (sh.samples(), sh.channels);
        let mut out = vec![0f32; sh.batch * n * (c + 1)];
        for (b, out_b) in out.chunks_mut(n * (c + 1)).enumerate() {
            sh.variance_appended(f, b, &e[b * n..(b + 1) * n], out_b);
        }
        Ok((CpuStorage::F32(out), Shape::from((sh.batch, n, c + 1))))
    }

    fn bwd(
        &self,
        features: &Tensor,
        _extra: &Tensor,
        _out: &Tensor,
        grad_out: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        if !self.0.is_whole() {
            return Err(OpsError::Shape {
                op: "sweep_variance_appended_window",
                what: "a window of the sweep has no gradient (inference only)".to_string(),
            }
            .into());
        }
        let c = self.0.channels;
        let g_var = grad_out.narrow(2, 0, c)?.contiguous()?;
        let g_features = features
            .contiguous()?
            .apply_op2(&g_var, SweepVarianceGradOp(self.0.clone()))?;
        let g_extra = grad_out.narrow(2, c, 1)?.contiguous()?;
        Ok((Some(g_features), Some(g_extra)))
    }
}
