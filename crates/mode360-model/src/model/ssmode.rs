//! The SSMODE network (paper section 4.3, with count-invariant view aggregation).
//!
//! ```text
//! images: N x (B, H, W, 3) -> stacked (N B, H, W, 3)
//! feature                   -> (N B, h, w, Cf) -> N x (B, h, w, Cf)   h = H / cost_downsample
//! photometric_cost          -> (B, D, h, w, 1)            optional ZNCC matching channel
//! cost_volume(_appended)    -> (B, D, h, w, C' (+ 1))     variance (and mean) over views, the
//!                              matching channel written beside it in the same pass
//! aggregation               -> K x (B, D/s, h/s, (w + 2 p)/s, Ch) stacked hourglasses, entry
//!                              stride s, then p/s columns copied across the longitude seam
//! classif{k}, crop          -> K x (B, D/s, h/s, w/s)
//! fine_head (optional)      -> the last one corrected at full h and w: (B, D/s, h, w)
//! regression                -> K x (B, H, W) range, index; confidence of the last
//! ```

use std::time::{Duration, Instant};

use candle_core::{Result, Tensor};
use candle_nn::VarBuilder;

use super::config::{SsmodeConfig, MIN_CAMERAS};
use super::cost_volume::{
    appended_in_slabs, cost_volume, cost_volume_appended, cost_volume_appended_spheres,
};
use super::feature::FeatureExtractor;
use super::fine_head::{FineHead, FINE_HEAD_PREFIX};
use super::hourglass::CostAggregation;
use super::photometric_cost::photometric_cost;
use super::readout::Readout;
use super::regression::{
    confidence, regress, regress_inference, RangeReadout, Regression, RegressionHead,
};
use super::seam::crop_longitude;
use super::sweep_sampling::SweepSampling;
use crate::model::ops::{flop_count, OpsError};
use mode360_core::geometry::DepthHypotheses;

/// Image channels (RGB).
const IMAGE_CHANNELS: usize = 3;

/// What [`Ssmode::forward`] returns.
#[derive(Clone, Debug)]
pub struct SsmodeOutput {
    /// Per hourglass, `(B, H, W)` range in metres; the last is the final estimate (only the
    /// final one when `forward` runs with `train = false`).
    pub stages: Vec<Tensor>,
    /// Like `stages`: `(B, H, W)` expected normalized inverse-depth index in [0, 1]
    /// (0 = `max_depth_m`, 1 = `min_depth_m`).
    pub inverse_depth_stages: Vec<Tensor>,
    /// `(B, H, W)` probability mass within 2 hypotheses of the final argmax.
    pub confidence: Tensor,
    /// `(B, N, H, W)` softmax over the hypotheses of the final stage; only with `train` (the
    /// inference path never materialises it).
    pub probabilities: Option<Tensor>,
}

/// Wall time and floating-point work of one stage of a forward pass.
#[derive(Clone, Debug, PartialEq)]
pub struct StageTiming {
    /// `feature`, `cost_volume`, `aggregation` or `regression`.
    pub stage: &'static str,
    pub elapsed: Duration,
    /// Convolution and matrix-product FLOPs issued by the stage (multiply-add = 2).
    pub flops: u64,
}

impl StageTiming {
    /// `flops / elapsed` in GFLOP/s (0 for an instantaneous stage).
    pub fn gflops_per_s(&self) -> f64 {
        let secs = self.elapsed.as_secs_f64();
        if secs > 0.0 {
            self.flops as f64 / secs / 1e9
        } else {
            0.0
        }
    }
}

/// Collects [`StageTiming`]s during [`Ssmode::forward_profiled`]. Candle's CPU ops run
/// eagerly, so a stage's time is the time between two marks.
#[derive(Clone, Debug)]
pub struct StageProfiler {
    last: Instant,
    flops_at_last: u64,
    stages: Vec<StageTiming>,
}

impl Default for StageProfiler {
    fn default() -> Self {
        Self::new()
    }
}

