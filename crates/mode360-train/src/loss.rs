//! The training loss: multi-stage SmoothL1 on the inverse-depth index, masked to valid
//! ground truth.
//!
//! Range spans 0.5 m to 1000 m, three and a half orders of magnitude; an L1 on metres would be
//! dominated by the sky and far facades. SSMODE's hypotheses are uniform in inverse depth, so
//! the natural regression target is the (continuous) hypothesis index
//!
//! `idx(rho) = (D - 1) (1/rho - 1/max_depth) / (1/min_depth - 1/max_depth)`,
//!
//! i.e. the network's normalized inverse depth `n = idx / (D - 1)` in `[0, 1]`, scaled to
//! hypothesis units so SmoothL1's `beta = 1` switches from L2 to L1 at one hypothesis step,
//! exactly as PSMNet's disparity loss does at one pixel. With stage predictions `n_s`:
//!
//! `L = sum_s w_s * mean_{valid} SmoothL1((D - 1) n_s - idx)`,
//! `SmoothL1(x) = 0.5 x^2 / beta if |x| < beta else |x| - 0.5 beta`.
//!
//! Valid pixels have a finite ground truth in `(0, max_depth]` (sky counts, at max depth).
//!
//! Obstacle weighting ([`LossWeighting`]): a pixel whose true range is at most
//! `near_range_m` weighs `near_weight`, and a prediction farther than the truth (a smaller
//! normalized inverse depth: the obstacle melts into what stands behind it) weighs
//! `too_far_weight` more; both 1 (the default) give the plain loss:
//!
//! `L = sum_s w_s * sum_{valid} a_p b_p SmoothL1(...) / |valid|`,
//! `a_p = (near_weight if g_p <= near_range_m, sky_weight if g_p = max_depth_m, else 1) * o_p`,
//! `b_p = too_far_weight if n_s < n and g_p <= too_far_range_m,`
//! `      too_near_weight if n_s > n and max(near_range_m, too_near_min_range_m) < g_p < max_depth_m`
//! `      and o_p = 1`
//! `      and no g_q < g_p / 1.25 within too_near_edge_px of p (Chebyshev), else 1`.
//!
//! The too-near weight is for the surfaces beyond the near range that are not obstacles (the
//! street at 5 to 80 m): heavy near and obstacle weights teach the network to read them too
//! near (phantom obstacles, obstacles fattened into their background), while within the near
//! range, and on an obstacle, a too-near reading is the safe error. With `too_near_edge_px`
//! the far side of a depth edge is left out too, so that the weight punishes phantom
//! surfaces, not a near object read a little wider than it is. With `too_near_min_range_m`
//! the zone starts farther out than the near range, so that the weight leaves the mid-range
//! between them (where a near object's neighbours stand) to the plain loss.
//!
//! With the output frame's labels, `o_p` weighs the pixels of the obstacles that
//! `mode360_core::obstacles` counts (object instances with median true range at most
//! [`mode360_core::obstacles::OBSTACLE_MAX_RANGE_M`] and enough pixels): `o_p = obstacle_weight`, times `thin_weight`
//! for an instance narrower than [`mode360_core::obstacles::THIN_MAX_WIDTH_DEG`]; 1 elsewhere and without labels.
//! `sky_weight` (labels not needed) keeps heavier obstacle weights from leaving the sky to be
//! read as a far surface.

use candle_core::{DType, Device, Tensor};
use mode360_core::frame::{FloatImage, SceneLabels, SurfaceClass};
use mode360_core::geometry::{DepthHypotheses, DepthRange, HypothesisSpacing};
// a neighbour over δ1's threshold nearer makes a pixel the far side of a depth edge
use mode360_core::metrics::DELTA_THRESHOLD;
use mode360_core::obstacles::frame_obstacles;
use std::collections::BTreeMap;

