//! The variance over views of a spherical sweep, fused: every camera's features are gathered
//! through its table and reduced per sample in one pass, so no per-camera `(B, N, C)` volume
//! is ever materialised (at 256x128 cells, 96 spheres and 8 channels each would be 100 MB).
//!
//! With `v_c[b, n] = Σ_k weight_c[n][k] · f_c[b, index_c[n][k]]` (camera `c` of `M`):
//!
//! ```text
//! var[b, n] = (1/M) Σ_c v_c²  -  ((1/M) Σ_c v_c)²
//! ∂L/∂v_c   = (2/M) · g[b, n] · (v_c - mean)        then through table c's adjoint to f_c
//! ```
//!
//! With cameras that do not see every sample ([`sweep_variance_visible`]), a camera's table has
//! all-zero weights where it sees nothing (so `v_c = 0` there and no gradient reaches it), and
//! `1/M` becomes the per-sample `s[n] = 1 / (views seeing n)`, or 0 where fewer than two views
//! see the sample: the variance is then 0 (no matching evidence) instead of mixing in views
//! that show something else.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Result, Shape, Tensor};
use mode360_core::geometry::BilinearTaps;
use rayon::prelude::*;
use std::sync::Arc;

use super::composite;
use super::sample_table::SampleTable;
use super::table::{adjoint_into, table_sample};
use super::types::{cpu_slice, dims_of, has_custom_kernels, OpsError};

mod appended;
pub use appended::{sweep_variance_appended, sweep_variance_appended_window};

/// Rank of the stacked features `(M B, H, W, C)`.
const FEATURE_RANK: usize = 4;
/// Output samples per rayon task.
const SAMPLES_PER_TASK: usize = 256;

/// Shapes shared by the forward and gradient kernels.
#[derive(Clone, Debug)]
struct SweepShape {
    tables: Vec<SampleTable>,
    batch: usize,
    pixels: usize,
    image: [usize; 2],
    channels: usize,
    /// Per sample `1 / views` (0 below two views); `None`: every camera sees every sample.
    view_scale: Option<Arc<[f32]>>,
    /// The first of the tables' samples computed: the output's sample `j` is the tables'
    /// sample `first + j` (0 but for [`sweep_variance_appended_window`]).
    first: usize,
    /// Samples computed: the tables' length, or the window's.
    samples: usize,
}

impl SweepShape {
    /// The factor that turns sums over cameras into means at sample `n`.
    #[inline]
    fn scale(&self, n: usize) -> f32 {
        match &self.view_scale {
            Some(s) => s[n],
            None => 1.0 / self.cameras() as f32,
        }
    }

    fn cameras(&self) -> usize {
        self.tables.len()
    }

    fn samples(&self) -> usize {
        self.samples
    }

    /// Whether the output holds every sample of the tables (the gradients need it).
    fn is_whole(&self) -> bool {
        self.first == 0 && self.samples == self.tables.first().map_or(0, SampleTable::len)
    }

    /// `v_c[b, n, :]` into `out`.
    #[inline]
    fn gather(&self, f: &[f32], cam: usize, b: usize, n: usize, out: &mut [f32]) {
        let c = self.channels;
        let table = &self.tables[cam];
        let base = (cam * self.batch + b) * self.pixels * c;
        let BilinearTaps { index, weight } = table.taps(self.first + n);
        let p = |k: usize| &f[base + index[k] as usize * c..base + (index[k] as usize + 1) * c];
        let (p0, p1, p2, p3) = (p(0), p(1), p(2), p(3));
        for (j, o) in out.iter_mut().enumerate() {
            *o = weight[0] * p0[j] + weight[1] * p1[j] + weight[2] * p2[j] + weight[3] * p3[j];
        }
    }

    /// Per sample of batch item `b`: the mean over cameras into `mean_b` `(N, C)` and the
    /// variance into `var_b`, each when given (the forward pass keeps only the variance, the
    /// gradient only the mean). Common channel counts run a kernel with the channel loop
    /// unrolled at compile time.
    fn moments(&self, f: &[f32], b: usize, mean_b: Option<&mut [f32]>, var_b: Option<&mut [f32]>) {
        match self.channels {
            4 => self.moments_n::<4>(f, b, mean_b, var_b),
            8 => self.moments_n::<8>(f, b, mean_b, var_b),
            16 => self.moments_n::<16>(f, b, mean_b, var_b),
            _ => match mean_b {
                Some(mean_b) => self.moments_any(f, b, mean_b, var_b),
                None => {
                    let mut mean = vec![0f32; self.samples() * self.channels];
                    self.moments_any(f, b, &mut mean, var_b)
                }
            },
        }
    }