impl StageProfiler {
    pub fn new() -> Self {
        Self {
            last: Instant::now(),
            flops_at_last: flop_count(),
            stages: Vec::new(),
        }
    }

    /// Ends the stage `stage` (started at the previous mark) and starts the next one.
    fn mark(&mut self, stage: &'static str) {
        let now = Instant::now();
        let flops = flop_count();
        self.stages.push(StageTiming {
            stage,
            elapsed: now - self.last,
            flops: flops.saturating_sub(self.flops_at_last),
        });
        self.last = now;
        self.flops_at_last = flops;
    }

    /// [`Self::mark`] on `profiler` when there is one.
    fn mark_on(profiler: &mut Option<&mut StageProfiler>, stage: &'static str) {
        if let Some(p) = profiler.as_deref_mut() {
            p.mark(stage);
        }
    }

    /// Ends two stages that ran interleaved since the previous mark: `first` took
    /// `first_elapsed` of the time and no counted FLOPs, `second` the rest.
    fn mark_split(&mut self, first: &'static str, first_elapsed: Duration, second: &'static str) {
        let now = Instant::now();
        let first_elapsed = first_elapsed.min(now - self.last);
        let flops = flop_count();
        self.stages.push(StageTiming {
            stage: first,
            elapsed: first_elapsed,
            flops: 0,
        });
        self.stages.push(StageTiming {
            stage: second,
            elapsed: now - self.last - first_elapsed,
            flops: flops.saturating_sub(self.flops_at_last),
        });
        self.last = now;
        self.flops_at_last = flops;
    }

    pub fn stages(&self) -> &[StageTiming] {
        &self.stages
    }
}

/// The network. Variable names: `feature.*`, `aggregation.*`, `classif{k}.*`, `fine_head.*`
/// (with `fine_head_channels`).
#[derive(Clone, Debug)]
pub struct Ssmode {
    cfg: SsmodeConfig,
    /// How the output is read (a setting, not part of the network).
    readout: Readout,
    hypotheses: DepthHypotheses,
    feature: FeatureExtractor,
    aggregation: CostAggregation,
    classif: Vec<RegressionHead>,
    fine_head: Option<FineHead>,
}

impl Ssmode {
    pub fn new(cfg: &SsmodeConfig, vb: VarBuilder) -> Result<Self> {
        cfg.validate().map_err(candle_core::Error::wrap)?;
        let hypotheses = cfg.output_hypotheses().map_err(candle_core::Error::wrap)?;
        Ok(Self {
            cfg: cfg.clone(),
            readout: Readout::default(),
            hypotheses,
            feature: FeatureExtractor::new(cfg, vb.pp("feature"))?,
            aggregation: CostAggregation::new(cfg, vb.pp("aggregation"))?,
            classif: (0..cfg.hourglasses)
                .map(|k| RegressionHead::new(cfg.hourglass_channels, vb.pp(format!("classif{k}"))))
                .collect::<Result<_>>()?,
            fine_head: (cfg.fine_head_channels > 0)
                .then(|| FineHead::new(cfg, vb.pp(FINE_HEAD_PREFIX)))
                .transpose()?,
        })
    }

    /// The fine head's first layer on the whole volume, when the network has the head.
    fn fine_cost_part(&self, volume: &Tensor) -> Result<Option<Tensor>> {
        self.fine_head
            .as_ref()
            .map(|h| h.cost_part(volume))
            .transpose()
    }

    /// The last hourglass's cropped cost `(B, D/s, h/s, w/s)`, corrected by the fine head
    /// from its first layer's output `fine_part` when the network has one: `(B, D/s, h, w)`.
    fn finish_cost(&self, coarse: Tensor, fine_part: Option<&Tensor>) -> Result<Tensor> {
        match (&self.fine_head, fine_part) {
            (Some(head), Some(part)) => head.forward(part, &coarse),
            _ => Ok(coarse),
        }
    }

    /// A regression head's cost `(B, D/s, h/s, (w + 2 p)/s)` -> `(B, D/s, h/s, w/s)`: the
    /// sphere's own columns, without the seam wrap's.
    fn crop_seam(&self, cost: Tensor) -> Result<Tensor> {
        crop_longitude(&cost, self.cfg.seam_pad_cells, self.cfg.aggregation_stride)
    }