/// PSMNet's stage weights (coarse to fine).
pub const PSMNET_STAGE_WEIGHTS: [f64; 3] = [0.5, 0.7, 1.0];
/// SmoothL1 transition point, in hypothesis steps.
pub const SMOOTH_L1_BETA: f64 = 1.0;

/// Errors computing the loss.
#[derive(Debug, thiserror::Error)]
pub enum LossError {
    #[error("loss: {0}")]
    Tensor(#[from] candle_core::Error),
    #[error("loss: {stages} prediction stages but {weights} stage weights")]
    StageCount { stages: usize, weights: usize },
    #[error("loss: depth range must satisfy 0 < min_depth_m < max_depth_m, got {min} and {max}")]
    DepthRange { min: f64, max: f64 },
}

/// Parameters of the loss.
#[derive(Clone, Debug, PartialEq)]
pub struct LossConfig {
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    /// Number of depth hypotheses `D`.
    pub hypotheses: usize,
    /// How the hypotheses are spread (the target is the normalized index in that spacing).
    pub spacing: HypothesisSpacing,
    /// One weight per output stage, coarse to fine; when the network returns fewer stages
    /// than weights, the last weights are used.
    pub stage_weights: Vec<f64>,
    /// Extra weight of near pixels and of too-far predictions.
    pub weighting: LossWeighting,
}

/// Extra weight of near pixels and of predictions farther than the truth (module docs); also
/// `mode360 train`'s loss options.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct LossWeighting {
    /// Range below which --near-weight applies, metres.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_NEAR_RANGE_M))]
    pub near_range_m: f64,
    /// Loss weight of pixels whose true range is at most --near-range-m (1: the plain loss).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub near_weight: f64,
    /// Loss weight of a pixel predicted farther than its truth (1: the plain loss).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub too_far_weight: f64,
    /// Where the too-far loss weight applies: pixels whose true range is at most this, metres
    /// (default: everywhere), so that the far field and the sky keep the plain loss.
    #[serde(default = "unlimited_range", deserialize_with = "range_or_unlimited")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = f64::INFINITY))]
    pub too_far_range_m: f64,
    /// Loss weight of the pixels of an obstacle as `eval` counts them (an object instance
    /// within 10 m; rendered samples only, they need labels; 1: the plain loss).
    #[serde(default = "unit_weight")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub obstacle_weight: f64,
    /// Further loss weight of a thin obstacle's pixels (narrower than 3 degrees).
    #[serde(default = "unit_weight")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub thin_weight: f64,
    /// Loss weight of a sky pixel (true range at the maximum depth; 1: the plain loss).
    #[serde(default = "unit_weight")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub sky_weight: f64,
    /// Loss weight of a pixel beyond --near-range-m (and short of the maximum depth), not on
    /// a weighted obstacle, predicted nearer than its truth: a phantom obstacle (1: the plain
    /// loss).
    #[serde(default = "unit_weight")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub too_near_weight: f64,
    /// Leave out of the too-near weight the pixels within this many pixels (of the training
    /// image) of a surface over 1.25 times nearer: the far side of a depth edge (0: off).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub too_near_edge_px: usize,
    /// Where the too-near weight starts: pixels whose true range is beyond both this and
    /// --near-range-m, metres (0: from --near-range-m).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub too_near_min_range_m: f64,
}

fn unit_weight() -> f64 {
    1.0
}

fn unlimited_range() -> f64 {
    f64::INFINITY
}

/// A range, where JSON's `null` (how serde_json writes an infinite one) is unlimited.
fn range_or_unlimited<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

/// Range below which [`LossWeighting::near_weight`] applies by default, metres.
pub const DEFAULT_NEAR_RANGE_M: f64 = 5.0;

