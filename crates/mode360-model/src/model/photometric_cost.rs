//! SSMODE's photometric cost channel ([`SsmodeConfig::photometric_cost`], a departure from the
//! paper): the learning-free sweep's matching evidence appended to the learned cost volume, so
//! that the aggregation starts from evidence that needs no training and learns to regularize
//! it and to distrust a view that disagrees (a soiled or blocked lens).
//!
//! For sphere `d` and cost cell `k`, every camera's grey image `g = 0.299 R + 0.587 G + 0.114 B`
//! is sampled through its sweep table (the same taps as the learned features), then, with
//! [`crate::matching::zncc`] and a `(2 r + 1)^2` window:
//!
//! ```text
//! cost_ab  = (1 - w_mean) (1 - zncc_ab) / 2 + w_mean min(|E[a] - E[b]| / s_mean, 1)
//! cost_ab' = s_ab cost_ab + (1 - s_ab) / 2      s_ab = |dir x b_hat_ab|: no parallax, undecided
//! cost     = mean of the best ceil(ceil(P / 2) S / P) of the S pairs both cameras see (of P)
//! channel  = 1 - 2 cost                          in [-1, 1]: 1 a match, 0 undecided or unseen
//! ```
//!
//! It is a function of the images alone (no gradient), computed per sphere in parallel on the
//! CPU whatever the device, and returned on the images' device as `(B, D, H, W, 1)`.
//!
//! [`SsmodeConfig::photometric_cost`]: super::config::SsmodeConfig::photometric_cost

use candle_core::{Result, Tensor};
use rayon::prelude::*;

use super::sweep_sampling::SweepSampling;
use crate::matching::luma;
use crate::matching::zncc::{sphere_cost, PairCostParams, ViewStats, UNDECIDED_COST};
use crate::model::ops::{OpsError, SampleTable};

/// ZNCC window radius in cost cells (a 5x5 window).
pub const WINDOW_RADIUS_CELLS: usize = 2;
/// Added to each window variance (intensity in [0, 1]) so flat windows score ZNCC 0.
pub const VARIANCE_FLOOR: f32 = 1e-6;
/// Weight of the window-mean difference term in the pair cost.
pub const MEAN_WEIGHT: f32 = 0.3;
/// Mean intensity difference at which the mean term saturates.
pub const MEAN_SCALE: f32 = 0.03;
/// Share of the camera pairs (the best ones) averaged per cell.
pub const BEST_PAIR_FRACTION: f32 = 0.5;
/// Channels of an RGB image tensor.
const IMAGE_CHANNELS: usize = 3;
/// A sample whose taps weigh less than this is one the camera does not see.
const SEEN_WEIGHT: f32 = 0.5;

/// The pair-cost parameters for `cameras` cameras.
fn pair_params(cameras: usize) -> PairCostParams {
    let pairs = cameras * cameras.saturating_sub(1) / 2;
    PairCostParams {
        window_radius_px: WINDOW_RADIUS_CELLS,
        variance_floor: VARIANCE_FLOOR,
        mean_weight: MEAN_WEIGHT,
        mean_scale: MEAN_SCALE,
        best_pairs: ((pairs as f32 * BEST_PAIR_FRACTION).ceil() as usize).max(1),
    }
}

/// Grey images of batch item `b`, one per camera, row-major at the images' resolution.
fn grey_images(images: &[Tensor], b: usize) -> Result<Vec<Vec<f32>>> {
    images
        .iter()
        .map(|img| {
            let rgb: Vec<f32> = img.narrow(0, b, 1)?.flatten_all()?.to_vec1()?;
            Ok(rgb
                .chunks_exact(IMAGE_CHANNELS)
                .map(|p| luma([p[0], p[1], p[2]]))
                .collect())
        })
        .collect()
}