    pub fn config(&self) -> &SsmodeConfig {
        &self.cfg
    }

    /// How the output is read ([`Readout::default`] unless [`Self::with_readout`] said).
    pub fn readout(&self) -> &Readout {
        &self.readout
    }

    /// The network with `readout` (checked): the far-plane test here, the far field in the
    /// [`SweepSampling`] built with it ([`SweepSampling::with_readout`]).
    pub fn with_readout(
        self,
        readout: Readout,
    ) -> std::result::Result<Self, crate::model::ModelError> {
        readout.validate()?;
        Ok(Self { readout, ..self })
    }

    /// The full-resolution hypotheses the range is regressed over.
    pub fn hypotheses(&self) -> &DepthHypotheses {
        &self.hypotheses
    }

    fn check_images(&self, images: &[Tensor], sampling: &SweepSampling) -> Result<()> {
        const OP: &str = "Ssmode::forward";
        if images.len() < MIN_CAMERAS || images.len() != sampling.camera_count() {
            return Err(OpsError::Shape {
                op: OP,
                what: format!(
                    "{} images for a sweep of {} cameras (at least {MIN_CAMERAS})",
                    images.len(),
                    sampling.camera_count()
                ),
            }
            .into());
        }
        let expected = sampling.geometry().output();
        if expected.width() != self.cfg.cost_width() {
            return Err(OpsError::Shape {
                op: OP,
                what: format!(
                    "sweep sampling built for cost width {}, the config needs {}",
                    expected.width(),
                    self.cfg.cost_width()
                ),
            }
            .into());
        }
        let first = images[0].dims().to_vec();
        for (cam, img) in images.iter().enumerate() {
            let dims = img.dims();
            let ok = dims.len() == 4
                && dims[1] == self.cfg.height()
                && dims[2] == self.cfg.width
                && dims[3] == IMAGE_CHANNELS
                && dims == first.as_slice();
            if !ok {
                return Err(OpsError::Shape {
                    op: OP,
                    what: format!(
                        "camera {cam}: image shape {dims:?}, expected (B, {}, {}, 3) like camera 0 {first:?}",
                        self.cfg.height(),
                        self.cfg.width
                    ),
                }
                .into());
            }
        }
        Ok(())
    }

    /// The whole cost volume of `features` `(N B, h, w, Cf)`: `(B, D, h, w, C')`, or
    /// `(B, D, h, w, C' + 1)` with the photometric cost channel written beside the views'
    /// variance in one pass.
    fn whole_volume(
        &self,
        images: &[Tensor],
        features: &Tensor,
        sampling: &SweepSampling,
    ) -> Result<Tensor> {
        if self.cfg.photometric_cost {
            // (B, D, h, w, 1)
            let photometric = photometric_cost(images, sampling)?;
            cost_volume_appended(features, sampling, self.cfg.cost, &photometric)
        } else {
            cost_volume(features, sampling, self.cfg.cost)
        }
    }