    /// Every camera's `(H W, C)` feature plane of batch item `b`.
    fn planes<'f, const C: usize>(&self, f: &'f [f32], b: usize) -> Vec<&'f [f32]> {
        (0..self.cameras())
            .map(|cam| {
                let base = (cam * self.batch + b) * self.pixels * C;
                &f[base..base + self.pixels * C]
            })
            .collect()
    }

    /// [`Self::moments_task`], in AVX2 and FMA where the CPU has them.
    #[inline(always)]
    fn run_task<const C: usize>(
        &self,
        planes: &[&[f32]],
        tables: &[&SampleTable],
        t: usize,
        mean_t: Option<&mut [f32]>,
        var_t: Option<&mut [f32]>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if crate::cpu::avx2_fma() {
            // SAFETY: the CPU runs AVX2 and FMA (`crate::cpu::avx2_fma`).
            return unsafe { self.moments_task_avx2::<C>(planes, tables, t, mean_t, var_t) };
        }
        self.moments_task::<C>(planes, tables, t, mean_t, var_t)
    }

    /// [`Self::moments`] for `C` channels known at compile time.
    fn moments_n<const C: usize>(
        &self,
        f: &[f32],
        b: usize,
        mean_b: Option<&mut [f32]>,
        var_b: Option<&mut [f32]>,
    ) {
        let planes = self.planes::<C>(f, b);
        let tables: Vec<&SampleTable> = self.tables.iter().collect();
        let run = |t: usize, mean_t: Option<&mut [f32]>, var_t: Option<&mut [f32]>| {
            self.run_task::<C>(&planes, &tables, t, mean_t, var_t)
        };
        let task = SAMPLES_PER_TASK * C;
        match (mean_b, var_b) {
            (Some(mean_b), Some(var_b)) => mean_b
                .par_chunks_mut(task)
                .zip(var_b.par_chunks_mut(task))
                .enumerate()
                .for_each(|(t, (m, v))| run(t, Some(m), Some(v))),
            (Some(mean_b), None) => mean_b
                .par_chunks_mut(task)
                .enumerate()
                .for_each(|(t, m)| run(t, Some(m), None)),
            (None, Some(var_b)) => var_b
                .par_chunks_mut(task)
                .enumerate()
                .for_each(|(t, v)| run(t, None, Some(v))),
            (None, None) => {}
        }
    }

    /// [`Self::moments_task`] compiled for AVX2 and FMA (8-wide vectors).
    ///
    /// # Safety
    /// The CPU must run AVX2 and FMA ([`crate::cpu::avx2_fma`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn moments_task_avx2<const C: usize>(
        &self,
        planes: &[&[f32]],
        tables: &[&SampleTable],
        t: usize,
        mean_t: Option<&mut [f32]>,
        var_t: Option<&mut [f32]>,
    ) {
        self.moments_task::<C>(planes, tables, t, mean_t, var_t)
    }

    /// Samples `t·SAMPLES_PER_TASK ..` of one rayon task (camera planes `(H W, C)` of one batch
    /// item, each camera's table) into the task's chunks of the outputs.
    #[inline(always)]
    fn moments_task<const C: usize>(
        &self,
        planes: &[&[f32]],
        tables: &[&SampleTable],
        t: usize,
        mut mean_t: Option<&mut [f32]>,
        mut var_t: Option<&mut [f32]>,
    ) {
        const TAPS: usize = SampleTable::TAPS;
        let len = mean_t
            .as_deref()
            .or(var_t.as_deref())
            .map_or(0, <[f32]>::len);
        for j in 0..len / C {
            let n = self.first + t * SAMPLES_PER_TASK + j;
            let (mut m, mut sq) = ([0f32; C], [0f32; C]);
            for (plane, table) in planes.iter().zip(tables) {
                let BilinearTaps {
                    index: i,
                    weight: w,
                } = table.taps(n);
                let mut v = [0f32; C];
                for k in 0..TAPS {
                    let o = i[k] as usize * C;
                    let p: &[f32; C] = plane[o..o + C].try_into().unwrap_or(&[0.0; C]);
                    for c in 0..C {
                        v[c] += w[k] * p[c];
                    }
                }
                for c in 0..C {
                    m[c] += v[c];
                    sq[c] += v[c] * v[c];
                }
            }
            let inv_m = self.scale(n);
            for c in 0..C {
                m[c] *= inv_m;
                sq[c] = sq[c] * inv_m - m[c] * m[c];
            }
            if let Some(mo) = mean_t.as_deref_mut() {
                mo[j * C..(j + 1) * C].copy_from_slice(&m);
            }
            if let Some(vo) = var_t.as_deref_mut() {
                vo[j * C..(j + 1) * C].copy_from_slice(&sq);
            }
        }
    }

    /// [`Self::moments`] for any channel count.
    fn moments_any(&self, f: &[f32], b: usize, mean_b: &mut [f32], var_b: Option<&mut [f32]>) {
        let c = self.channels;
        let task = SAMPLES_PER_TASK * c;
        let fill = |t: usize, mean_t: &mut [f32], var_t: Option<&mut [f32]>| {
            let mut v = vec![0f32; c];
            let mut sq = vec![0f32; c];
            let mut var_t = var_t;
            for (j, m) in mean_t.chunks_mut(c).enumerate() {
                let n = t * SAMPLES_PER_TASK + j;
                let scale_n = self.first + n;
                m.fill(0.0);
                sq.fill(0.0);
                for cam in 0..self.cameras() {
                    self.gather(f, cam, b, n, &mut v);
                    for ((m, s), x) in m.iter_mut().zip(sq.iter_mut()).zip(&v) {
                        *m += x;
                        *s += x * x;
                    }
                }
                let inv_m = self.scale(scale_n);
                for x in m.iter_mut() {
                    *x *= inv_m;
                }
                if let Some(var) = var_t.as_deref_mut() {
                    for ((o, s), m) in var[j * c..(j + 1) * c].iter_mut().zip(&sq).zip(m.iter()) {
                        *o = s * inv_m - m * m;
                    }
                }
            }
        };
        match var_b {
            Some(var_b) => mean_b
                .par_chunks_mut(task)
                .zip(var_b.par_chunks_mut(task))
                .enumerate()
                .for_each(|(t, (mean_t, var_t))| fill(t, mean_t, Some(var_t))),
            None => mean_b
                .par_chunks_mut(task)
                .enumerate()
                .for_each(|(t, mean_t)| fill(t, mean_t, None)),
        }
    }
}

