//! Learning-free photometric spherical sweep: the classical baseline next to SSMODE.
//!
//! Pipeline for one frame (output ERP grid `W x H`, `N` cameras, `D` spheres):
//!
//! 1. Every camera image becomes a grey image `g = 0.299 R + 0.587 G + 0.114 B` in [0, 1].
//! 2. For each sphere `i` (range `rho_i`, uniform in inverse depth, index 0 the farthest
//!    `1 / max_depth`), every camera is sampled onto the output grid with the exact sweep
//!    formula of [`mode360_core::geometry::SweepGeometry`] (submodule `sampling`); a camera whose frame
//!    is the output frame is used as is.
//! 3. Windowed ZNCC between every camera pair, the best `ceil(f P)` of the `P` pair costs
//!    averaged per pixel (occlusion-robust, submodule `cost`; where only `S < P` pairs see the
//!    pixel, a fisheye's blind region or a masked lens, the best `ceil(ceil(f P) S / P)`); pairs are blended toward the
//!    undecided cost where their baseline is nearly parallel to the ray; a small far prior
//!    `far_prior * i / (D - 1)` is added: a cost volume `C(v, u, i)`.
//! 4. Semi-global aggregation along rows (closed loops in longitude) and columns, with `P2`
//!    lowered across intensity edges of the output view (submodule `sgm`).
//! 5. Winner-take-all `i* = argmin_i S(i)`, refined by the parabola through
//!    `S(i*-1), S(i*), S(i*+1)`: `i = i* + (S(i*-1) - S(i*+1)) / (2 (S(i*-1) - 2 S(i*) + S(i*+1)))`,
//!    which is linear in inverse depth; range `1 / inv(i)`. Index 0 is `max_depth` (sky).
//! 6. Confidence from the aggregated cost curve's margin:
//!    `m = (S_2 - S(i*)) / n_paths` with `S_2` the lowest cost more than
//!    `CONFIDENCE_EXCLUSION` hypotheses away, and `confidence = m / (m + m_0)` in [0, 1).
//!
//! Per-rig work (rotated output rays per camera) is cached and reused while the rig, the
//! image sizes and the output grid stay the same. Sampling is computed per sphere on the fly;
//! memory peaks at three `W H D` f32 volumes (per-sphere slices, the `[v][u][i]` volume, the
//! aggregated volume: 3 x 64 MiB at 512x256 with 128 spheres).
//!
//! Measured on rendered 512x256 street frames (4 cameras, defaults): delta1 about 91 %, about
//! 3.3 CPU-seconds per frame (under 2 s wall on two idle cores).

mod config;
mod curve;
pub mod sampling;
mod sgm;

pub use config::{AggregationConfig, PhotometricConfig};
pub use curve::{refine_minimum, CurveMinimum, CONFIDENCE_EXCLUSION};

use super::lens_mask::LensMask;
use super::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360_core::frame::RgbImage;
use mode360_core::geometry::panorama::{panorama_rig, RigRemap};
use mode360_core::geometry::{DepthHypotheses, ErpGrid, Rig};
use mode360_model::matching::zncc::{self as cost, PairCostParams, ViewStats};
use mode360_model::matching::{luma, INTENSITY_SCALE};
use nalgebra::Isometry3;
use rayon::prelude::*;
use sampling::CameraSampler;

/// Name of this estimator on the command line and in reports.
pub const PHOTOMETRIC_NAME: &str = "photometric";

/// What the per-rig cache was built for.
#[derive(Clone, Debug, PartialEq)]
struct CacheKey {
    output: ErpGrid,
    camera_grids: Vec<ErpGrid>,
    cam_from_output: Vec<Isometry3<f64>>,
}

/// Per-rig sampling data, reused between frames.
#[derive(Debug)]
struct RigCache {
    key: CacheKey,
    /// Per camera, where its panorama holds content (`None`: everywhere).
    validity: Vec<Option<Vec<f32>>>,
    /// Per camera, where it is used: `validity` without the lens masks' blocked parts.
    seen: Vec<Option<Vec<f32>>>,
    /// The lens masks `seen` was built with.
    masks: Vec<Option<LensMask>>,
    samplers: Vec<CameraSampler>,
    /// Per camera pair `(a < b)`, per output pixel: `sin(angle(ray, baseline))^k`.
    pair_weights: Vec<Vec<f32>>,
}