/// Each pixel's smallest valid true range within `radius_px` pixels (a `(2 r + 1)^2` window,
/// clamped at the image's borders; invalid ranges ignored; +inf where none), a separable
/// minimum filter. `radius_px` 0 gives the image itself.
fn nearest_within(g: &FloatImage, radius_px: usize) -> Vec<f32> {
    let valid = |r: f32| {
        if r.is_finite() && r > 0.0 {
            r
        } else {
            f32::INFINITY
        }
    };
    let (w, h) = (g.width, g.height);
    let data: Vec<f32> = g.data.iter().map(|&r| valid(r)).collect();
    if radius_px == 0 || data.len() != w * h {
        return data;
    }
    let mut rows = vec![f32::INFINITY; w * h];
    for y in 0..h {
        for x in 0..w {
            let (lo, hi) = (x.saturating_sub(radius_px), (x + radius_px).min(w - 1));
            rows[y * w + x] = data[y * w + lo..=y * w + hi]
                .iter()
                .fold(f32::INFINITY, |m, &r| m.min(r));
        }
    }
    let mut out = vec![f32::INFINITY; w * h];
    for y in 0..h {
        let (lo, hi) = (y.saturating_sub(radius_px), (y + radius_px).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (lo..=hi).fold(f32::INFINITY, |m, yy| m.min(rows[yy * w + x]));
        }
    }
    out
}

impl Default for LossWeighting {
    /// The plain loss: every weight 1.
    fn default() -> Self {
        Self {
            near_range_m: DEFAULT_NEAR_RANGE_M,
            near_weight: 1.0,
            too_far_weight: 1.0,
            too_far_range_m: f64::INFINITY,
            obstacle_weight: 1.0,
            thin_weight: 1.0,
            sky_weight: 1.0,
            too_near_weight: 1.0,
            too_near_edge_px: 0,
            too_near_min_range_m: 0.0,
        }
    }
}

impl LossWeighting {
    fn is_plain(&self) -> bool {
        self.near_weight == 1.0
            && self.too_far_weight == 1.0
            && self.obstacle_weight == 1.0
            && self.thin_weight == 1.0
            && self.sky_weight == 1.0
            && self.too_near_weight == 1.0
    }

    fn weighs_obstacles(&self) -> bool {
        self.obstacle_weight != 1.0 || self.thin_weight != 1.0
    }

    /// The obstacle factor `o_p` of every pixel of one frame (module docs); all 1 without
    /// labels, with labels of another size, or when the obstacle weights are 1.
    pub fn obstacle_factors(
        &self,
        range_m: &FloatImage,
        labels: Option<&SceneLabels>,
        max_depth_m: f64,
    ) -> Vec<f32> {
        let mut factors = vec![1.0f32; range_m.data.len()];
        let Some(labels) = labels.filter(|_| self.weighs_obstacles()) else {
            return factors;
        };
        // Scored against itself: only the instances' true ranges and widths are used.
        let Ok(frame) = frame_obstacles(&range_m.data, &range_m.data, labels, max_depth_m) else {
            return factors;
        };
        let by_instance: BTreeMap<u16, f32> = frame
            .obstacles
            .iter()
            .map(|o| {
                let thin = if o.is_thin() { self.thin_weight } else { 1.0 };
                (o.instance, (self.obstacle_weight * thin) as f32)
            })
            .collect();
        for ((f, class), id) in factors.iter_mut().zip(&labels.class).zip(&labels.instance) {
            if *class == SurfaceClass::Object {
                if let Some(w) = by_instance.get(id) {
                    *f = *w;
                }
            }
        }
        factors
    }
}

/// Regression target and validity mask of one or more ground-truth images.
#[derive(Clone, Debug)]
pub struct LossTarget {
    /// `(B, H, W)` normalized inverse depth in `[0, 1]` (0 where invalid).
    pub normalized_inverse_depth: Tensor,
    /// `(B, H, W)` 1 for valid pixels, 0 elsewhere.
    pub mask: Tensor,
    /// `(B, H, W)` each valid pixel's weight (`near_weight` or 1), 0 elsewhere.
    pub weight: Tensor,
    /// `(B, H, W)` 1 where a too-far reading weighs `too_far_weight` (true range at most
    /// `too_far_range_m`), 0 elsewhere.
    pub too_far_zone: Tensor,
    /// `(B, H, W)` 1 where a too-near reading weighs `too_near_weight` (true range beyond
    /// `near_range_m` and `too_near_min_range_m` and short of the maximum depth, not on a
    /// weighted obstacle), 0 elsewhere.
    pub too_near_zone: Tensor,
}