/// Samples `grey` through `table` for the cells `first .. first + out.len()`; returns the
/// per-cell tap weight (1 where the camera sees the sample, 0 where it does not). The sweep's
/// tables of ERP samples are read directly ([`mode360_core::geometry::ErpGrid::interpolate`]:
/// this loop was half the channel's time when it expanded every sample's taps).
#[inline(always)]
fn warp(grey: &[f32], table: &SampleTable, first: usize, out: &mut [f32], seen: &mut [f32]) {
    if let Some((grid, samples)) = table.erp_samples() {
        let samples = &samples[first..first + out.len()];
        for ((o, s), &sample) in out.iter_mut().zip(seen.iter_mut()).zip(samples) {
            *o = grid.interpolate(sample, grey);
            *s = if sample.is_seen() { 1.0 } else { 0.0 };
        }
        return;
    }
    for (k, (o, s)) in out.iter_mut().zip(seen.iter_mut()).enumerate() {
        let taps = table.taps(first + k);
        let mut value = 0.0;
        let mut total = 0.0;
        for (&i, &w) in taps.index.iter().zip(&taps.weight) {
            value += w * grey[i as usize];
            total += w;
        }
        *o = value;
        *s = total;
    }
}

/// A camera's warped view statistics and, on rigs where not every camera sees every sample,
/// where it sees the sphere.
type WarpedView = (ViewStats, Option<Vec<f32>>);

/// What one sphere's channel is computed from (one batch item).
struct SphereInputs<'a> {
    grey: &'a [Vec<f32>],
    tables: &'a [&'a SampleTable],
    /// Per camera, its statistics when it is the output frame (the same on every sphere).
    fixed: &'a [Option<WarpedView>],
    pair_weights: &'a [Vec<f32>],
    track_seen: bool,
    params: PairCostParams,
    w: usize,
    h: usize,
}

impl SphereInputs<'_> {
    /// [`Self::channel`] compiled for AVX2 and FMA (8-wide vectors).
    ///
    /// # Safety
    /// The CPU must run AVX2 and FMA ([`crate::cpu::avx2_fma`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn channel_avx2(&self, d: usize) -> Vec<f32> {
        self.channel(d)
    }

    /// Sphere `d`'s channel `(H W)`, in `[-1, 1]`.
    ///
    /// Loops rather than iterator closures: a closure's body that is not inlined is compiled
    /// without the caller's AVX2 ([`Self::channel_avx2`]), and the warp and window statistics
    /// of every camera were half the channel's time that way.
    #[inline(always)]
    fn channel(&self, d: usize) -> Vec<f32> {
        let cells = self.w * self.h;
        let mut tmp = vec![0.0f32; cells];
        let mut owned: Vec<Option<WarpedView>> = Vec::with_capacity(self.grey.len());
        for ((grey, table), fixed) in self.grey.iter().zip(self.tables).zip(self.fixed) {
            owned.push(if fixed.is_none() {
                Some(self.warped_view(grey, table, d, &mut tmp))
            } else {
                None
            });
        }
        let mut views: Vec<&ViewStats> = Vec::with_capacity(owned.len());
        let mut seen: Vec<Option<&[f32]>> = Vec::with_capacity(owned.len());
        for (own, fixed) in owned.iter().zip(self.fixed) {
            if let Some((stats, mask)) = own.as_ref().or(fixed.as_ref()) {
                views.push(stats);
                seen.push(mask.as_deref());
            }
        }
        let mut channel = sphere_cost(
            &views,
            &seen,
            self.pair_weights,
            self.w,
            self.h,
            &self.params,
        );
        for c in channel.iter_mut() {
            *c = (UNDECIDED_COST - *c) / UNDECIDED_COST;
        }
        channel
    }

    /// Camera `grey`'s view of sphere `d` through `table`: its window statistics and, where
    /// tracked, where it sees the sphere. `tmp` is scratch of a sphere's size.
    #[inline(always)]
    fn warped_view(
        &self,
        grey: &[f32],
        table: &SampleTable,
        d: usize,
        tmp: &mut [f32],
    ) -> WarpedView {
        let cells = self.w * self.h;
        let mut warped = vec![0.0f32; cells];
        let mut weight = vec![0.0f32; cells];
        warp(grey, table, d * cells, &mut warped, &mut weight);
        let stats = ViewStats::new(warped, self.w, self.h, self.params.window_radius_px, tmp);
        (stats, self.track_seen.then(|| seen_mask(&weight)))
    }
}