    /// Training of the fine head alone, the rest of the network frozen: the final stage as
    /// [`Ssmode::forward`] with `train` computes it (range, index, confidence, probabilities),
    /// but the only variables it depends on are `fine_head.*`. The head's two inputs, the
    /// cost volume and the last hourglass's cost, are detached, so a backward pass runs
    /// through the head and the regression only (about a third of a full training step), and
    /// the earlier hourglasses are not regressed. An error on a network without the head.
    pub fn forward_fine_head_only(
        &self,
        images: &[Tensor],
        sampling: &SweepSampling,
    ) -> Result<SsmodeOutput> {
        const OP: &str = "Ssmode::forward_fine_head_only";
        let Some(fine_head) = &self.fine_head else {
            return Err(OpsError::Shape {
                op: OP,
                what: "the network has no fine head (fine_head_channels 0)".to_string(),
            }
            .into());
        };
        self.check_images(images, sampling)?;
        // (N B, H, W, 3)
        let stacked = Tensor::cat(images, 0)?;
        // (N B, h, w, Cf)
        let features = self
            .feature
            .forward(&stacked, sampling.sphere_conv())?
            .detach();
        // (B, D, h, w, C' (+ 1)), depending on no variable
        let volume = self.whole_volume(images, &features, sampling)?;
        drop(features);
        // (B, D/s, h/s, (w + 2 p)/s, Ch)
        let last = self
            .aggregation
            .forward(&volume, self.cfg.seam_pad_cells)?
            .pop()
            .zip(self.classif.last())
            .ok_or(OpsError::Shape {
                op: OP,
                what: "no hourglass stages".to_string(),
            })?;
        // (B, D/s, h/s, w/s), detached: the hourglasses' graph is dropped here
        let coarse = self.crop_seam(last.1.forward(&last.0)?)?.detach();
        drop(last);
        // (B, D/s, h, w)
        let cost = fine_head.forward(&fine_head.cost_part(&volume)?, &coarse)?;
        drop(volume);
        // (B, H, W)
        let r = self.regress_stage(&cost, sampling)?;
        Ok(SsmodeOutput {
            stages: vec![r.range_m],
            inverse_depth_stages: vec![r.inverse_depth_index],
            confidence: confidence(&r.probabilities)?,
            probabilities: Some(r.probabilities),
        })
    }

    /// Training's regression of one stage's cost `(B, D/s, h', w')` into `(B, H, W)` range,
    /// index and probabilities, with the far-plane test on `sampling`'s rig.
    fn regress_stage(&self, cost: &Tensor, sampling: &SweepSampling) -> Result<Regression> {
        regress(
            cost,
            &self.hypotheses,
            self.cfg.height(),
            self.cfg.width,
            self.range_readout(sampling),
        )
    }

