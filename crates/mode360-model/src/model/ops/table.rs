//! Bilinear gathering through a precomputed table of taps (the spherical-sweep sampling).
//!
//! Forward: `out[b, n, c] = Σ_{k<4} weight[n][k] · features[b, index[n][k], c]` with the features
//! `(B, H, W, C)` seen as `(B, H·W, C)`. Backward to the features is the transposed table, stored
//! as compressed rows: for every pixel `p`, the list of `(n, weight)` whose taps hit `p`, so that
//! `grad_features[b, p, c] = Σ_{(n, w) ∈ row p} w · grad_out[b, n, c]` is a parallel gather with
//! no write conflicts. When there are many more samples than pixels (a sweep volume sampling one
//! feature image), a scatter-add streaming through the samples with one accumulator per thread
//! is faster and is used instead. The table itself gets no gradient.

use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape, Tensor};
use mode360_core::geometry::BilinearTaps;
use rayon::prelude::*;

use super::composite;
use super::sample_table::{SampleTable, TransposedTable};
#[cfg(feature = "cuda")]
use super::table_cuda;
use super::types::{cpu_slice, dims_of, has_custom_kernels, OpsError};

/// Rank of the features `(B, H, W, C)`.
const FEATURE_RANK: usize = 4;
/// Output samples per rayon task in the forward gather.
const SAMPLES_PER_TASK: usize = 256;
/// Pixels per rayon task in the transposed gather.
const PIXELS_PER_TASK: usize = 256;

/// Bilinear gather: features `(B, H, W, C)` -> `(B, N, C)`,
/// `out[b, n, c] = Σ_k weight[n][k] · features[b, index[n][k], c]`, indices into `H·W`.
/// Gradients flow to `features` (not to the table).
pub fn table_sample(features: &Tensor, table: &SampleTable) -> Result<Tensor> {
    const OP: &str = "table_sample";
    let dims = dims_of(features, OP, "features", FEATURE_RANK)?;
    if dims.contains(&0) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("features {dims:?} must not be empty"),
        }
        .into());
    }
    table.check_pixels(dims[1] * dims[2], OP)?;
    if !has_custom_kernels(features.device()) && !features.device().is_cuda() {
        return composite::table_sample_composite(features, table);
    }
    // the CPU kernel, or on a GPU the CUDA kernels of `table_cuda` (a build without the `cuda`
    // feature has no CUDA device)
    // (B, H, W, C) -> (B, N, C)
    features.contiguous()?.apply_op1(TableSampleOp {
        table: table.clone(),
        batch: dims[0],
        pixels: dims[1] * dims[2],
        image: [dims[1], dims[2]],
        channels: dims[3],
    })
}

/// `features (B, H, W, C) -> (B, N, C)`.
struct TableSampleOp {
    table: SampleTable,
    batch: usize,
    pixels: usize,
    image: [usize; 2],
    channels: usize,
}

impl CustomOp1 for TableSampleOp {
    fn name(&self) -> &'static str {
        "table_sample"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let f = cpu_slice(storage, layout, self.name())?;
        let (n, c) = (self.table.len(), self.channels);
        let mut out = vec![0f32; self.batch * n * c];
        for (b, out_b) in out.chunks_mut(n * c).enumerate() {
            let f_b = &f[b * self.pixels * c..(b + 1) * self.pixels * c];
            out_b
                .par_chunks_mut(SAMPLES_PER_TASK * c)
                .enumerate()
                .for_each(|(task, out_task)| {
                    for (j, o) in out_task.chunks_mut(c).enumerate() {
                        let BilinearTaps {
                            index: i,
                            weight: w,
                        } = self.table.taps(task * SAMPLES_PER_TASK + j);
                        let p = |k: usize| &f_b[i[k] as usize * c..(i[k] as usize + 1) * c];
                        let (p0, p1, p2, p3) = (p(0), p(1), p(2), p(3));
                        let taps = p0.iter().zip(p1).zip(p2).zip(p3);
                        for (o, (((a, b), c), d)) in o.iter_mut().zip(taps) {
                            *o = w[0] * a + w[1] * b + w[2] * c + w[3] * d;
                        }
                    }
                });
        }
        Ok((CpuStorage::F32(out), Shape::from((self.batch, n, c))))
    }

    #[cfg(feature = "cuda")]
    fn cuda_fwd(
        &self,
        storage: &candle_core::CudaStorage,
        layout: &Layout,
    ) -> Result<(candle_core::CudaStorage, Shape)> {
        let (b, n, c) = (self.batch, self.table.len(), self.channels);
        let kernel = table_cuda::TableKernel::Gather;
        let out = table_cuda::run(kernel, &self.table, storage, layout, b, self.pixels, c)?;
        Ok((out, Shape::from((b, n, c))))
    }

    fn bwd(&self, _features: &Tensor, _out: &Tensor, grad_out: &Tensor) -> Result<Option<Tensor>> {
        let grad = grad_out.contiguous()?.apply_op1(TableSampleTransposeOp {
            table: self.table.clone(),
            batch: self.batch,
            pixels: self.pixels,
            image: self.image,
            channels: self.channels,
        })?;
        Ok(Some(grad))
    }
}