/// 1 where a camera's tap weight says it sees the sample, else 0.
#[inline(always)]
fn seen_mask(weight: &[f32]) -> Vec<f32> {
    let mut mask = vec![0.0f32; weight.len()];
    for (m, &x) in mask.iter_mut().zip(weight) {
        *m = if x >= SEEN_WEIGHT { 1.0 } else { 0.0 };
    }
    mask
}

/// The photometric cost channel `(B, D, H, W, 1)` of `images` (one `(B, H, W, 3)` tensor in
/// `[0, 1]` per camera, at the cost volume's resolution) for the rig of `sampling`.
pub fn photometric_cost(images: &[Tensor], sampling: &SweepSampling) -> Result<Tensor> {
    const OP: &str = "photometric_cost";
    let shape_err =
        |what: String| -> candle_core::Error { OpsError::Shape { op: OP, what }.into() };
    let cameras = sampling.camera_count();
    if images.len() != cameras {
        return Err(shape_err(format!(
            "{} images for a sweep of {cameras} cameras",
            images.len()
        )));
    }
    let pair_weights = sampling.pair_weights().ok_or_else(|| {
        shape_err("the sweep sampling was built without pair weights".to_string())
    })?;
    let grid = sampling.geometry().output();
    let (w, h) = (grid.width(), grid.height());
    let cells = grid.len();
    let spheres = sampling.geometry().hypotheses().count();
    let (batch, ih, iw, ic) = images[0].dims4()?;
    if (ih, iw, ic) != (h, w, IMAGE_CHANNELS) {
        return Err(shape_err(format!(
            "images are ({batch}, {ih}, {iw}, {ic}), the cost volume needs ({batch}, {h}, {w}, 3)"
        )));
    }
    let tables = (0..cameras)
        .map(|cam| {
            sampling
                .sweep_table(cam)
                .ok_or_else(|| shape_err(format!("no sweep table for camera {cam}")))
        })
        .collect::<Result<Vec<_>>>()?;
    let track_seen = sampling.view_scale().is_some();
    let params = pair_params(cameras);
    let mut out = Vec::with_capacity(batch * spheres * cells);
    for b in 0..batch {
        let grey = grey_images(images, b)?;
        // A camera that is the output frame looks the same on every sphere: its statistics
        // are computed once.
        let mut tmp = vec![0.0f32; cells];
        let fixed: Vec<Option<WarpedView>> = grey
            .iter()
            .zip(&tables)
            .enumerate()
            .map(|(cam, (g, table))| {
                sampling.geometry().is_output_camera(cam).then(|| {
                    let (mut warped, mut weight) = (vec![0.0f32; cells], vec![0.0f32; cells]);
                    warp(g, table, 0, &mut warped, &mut weight);
                    let stats = ViewStats::new(warped, w, h, params.window_radius_px, &mut tmp);
                    (stats, track_seen.then(|| seen_mask(&weight)))
                })
            })
            .collect();
        let sphere = SphereInputs {
            grey: &grey,
            tables: &tables,
            fixed: &fixed,
            pair_weights,
            track_seen,
            params,
            w,
            h,
        };
        let avx2_fma = crate::cpu::avx2_fma();
        let slices: Vec<Vec<f32>> = (0..spheres)
            .into_par_iter()
            .map(|d| {
                #[cfg(target_arch = "x86_64")]
                if avx2_fma {
                    // SAFETY: the CPU runs AVX2 and FMA (`crate::cpu::avx2_fma`).
                    return unsafe { sphere.channel_avx2(d) };
                }
                let _ = avx2_fma;
                sphere.channel(d)
            })
            .collect();
        for s in slices {
            out.extend(s);
        }
    }
    Tensor::from_vec(out, (batch, spheres, h, w, 1), images[0].device())
}