    /// The far-plane test and the near mode of the readout on `sampling`'s rig.
    fn range_readout<'a>(&self, sampling: &'a SweepSampling) -> RangeReadout<'a> {
        RangeReadout {
            probability: self.readout.far_plane_probability,
            far_counts: sampling.far_counts(),
            near_mode_probability: self.readout.near_mode_probability,
        }
    }

    /// Inference's readout: only the last hourglass `(B, D/s, h/s, (w + 2 p)/s, Ch)`, regressed
    /// by the fused kernel into `(B, H, W)` range, index and confidence.
    fn regress_last(
        &self,
        mut aggregated: Vec<Tensor>,
        fine_part: Option<Tensor>,
        sampling: &SweepSampling,
    ) -> Result<SsmodeOutput> {
        let (head, x) = self
            .classif
            .last()
            .zip(aggregated.pop())
            .ok_or(OpsError::Shape {
                op: "Ssmode::forward",
                what: "no hourglass stages".to_string(),
            })?;
        drop(aggregated);
        // (B, D/s, h/s, w/s), with the fine head (B, D/s, h, w)
        let cost = self.finish_cost(self.crop_seam(head.forward(&x)?)?, fine_part.as_ref())?;
        drop(x);
        drop(fine_part);
        // (B, H, W) each
        let r = regress_inference(
            &cost,
            &self.hypotheses,
            self.cfg.height(),
            self.cfg.width,
            self.range_readout(sampling),
        )?;
        Ok(SsmodeOutput {
            stages: vec![r.range_m],
            inverse_depth_stages: vec![r.inverse_depth_index],
            confidence: r.confidence,
            probabilities: None,
        })
    }

    /// images: one `(B, H, W, 3)` f32 tensor in [0, 1] per camera, rig order (any count >= 2).
    /// With `train` every hourglass is regressed (for the stacked loss); without it only the
    /// last one, so `stages` and `inverse_depth_stages` then hold just the final estimate.
    /// The network has no train-only layers: the final stage is identical either way.
    pub fn forward(
        &self,
        images: &[Tensor],
        sampling: &SweepSampling,
        train: bool,
    ) -> Result<SsmodeOutput> {
        self.forward_profiled(images, sampling, train, None)
    }

    /// [`Ssmode::forward`], recording per-stage timings into `profiler` when given.
    pub fn forward_profiled(
        &self,
        images: &[Tensor],
        sampling: &SweepSampling,
        train: bool,
        mut profiler: Option<&mut StageProfiler>,
    ) -> Result<SsmodeOutput> {
        self.check_images(images, sampling)?;
        // (N B, H, W, 3)
        let stacked = Tensor::cat(images, 0)?;
        // (N B, h, w, Cf)
        let features = self.feature.forward(&stacked, sampling.sphere_conv())?;
        StageProfiler::mark_on(&mut profiler, "feature");
        if !train && self.cfg.photometric_cost && appended_in_slabs(&features, self.cfg.cost) {
            // inference never holds the whole volume: the entry convolution takes it a few
            // spheres at a time (the same numbers; 108 MiB less at 256)
            let sweep_start = Instant::now();
            // (B, D, h, w, 1)
            let photometric = photometric_cost(images, sampling)?;
            let mut sweep_time = sweep_start.elapsed();
            let slab = |spheres| {
                let start = Instant::now();
                // (B, len, h, w, C' + 1)
                let volume =
                    cost_volume_appended_spheres(&features, sampling, &photometric, spheres);
                sweep_time += start.elapsed();
                volume
            };
            // K x (B, D/s, h/s, (w + 2 p)/s, Ch), and the fine head's first layer
            // (B, D/s, h, w, Cf)
            let (aggregated, fine_part) = self.aggregation.forward_slabs(
                self.cfg.spheres,
                slab,
                self.cfg.seam_pad_cells,
                self.fine_head.as_ref().map(FineHead::cost_conv),
            )?;
            drop(features);
            if let Some(p) = profiler.as_deref_mut() {
                p.mark_split("cost_volume", sweep_time, "aggregation");
            }
            let out = self.regress_last(aggregated, fine_part, sampling)?;
            StageProfiler::mark_on(&mut profiler, "regression");
            return Ok(out);
        }
        // (B, D, h, w, C' (+ 1))
        let volume = self.whole_volume(images, &features, sampling)?;
        drop(features);
        StageProfiler::mark_on(&mut profiler, "cost_volume");
        // K x (B, D/s, h/s, (w + 2 p)/s, Ch), p columns from across the longitude seam each side
        let aggregated = self.aggregation.forward(&volume, self.cfg.seam_pad_cells)?;
        // (B, D/s, h, w, Cf)
        let fine_part = self.fine_cost_part(&volume)?;
        drop(volume);
        StageProfiler::mark_on(&mut profiler, "aggregation");
        if !train {
            let out = self.regress_last(aggregated, fine_part, sampling)?;
            StageProfiler::mark_on(&mut profiler, "regression");
            return Ok(out);
        }
        let mut stages = Vec::with_capacity(aggregated.len());
        let mut inverse_depth_stages = Vec::with_capacity(aggregated.len());
        let mut last_probabilities = None;
        let last = aggregated.len().saturating_sub(1);
        for (k, (head, x)) in self.classif.iter().zip(&aggregated).enumerate() {
            // (B, D/s, h/s, w/s); the last with the fine head (B, D/s, h, w)
            let cost = self.crop_seam(head.forward(x)?)?;
            let cost = if k == last {
                self.finish_cost(cost, fine_part.as_ref())?
            } else {
                cost
            };
            // (B, H, W)
            let r = self.regress_stage(&cost, sampling)?;
            stages.push(r.range_m);
            inverse_depth_stages.push(r.inverse_depth_index);
            last_probabilities = Some(r.probabilities);
        }
        let probabilities = last_probabilities.ok_or(OpsError::Shape {
            op: "Ssmode::forward",
            what: "no hourglass stages".to_string(),
        })?;
        let confidence = confidence(&probabilities)?;
        StageProfiler::mark_on(&mut profiler, "regression");
        Ok(SsmodeOutput {
            stages,
            inverse_depth_stages,
            confidence,
            probabilities: Some(probabilities),
        })
    }
}