/// `out[p] += Σ_{(n, w) ∈ row p} w · g[n]` over the transposed table, one task per pixel block:
/// no write conflicts, but reads of `g` jump around.
fn gather_transposed(t: &TransposedTable, g: &[f32], out: &mut [f32], c: usize) {
    out.par_chunks_mut(PIXELS_PER_TASK * c)
        .enumerate()
        .for_each(|(task, out_task)| {
            for (j, o) in out_task.chunks_mut(c).enumerate() {
                let p = task * PIXELS_PER_TASK + j;
                for e in t.start[p]..t.start[p + 1] {
                    let (s, w) = (t.sample[e] as usize, t.weight[e]);
                    for (o, v) in o.iter_mut().zip(&g[s * c..(s + 1) * c]) {
                        *o += w * v;
                    }
                }
            }
        });
}

/// `out[index[n][k]] += weight[n][k] · g[n]` streaming through `g` in sample order, one
/// private accumulator per thread (summed at the end): for many more samples than pixels.
fn scatter_add(table: &SampleTable, g: &[f32], out: &mut [f32], c: usize, threads: usize) {
    let n = table.len();
    let per_thread = n.div_ceil(threads);
    let partials: Vec<Vec<f32>> = (0..threads)
        .into_par_iter()
        .map(|t| {
            let mut acc = vec![0f32; out.len()];
            for s in t * per_thread..((t + 1) * per_thread).min(n) {
                let src = &g[s * c..(s + 1) * c];
                let taps = table.taps(s);
                for (&p, &w) in taps.index.iter().zip(&taps.weight) {
                    let p = p as usize;
                    for (o, v) in acc[p * c..(p + 1) * c].iter_mut().zip(src) {
                        *o += w * v;
                    }
                }
            }
            acc
        })
        .collect();
    out.par_chunks_mut(PIXELS_PER_TASK * c)
        .enumerate()
        .for_each(|(task, chunk)| {
            let start = task * PIXELS_PER_TASK * c;
            let len = chunk.len();
            for part in &partials {
                for (o, v) in chunk.iter_mut().zip(&part[start..start + len]) {
                    *o += v;
                }
            }
        });
}

/// `out[p] += Σ_{(n, w) ∈ row p} w · g[n]` for one batch item: the adjoint of the table's
/// gather, `g` `(N, C)` into `out` `(pixels, C)`, by scatter or transposed gather, whichever
/// is faster for the table's shape.
pub(super) fn adjoint_into(
    table: &SampleTable,
    g: &[f32],
    out: &mut [f32],
    pixels: usize,
    c: usize,
) {
    let threads = rayon::current_num_threads().max(1);
    if table.len() >= pixels * threads {
        scatter_add(table, g, out, c, threads);
    } else {
        gather_transposed(&table.transposed(pixels), g, out, c);
    }
}

/// The adjoint of [`TableSampleOp`]: `(B, N, C) -> (B, H, W, C)`.
struct TableSampleTransposeOp {
    table: SampleTable,
    batch: usize,
    pixels: usize,
    image: [usize; 2],
    channels: usize,
}

impl CustomOp1 for TableSampleTransposeOp {
    fn name(&self) -> &'static str {
        "table_sample_transpose"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = cpu_slice(storage, layout, self.name())?;
        let (n, c) = (self.table.len(), self.channels);
        let mut out = vec![0f32; self.batch * self.pixels * c];
        for (b, out_b) in out.chunks_mut(self.pixels * c).enumerate() {
            adjoint_into(
                &self.table,
                &g[b * n * c..(b + 1) * n * c],
                out_b,
                self.pixels,
                c,
            );
        }
        let [h, w] = self.image;
        Ok((CpuStorage::F32(out), Shape::from((self.batch, h, w, c))))
    }

    #[cfg(feature = "cuda")]
    fn cuda_fwd(
        &self,
        storage: &candle_core::CudaStorage,
        layout: &Layout,
    ) -> Result<(candle_core::CudaStorage, Shape)> {
        let ([h, w], b, c) = (self.image, self.batch, self.channels);
        let kernel = table_cuda::TableKernel::Adjoint;
        let out = table_cuda::run(kernel, &self.table, storage, layout, b, self.pixels, c)?;
        Ok((out, Shape::from((b, h, w, c))))
    }

    fn bwd(&self, _g: &Tensor, _out: &Tensor, grad_out: &Tensor) -> Result<Option<Tensor>> {
        Ok(Some(table_sample(grad_out, &self.table)?))
    }
}