/// Variance over cameras of the table-sampled features: stacked features `(M B, H, W, C)`
/// (camera-major: camera `c`'s batch at rows `c B .. (c + 1) B`) and one table of `N` samples
/// per camera -> `(B, N, C)`. Gradients flow to the features.
pub fn sweep_variance(features: &Tensor, tables: &[SampleTable]) -> Result<Tensor> {
    sweep_variance_impl(features, tables, None)
}

/// [`sweep_variance`] over the cameras that see each sample: `view_scale[n]` is
/// `1 / (cameras seeing sample n)`, or 0 where fewer than two do (see [`view_scale`]); the
/// tables have zero weights where their camera sees nothing.
pub fn sweep_variance_visible(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: &Arc<[f32]>,
) -> Result<Tensor> {
    sweep_variance_impl(features, tables, Some(view_scale))
}

/// Fewest views whose agreement is evidence.
pub const MIN_VIEWS: usize = 2;

/// Per sample of `tables`: `1 / views` where `views >= MIN_VIEWS` cameras see it (the sum of a
/// table's weights is 1 where its camera sees the sample, 0 where it does not), else 0.
pub fn view_scale(tables: &[SampleTable]) -> Arc<[f32]> {
    let samples = tables.first().map_or(0, SampleTable::len);
    (0..samples)
        .into_par_iter()
        .with_min_len(SAMPLES_PER_TASK)
        .map(|n| {
            let views: f32 = tables
                .iter()
                .map(|t| t.taps(n).weight.iter().sum::<f32>())
                .sum();
            if views + 0.5 >= MIN_VIEWS as f32 {
                1.0 / views
            } else {
                0.0
            }
        })
        .collect::<Vec<f32>>()
        .into()
}

fn sweep_variance_impl(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&Arc<[f32]>>,
) -> Result<Tensor> {
    match sweep_shape(features, tables, view_scale)? {
        Some(shape) => features.contiguous()?.apply_op1(SweepVarianceOp(shape)),
        None => sweep_variance_fallback(features, tables, view_scale),
    }
}

/// The device-generic paths: a GPU's (the composite around the table gather's CUDA kernel) or
/// the composite of plain tensor ops.
fn sweep_variance_fallback(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&Arc<[f32]>>,
) -> Result<Tensor> {
    let view_scale = view_scale.map(|s| &s[..]);
    if features.device().is_cuda() {
        return composite::sweep_variance_with(features, tables, view_scale, table_sample);
    }
    composite::sweep_variance_composite(features, tables, view_scale)
}