impl LossConfig {
    fn check(&self) -> Result<(), LossError> {
        if !(self.min_depth_m > 0.0 && self.min_depth_m < self.max_depth_m) {
            return Err(LossError::DepthRange {
                min: self.min_depth_m,
                max: self.max_depth_m,
            });
        }
        Ok(())
    }

    /// The normalized hypothesis index of a range, clamped to `[0, 1]`: uniform in inverse
    /// depth `n(rho) = (1/rho - 1/max) / (1/min - 1/max)`, uniform in log depth
    /// `n(rho) = (ln max - ln rho) / (ln max - ln min)`
    /// ([`DepthHypotheses::normalized_of_depth`]).
    pub fn normalized_inverse_depth(&self, range_m: f64) -> f64 {
        Self::normalized_in(self.depth_hypotheses().as_ref(), range_m)
    }

    /// The hypotheses the target is indexed in (`None` for an invalid range).
    fn depth_hypotheses(&self) -> Option<DepthHypotheses> {
        DepthRange::new(self.min_depth_m, self.max_depth_m)
            .and_then(|r| DepthHypotheses::with_spacing(r, self.hypotheses.max(2), self.spacing))
            .ok()
    }

    fn normalized_in(hypotheses: Option<&DepthHypotheses>, range_m: f64) -> f64 {
        hypotheses
            .map_or(0.0, |h| h.normalized_of_depth(range_m))
            .clamp(0.0, 1.0)
    }

    /// Builds the target and mask tensors from ground-truth range images (one per batch item).
    pub fn target(&self, gts: &[&FloatImage], device: &Device) -> Result<LossTarget, LossError> {
        let unlabelled: Vec<_> = gts.iter().map(|g| (*g, None)).collect();
        self.target_labelled(&unlabelled, device)
    }

    /// [`Self::target`] with each image's labels, where it has them, for the obstacle weights.
    pub fn target_labelled(
        &self,
        gts: &[(&FloatImage, Option<&SceneLabels>)],
        device: &Device,
    ) -> Result<LossTarget, LossError> {
        self.check()?;
        let hypotheses = self.depth_hypotheses();
        let (w, h) = gts
            .first()
            .map(|(g, _)| (g.width, g.height))
            .unwrap_or((0, 0));
        let mut target = Vec::with_capacity(gts.len() * w * h);
        let mut mask = Vec::with_capacity(gts.len() * w * h);
        let mut weight = Vec::with_capacity(gts.len() * w * h);
        let mut too_far_zone = Vec::with_capacity(gts.len() * w * h);
        let mut too_near_zone = Vec::with_capacity(gts.len() * w * h);
        let near = &self.weighting;
        let too_near_from_m = near.near_range_m.max(near.too_near_min_range_m);
        for (g, labels) in gts {
            let factors = near.obstacle_factors(g, *labels, self.max_depth_m);
            let nearest = nearest_within(g, near.too_near_edge_px);
            for ((&r, &obstacle), &nearest) in g.data.iter().zip(&factors).zip(&nearest) {
                let r = f64::from(r);
                if r.is_finite() && r > 0.0 && r <= self.max_depth_m {
                    target.push(Self::normalized_in(hypotheses.as_ref(), r) as f32);
                    mask.push(1.0f32);
                    let range_w = if r <= near.near_range_m {
                        near.near_weight as f32
                    } else if r >= self.max_depth_m {
                        near.sky_weight as f32
                    } else {
                        1.0
                    };
                    weight.push(range_w * obstacle);
                    too_far_zone.push(f32::from(u8::from(r <= near.too_far_range_m)));
                    too_near_zone.push(f32::from(u8::from(
                        r > too_near_from_m
                            && r < self.max_depth_m
                            && obstacle == 1.0
                            && f64::from(nearest) * DELTA_THRESHOLD >= r,
                    )));
                } else {
                    target.push(0.0);
                    mask.push(0.0);
                    weight.push(0.0);
                    too_far_zone.push(0.0);
                    too_near_zone.push(0.0);
                }
            }
        }
        let shape = (gts.len(), h, w);
        Ok(LossTarget {
            normalized_inverse_depth: Tensor::from_vec(target, shape, device)?,
            mask: Tensor::from_vec(mask, shape, device)?,
            weight: Tensor::from_vec(weight, shape, device)?,
            too_far_zone: Tensor::from_vec(too_far_zone, shape, device)?,
            too_near_zone: Tensor::from_vec(too_near_zone, shape, device)?,
        })
    }