/// The learning-free photometric spherical-sweep depth estimator.
#[derive(Debug)]
pub struct PhotometricSweep {
    cfg: PhotometricConfig,
    hypotheses: DepthHypotheses,
    cache: Option<RigCache>,
    /// Fisheye images into panoramas as wide as the output, for the last rig seen.
    remap: Option<RigRemap>,
    /// Blocked parts of the cameras' views ([`DepthEstimator::set_lens_masks`]).
    lens_masks: Vec<Option<LensMask>>,
}

impl PhotometricSweep {
    /// Validates `cfg`.
    pub fn new(cfg: PhotometricConfig) -> Result<Self, EstimatorError> {
        let hypotheses = cfg.validate()?;
        Ok(Self {
            cfg,
            hypotheses,
            cache: None,
            remap: None,
            lens_masks: Vec::new(),
        })
    }

    pub fn config(&self) -> &PhotometricConfig {
        &self.cfg
    }

    pub fn hypotheses(&self) -> &DepthHypotheses {
        &self.hypotheses
    }

    /// The matching cost volume `[v][u][i]` before aggregation (exposed for analysis).
    pub fn cost_volume(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<Vec<f32>, EstimatorError> {
        let grey = self.prepare(rig, images, output)?;
        Ok(self.build_volume(&grey, output))
    }

    /// Checks the images, refreshes the rig cache, returns grey images.
    fn prepare(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<Vec<Vec<f32>>, EstimatorError> {
        if images.len() != rig.cameras.len() {
            return Err(EstimatorError::ImageCount {
                got: images.len(),
                expected: rig.cameras.len(),
            });
        }
        // Fisheye cameras are swept through panoramas of their own frame; the remap is
        // built once per rig and output grid (a new one invalidates the sampling cache).
        let remap = match &mut self.remap {
            Some(r) if r.serves(rig, output) => r,
            slot => {
                self.cache = None;
                slot.insert(RigRemap::new(rig, output))
            }
        };
        let panoramas =
            remap
                .panoramas(images)
                .map_err(|(camera, e)| EstimatorError::BadImage {
                    camera,
                    problem: e.to_string(),
                })?;
        let pano_rig = panorama_rig(rig);
        let mut camera_grids = Vec::with_capacity(images.len());
        for (img, cam) in panoramas.iter().zip(&rig.cameras) {
            let (width, height) = img.dimensions();
            let bad = || EstimatorError::BadImageSize {
                camera: cam.name.clone(),
                width,
                height,
            };
            if width != 2 * height {
                return Err(bad());
            }
            camera_grids.push(ErpGrid::new(width as usize).map_err(|_| bad())?);
        }
        let key = CacheKey {
            output,
            camera_grids,
            cam_from_output: (0..rig.cameras.len())
                .map(|i| pano_rig.cam_from_output(i))
                .collect(),
        };
        if self.cache.as_ref().map(|c| &c.key) != Some(&key) {
            let samplers = key
                .camera_grids
                .par_iter()
                .zip(key.cam_from_output.par_iter())
                .map(|(grid, pose)| CameraSampler::new(output, pose, *grid))
                .collect();
            let pair_weights = pair_parallax_weights(&key, self.cfg.parallax_exponent);
            let validity = self
                .remap
                .as_ref()
                .map(RigRemap::validity)
                .unwrap_or_default();
            self.cache = Some(RigCache {
                key,
                seen: validity.clone(),
                validity,
                masks: Vec::new(),
                samplers,
                pair_weights,
            });
        }
        if let Some(cache) = self.cache.as_mut() {
            // Masks of another number of cameras are stale: ignored.
            let masks = if self.lens_masks.len() == cache.samplers.len() {
                &self.lens_masks[..]
            } else {
                &[]
            };
            if cache.masks != masks {
                cache.seen = masked_validity(&cache.validity, masks, &cache.key.camera_grids);
                cache.masks = masks.to_vec();
            }
        }
        Ok(panoramas.par_iter().map(|p| grey_image(p)).collect())
    }

    fn pair_params(&self, cameras: usize) -> PairCostParams {
        let pairs = cameras * cameras.saturating_sub(1) / 2;
        PairCostParams {
            window_radius_px: self.cfg.window_radius_px,
            variance_floor: self.cfg.variance_floor,
            mean_weight: self.cfg.mean_weight,
            mean_scale: self.cfg.mean_scale,
            best_pairs: ((pairs as f32 * self.cfg.best_pair_fraction).ceil() as usize).max(1),
        }
    }

    /// Cost volume `[v][u][i]` of the cached rig.
    fn build_volume(&self, grey: &[Vec<f32>], output: ErpGrid) -> Vec<f32> {
        let Some(cache) = self.cache.as_ref() else {
            return Vec::new();
        };
        let (w, h) = (output.width(), output.height());
        let n = output.len();
        let d_count = self.hypotheses.count();
        let params = self.pair_params(grey.len());
        // Views whose sampling is the identity are the same on every sphere: compute once.
        let fixed: Vec<Option<ViewStats>> = cache
            .samplers
            .iter()
            .zip(grey)
            .map(|(sampler, img)| {
                sampler.identity.then(|| {
                    let mut tmp = vec![0.0f32; n];
                    ViewStats::new(img.clone(), w, h, params.window_radius_px, &mut tmp)
                })
            })
            .collect();
        let slices: Vec<Vec<f32>> = (0..d_count)
            .into_par_iter()
            .map(|i| {
                let range_m = self.hypotheses.depth_m(i as f64) as f32;
                let mut tmp = vec![0.0f32; n];
                let warped: Vec<Option<ViewStats>> = cache
                    .samplers
                    .iter()
                    .zip(grey)
                    .zip(&fixed)
                    .map(|((sampler, img), fixed)| {
                        fixed.is_none().then(|| {
                            let mut warped = vec![0.0f32; n];
                            sampler.warp(img, range_m, &mut warped);
                            ViewStats::new(warped, w, h, params.window_radius_px, &mut tmp)
                        })
                    })
                    .collect();
                let views: Vec<&ViewStats> = warped
                    .iter()
                    .zip(&fixed)
                    .filter_map(|(a, b)| a.as_ref().or(b.as_ref()))
                    .collect();
                // Where each camera's lens sees the sphere's points (`None`: everywhere).
                let seen: Vec<Option<Vec<f32>>> = cache
                    .samplers
                    .iter()
                    .zip(&cache.seen)
                    .map(|(sampler, valid)| {
                        valid.as_ref().map(|valid| {
                            let mut warped = vec![0.0f32; n];
                            sampler.warp(valid, range_m, &mut warped);
                            warped
                        })
                    })
                    .collect();
                let seen: Vec<Option<&[f32]>> = seen.iter().map(Option::as_deref).collect();
                cost::sphere_cost(&views, &seen, &cache.pair_weights, w, h, &params)
            })
            .collect();
        let prior_step = self.cfg.far_prior / (d_count - 1).max(1) as f32;
        let mut volume = vec![0.0f32; n * d_count];
        volume
            .par_chunks_mut(w * d_count)
            .enumerate()
            .for_each(|(v, row)| {
                for (u, cell) in row.chunks_exact_mut(d_count).enumerate() {
                    let k = v * w + u;
                    for (i, (c, slice)) in cell.iter_mut().zip(&slices).enumerate() {
                        *c = slice[k] + prior_step * i as f32;
                    }
                }
            });
        volume
    }
}

/// Each camera's validity (`None`: it sees everything) with its lens mask's blocked part set to
/// 0, on the camera's panorama grid.
fn masked_validity(
    validity: &[Option<Vec<f32>>],
    masks: &[Option<LensMask>],
    grids: &[ErpGrid],
) -> Vec<Option<Vec<f32>>> {
    grids
        .iter()
        .enumerate()
        .map(|(c, grid)| {
            let valid = validity.get(c).cloned().flatten();
            let Some(mask) = masks.get(c).and_then(Option::as_ref) else {
                return valid;
            };
            let mut valid = valid.unwrap_or_else(|| vec![1.0; grid.len()]);
            for (v, blocked) in valid.iter_mut().zip(mask.blocked_on(*grid)) {
                if blocked {
                    *v = 0.0;
                }
            }
            Some(valid)
        })
        .collect()
}

/// Parallax weights of the cached rig's camera pairs ([`mode360_model::matching::pair_parallax_weights`]).
fn pair_parallax_weights(key: &CacheKey, exponent: f32) -> Vec<Vec<f32>> {
    let centres: Vec<_> = key
        .cam_from_output
        .iter()
        .map(|c| c.inverse().translation.vector)
        .collect();
    mode360_model::matching::pair_parallax_weights(key.output, &centres, exponent)
}

impl PhotometricSweep {
    /// The output view for edge-aware aggregation: the camera nearest the output origin,
    /// sampled on the farthest sphere (exact when it is the output camera).
    fn guide_image(&self, grey: &[Vec<f32>], output: ErpGrid) -> Vec<f32> {
        let mut guide = vec![0.0f32; output.len()];
        let Some(cache) = self.cache.as_ref() else {
            return guide;
        };
        let nearest = cache
            .key
            .cam_from_output
            .iter()
            .enumerate()
            .min_by(|a, b| {
                a.1.translation
                    .vector
                    .norm()
                    .total_cmp(&b.1.translation.vector.norm())
            })
            .map(|(i, _)| i)
            .unwrap_or(0);
        if let (Some(sampler), Some(img)) = (cache.samplers.get(nearest), grey.get(nearest)) {
            let far_m = self.hypotheses.depth_m(0.0) as f32;
            sampler.warp(img, far_m, &mut guide);
        }
        guide
    }
}

/// Grey image in [0, 1], row-major.
fn grey_image(img: &RgbImage) -> Vec<f32> {
    img.pixels()
        .map(|p| luma([f32::from(p[0]), f32::from(p[1]), f32::from(p[2])]) * INTENSITY_SCALE)
        .collect()
}

impl PhotometricSweep {
    /// Depth and confidence from a (possibly aggregated) volume `[v][u][i]`.
    fn decide(&self, volume: &[f32], output: ErpGrid, refine: bool, paths: usize) -> DepthEstimate {
        let d_count = self.hypotheses.count();
        let margin_scale = self.cfg.confidence_margin * paths.max(1) as f32;
        let max_depth_m = self.hypotheses.range().max_depth_m;
        let (range, conf): (Vec<f32>, Vec<f32>) = volume
            .par_chunks(d_count)
            .map(|curve| {
                let m = refine_minimum(curve, refine);
                let range_m = if m.index <= 0.0 {
                    max_depth_m
                } else {
                    self.hypotheses.depth_m(m.index)
                };
                (range_m as f32, m.margin / (m.margin + margin_scale))
            })
            .unzip();
        DepthEstimate::on_grid(output, range, conf)
    }

    /// Like [`DepthEstimator::estimate`], optionally without the parabolic refinement (plain
    /// winner-take-all), for comparisons.
    pub fn estimate_with(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
        refine: bool,
    ) -> Result<DepthEstimate, EstimatorError> {
        let started = std::time::Instant::now();
        let grey = self.prepare(rig, images, output)?;
        let prepared_s = started.elapsed().as_secs_f64();
        let volume = self.build_volume(&grey, output);
        let volume_s = started.elapsed().as_secs_f64() - prepared_s;
        tracing::debug!(prepared_s, volume_s, "photometric sweep: cost volume built");
        let agg = self.cfg.aggregation;
        if !agg.enabled {
            return Ok(self.decide(&volume, output, refine, 1));
        }
        let pen = sgm::SgmPenalties {
            p1: agg.p1,
            p2: agg.p2,
            edge_scale: agg.edge_scale,
        };
        let guide = self.guide_image(&grey, output);
        let summed = sgm::aggregate(
            &volume,
            &guide,
            output.width(),
            output.height(),
            self.hypotheses.count(),
            pen,
            agg.row_warmup_px,
        );
        drop(volume);
        let aggregated_s = started.elapsed().as_secs_f64() - prepared_s - volume_s;
        let estimate = self.decide(&summed, output, refine, sgm::PATH_COUNT);
        tracing::debug!(
            aggregated_s,
            total_s = started.elapsed().as_secs_f64(),
            "photometric sweep: done"
        );
        Ok(estimate)
    }
}

impl DepthEstimator for PhotometricSweep {
    fn name(&self) -> &str {
        PHOTOMETRIC_NAME
    }

    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        self.estimate_with(rig, images, output, true)
    }

    fn set_lens_masks(&mut self, masks: &[Option<LensMask>]) {
        if self.lens_masks != masks {
            self.lens_masks = masks.to_vec();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::DepthRange;

    #[test]
    fn config_reads_partial_json_with_defaults() -> Result<(), serde_json::Error> {
        let cfg: PhotometricConfig =
            serde_json::from_str(r#"{"hypotheses": 64, "aggregation": {"p2": 0.9}}"#)?;
        assert_eq!(cfg.hypotheses, 64);
        assert_eq!(cfg.aggregation.p2, 0.9);
        assert_eq!(cfg.aggregation.p1, AggregationConfig::default().p1);
        assert_eq!(cfg.depth_range, DepthRange::paper());
        let back: PhotometricConfig = serde_json::from_str(&serde_json::to_string(&cfg)?)?;
        assert_eq!(back, cfg);
        Ok(())
    }

    #[test]
    fn rejects_bad_config() {
        let cfg = PhotometricConfig {
            hypotheses: 1,
            ..Default::default()
        };
        assert!(PhotometricSweep::new(cfg).is_err());
        let cfg = PhotometricConfig {
            best_pair_fraction: 0.0,
            ..Default::default()
        };
        assert!(matches!(
            PhotometricSweep::new(cfg),
            Err(EstimatorError::BadConfig { .. })
        ));
    }
}