/// The kernels' shapes after checking the arguments; `None` where the device-generic path
/// runs instead (a GPU, or composites forced on the CPU).
fn sweep_shape(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&Arc<[f32]>>,
) -> Result<Option<SweepShape>> {
    const OP: &str = "sweep_variance";
    let dims = dims_of(features, OP, "features", FEATURE_RANK)?;
    let cameras = tables.len();
    let samples = tables.first().map_or(0, SampleTable::len);
    if cameras == 0 || dims.contains(&0) || !dims[0].is_multiple_of(cameras) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("features {dims:?} for {cameras} cameras' tables"),
        }
        .into());
    }
    if let Some(t) = tables.iter().find(|t| t.len() != samples) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("tables of {} and {samples} samples", t.len()),
        }
        .into());
    }
    if let Some(v) = view_scale.filter(|v| v.len() != samples) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("{} view scales for {samples} samples", v.len()),
        }
        .into());
    }
    let pixels = dims[1] * dims[2];
    for t in tables {
        t.check_pixels(pixels, OP)?;
    }
    let batch = dims[0] / cameras;
    if features.device().is_cuda() || !has_custom_kernels(features.device()) {
        return Ok(None);
    }
    Ok(Some(SweepShape {
        tables: tables.to_vec(),
        batch,
        pixels,
        image: [dims[1], dims[2]],
        channels: dims[3],
        view_scale: view_scale.cloned(),
        first: 0,
        samples,
    }))
}

struct SweepVarianceOp(SweepShape);

impl CustomOp1 for SweepVarianceOp {
    fn name(&self) -> &'static str {
        "sweep_variance"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let f = cpu_slice(storage, layout, self.name())?;
        let sh = &self.0;
        let (n, c) = (sh.samples(), sh.channels);
        let mut var = vec![0f32; sh.batch * n * c];
        for (b, var_b) in var.chunks_mut(n * c).enumerate() {
            sh.moments(f, b, None, Some(var_b));
        }
        Ok((CpuStorage::F32(var), Shape::from((sh.batch, n, c))))
    }

    fn bwd(&self, features: &Tensor, _out: &Tensor, grad_out: &Tensor) -> Result<Option<Tensor>> {
        let grad = features
            .contiguous()?
            .apply_op2(&grad_out.contiguous()?, SweepVarianceGradOp(self.0.clone()))?;
        Ok(Some(grad))
    }
}

/// `(features (M B, H, W, C), grad (B, N, C))` -> gradient of the features.
struct SweepVarianceGradOp(SweepShape);

impl CustomOp2 for SweepVarianceGradOp {
    fn name(&self) -> &'static str {
        "sweep_variance_grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let f = cpu_slice(s1, l1, self.name())?;
        let g = cpu_slice(s2, l2, self.name())?;
        let sh = &self.0;
        let (n, c, m) = (sh.samples(), sh.channels, sh.cameras());
        let mut out = vec![0f32; m * sh.batch * sh.pixels * c];
        let mut mean = vec![0f32; n * c];
        let mut g_cam = vec![0f32; n * c];
        for b in 0..sh.batch {
            sh.moments(f, b, Some(&mut mean), None);
            let g_b = &g[b * n * c..(b + 1) * n * c];
            for cam in 0..m {
                g_cam
                    .par_chunks_mut(SAMPLES_PER_TASK * c)
                    .enumerate()
                    .for_each(|(t, gc)| {
                        let mut v = vec![0f32; c];
                        for (j, o) in gc.chunks_mut(c).enumerate() {
                            let s = t * SAMPLES_PER_TASK + j;
                            sh.gather(f, cam, b, s, &mut v);
                            let (gs, ms) = (&g_b[s * c..(s + 1) * c], &mean[s * c..(s + 1) * c]);
                            let scale = 2.0 * sh.scale(s);
                            for (((o, x), gv), mv) in o.iter_mut().zip(&v).zip(gs).zip(ms) {
                                *o = scale * gv * (x - mv);
                            }
                        }
                    });
                let base = (cam * sh.batch + b) * sh.pixels * c;
                adjoint_into(
                    &sh.tables[cam],
                    &g_cam,
                    &mut out[base..base + sh.pixels * c],
                    sh.pixels,
                    c,
                );
            }
        }
        let [h, w] = sh.image;
        Ok((CpuStorage::F32(out), Shape::from((m * sh.batch, h, w, c))))
    }

    fn bwd(
        &self,
        _f: &Tensor,
        _g: &Tensor,
        _out: &Tensor,
        _grad_out: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        candle_core::bail!("sweep_variance: second derivatives are not implemented")
    }
}