    /// The multi-stage loss (a scalar tensor) of `stages` (each `(B, H, W)` normalized
    /// inverse depth, coarse to fine) against `target`.
    pub fn loss(&self, stages: &[Tensor], target: &LossTarget) -> Result<Tensor, LossError> {
        self.check()?;
        if stages.is_empty() || stages.len() > self.stage_weights.len() {
            return Err(LossError::StageCount {
                stages: stages.len(),
                weights: self.stage_weights.len(),
            });
        }
        let weights = &self.stage_weights[self.stage_weights.len() - stages.len()..];
        let scale = self.hypotheses.saturating_sub(1).max(1) as f64;
        let valid = target.mask.sum_all()?.to_dtype(DType::F32)?;
        let denom = valid.maximum(1.0)?;
        let mut total: Option<Tensor> = None;
        for (pred, &w) in stages.iter().zip(weights) {
            let diff = ((pred - &target.normalized_inverse_depth)? * scale)?;
            let per_pixel = smooth_l1(&diff, SMOOTH_L1_BETA)?;
            let per_pixel = if self.weighting.is_plain() {
                (per_pixel * &target.mask)?
            } else {
                // Too far: a smaller normalized inverse depth than the truth, where it counts.
                let too_far = diff.lt(0.0)?.to_dtype(DType::F32)?;
                let too_far = (too_far * &target.too_far_zone)?;
                // 1 + (too_far_weight - 1) * [too far in the zone]
                let far_w = ((too_far * (self.weighting.too_far_weight - 1.0))? + 1.0)?;
                let per_pixel = ((per_pixel * &target.weight)? * far_w)?;
                if self.weighting.too_near_weight == 1.0 {
                    per_pixel
                } else {
                    // 1 + (too_near_weight - 1) * [too near in its zone]
                    let too_near = diff.gt(0.0)?.to_dtype(DType::F32)?;
                    let too_near = (too_near * &target.too_near_zone)?;
                    let near_w = ((too_near * (self.weighting.too_near_weight - 1.0))? + 1.0)?;
                    (per_pixel * near_w)?
                }
            };
            let term = (per_pixel.sum_all()? / &denom)?;
            let term = (term * w)?;
            total = Some(match total {
                Some(t) => (t + term)?,
                None => term,
            });
        }
        total.ok_or(LossError::StageCount {
            stages: 0,
            weights: self.stage_weights.len(),
        })
    }
}

/// Elementwise `0.5 x^2 / beta` where `|x| < beta`, else `|x| - 0.5 beta`.
pub fn smooth_l1(x: &Tensor, beta: f64) -> Result<Tensor, candle_core::Error> {
    let abs = x.abs()?;
    let quadratic = (x.sqr()? * (0.5 / beta))?;
    let linear = (&abs - 0.5 * beta)?;
    let small = abs.lt(beta)?;
    small.where_cond(&quadratic, &linear)
}
