//! PSMODE, the paper's two-stage estimator (section 4.2), as a [`DepthEstimator`].
//!
//! Stage 1, pairwise stereo in GEER: for each chosen camera pair both panoramas are turned into
//! the pair's GEER frame ([`PairView`]: GEER stored transposed, so epipolar lines are columns
//! and the network's longitude wrap serves GEER's azimuth); a two-camera network matches them
//! along those lines, its range is from the left camera, and it is brought into the rig's
//! output frame by splatting ([`PairView::align`]), dropping what either camera does not see.
//! The stage-1 network is SSMODE's architecture on the two-camera pair rig (its sweep over the
//! pair rig is a search along the epipolar columns; its hypotheses are uniform in log range,
//! that is, per row a set of angular disparities), so SSMODE's features, cost volume,
//! aggregation and readout are shared, not copied. It runs at the pair width
//! ([`DEFAULT_PAIR_WIDTH`], 512) where the output is at least that wide, else at the width it
//! was trained at (256): the same weights keep more obstacles and read every held-out row but
//! random objects better at 512, for about three times the time.
//!
//! Stage 2, fusion: the trained fusion network ([`Fusion`], [`PairFusion::Network`]) takes the
//! pairs' aligned ranges and confidences and the reference panorama on its own grid; without
//! it, [`PairFusion::Consensus`] (the default setting) takes per output pixel the range the
//! pairs agree on, and [`PairFusion::MostConfident`] (`none`) the pair with the highest
//! confidence (the paper's "PSMODE without fusion").

use nalgebra::Isometry3;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::lens_mask::analysis_grid;
use super::lens_mask::LensMask;
use super::ssmode::{camera_panoramas, locate_weights, SsmodeEstimator};
use super::{DepthEstimate, DepthEstimator, EstimatorError};
use candle_core::Tensor;
use mode360_core::frame::RgbImage;
use mode360_core::geometry::panorama::{CameraPanorama, RigRemap};
use mode360_core::geometry::{
    resample_erp, AlignedRange, ErpGrid, ErpRotation, PairSide, PairView, PixelCoord, Rig,
};
use mode360_model::model::readout::NEAR_MODE_OFF;
use mode360_model::model::{
    load_fusion_weights, ComputeDevice, Fusion, ModelError, ReadoutOverrides,
};

mod fusion;
mod pairs;

use fusion::{blend, consensus, most_confident};
pub use fusion::{
    fusion_tensors, fusion_weights_path, PairFusion, AGREEMENT_RATIO, BUILTIN_FUSION_WEIGHTS,
    CONSENSUS_FUSION, DEFAULT_FUSION_WEIGHTS_PATH, NO_FUSION,
};
use pairs::{camera_names, pair_name};
pub use pairs::{PairChoice, PAIR_SEPARATOR};

/// The estimator's name on the command line and in reports.
pub const PSMODE_NAME: &str = "psmode";

/// Stage 1's input width by default (`--pair-width`, the node's `pair_width`): the pairs are
/// matched at 512 wherever the output is at least that wide. The network was trained at 256;
/// at 512 held-out streets read 1.5 points more and cluttered streets 6.4 more, with more
/// obstacles kept, for about three times the time (models/README.md).
pub const DEFAULT_PAIR_WIDTH: usize = 512;

/// A pair width that keeps stage 1 at the width its network was trained at.
pub const TRAINED_PAIR_WIDTH: usize = 0;

/// Stage 1's result on one grid: every pair's range in the output frame, and the reference
/// camera's panorama turned into the output frame (the fusion network's RGB input).
#[derive(Clone, Debug)]
pub struct PairwiseEstimate {
    pub grid: ErpGrid,
    pub aligned: Vec<AlignedRange>,
    /// Per pair (as `aligned`), its parallax on `grid` ([`PairView::parallax_on`]); empty
    /// unless the fusion's inputs were asked for on `grid`.
    pub parallax_m: Vec<Arc<[f32]>>,
    /// Row-major RGB in [0, 1], interleaved, on `grid`.
    pub reference_rgb: Vec<f32>,
}

/// A pair's two cameras' masks in the pair frame, left then right.
type PairMasks = [Option<LensMask>; 2];

/// One pair's stage 1: its view, its network (weights shared with the others), its panorama
/// rotations (built for the panoramas' grid) and the per-rig tables it keeps.
struct PairStage {
    view: PairView,
    stage1: SsmodeEstimator,
    rotations: Option<(ErpGrid, [ErpRotation; 2])>,
    /// The pair's parallax on a grid ([`PairView::parallax_on`]): fixed per rig.
    parallax: Option<(ErpGrid, Arc<[f32]>)>,
    /// The two cameras' masks in the pair frame ([`PsmodeEstimator::pair_masks`]) and the lens
    /// masks they were built from.
    masks: Option<(Vec<Option<LensMask>>, PairMasks)>,
}

impl PairStage {
    /// The pair's parallax on `grid`, built once per rig and grid.
    fn parallax(&mut self, grid: ErpGrid, rig_from_output: &Isometry3<f64>) -> Arc<[f32]> {
        match &self.parallax {
            Some((g, p)) if *g == grid => p.clone(),
            _ => {
                let p: Arc<[f32]> = self.view.parallax_on(grid, rig_from_output).into();
                self.parallax = Some((grid, p.clone()));
                p
            }
        }
    }
}

/// The pairs of the last rig and stage-1 width seen.
struct Setup {
    rig: Rig,
    width: usize,
    stages: Vec<PairStage>,
}

/// PSMODE inference: stage 1 per pair, then fusion.
pub struct PsmodeEstimator {
    stage1_path: PathBuf,
    /// Stage 1 at the width its network was trained at.
    base: SsmodeEstimator,
    /// Stage 1 at the pair width, where that is wider than `base`'s; it runs when the output
    /// is at least that wide ([`Self::stage1_width`]).
    wide: Option<SsmodeEstimator>,
    pairs: PairChoice,
    fusion: PairFusion,
    setup: Option<Setup>,
    remap: Option<RigRemap>,
    lens_masks: Vec<Option<LensMask>>,
    /// The reference panorama into the output frame, for the last rig and grids seen.
    reference_rotation: Option<(ErpGrid, ErpGrid, ErpRotation)>,
}

impl PsmodeEstimator {
    /// Stage-1 weights from `path` (found as [`locate_weights`] says) on `device`, run at
    /// `pair_width` where the output is at least that wide and at their trained width
    /// otherwise ([`TRAINED_PAIR_WIDTH`] or a width at most the trained one: always the
    /// trained width), and the fusion network from the file `fusion` (`None`: the most
    /// confident pair per pixel, [`CONSENSUS_FUSION`]: the pairs' consensus;
    /// [`fusion_weights_path`] turns a setting into this). An error naming `pair_width` when
    /// the network cannot run at it.
    pub fn load_on(
        path: impl AsRef<Path>,
        fusion: Option<&Path>,
        device: ComputeDevice,
        pairs: PairChoice,
        pair_width: usize,
    ) -> Result<Self, EstimatorError> {
        // Stage 1 reads without the near mode: the pair choice and the fusion network were
        // tuned and trained on its readout without it.
        let readout = ReadoutOverrides {
            near_mode_probability: Some(NEAR_MODE_OFF),
            ..ReadoutOverrides::default()
        };
        let base = SsmodeEstimator::load_configured(path.as_ref(), device, None, &readout)?;
        let wide = if pair_width > base.config().width {
            let wide =
                SsmodeEstimator::load_configured(path.as_ref(), device, Some(pair_width), &readout)
                    .map_err(|e| EstimatorError::BadConfig {
                        field: "pair_width".to_string(),
                        problem: format!("PSMODE's stage 1 at {pair_width}: {e}"),
                    })?;
            Some(wide)
        } else {
            None
        };
        let mut est = Self::from_stage1(base, pairs);
        est.wide = wide;
        if fusion == Some(Path::new(CONSENSUS_FUSION)) {
            est.fusion = PairFusion::Consensus;
        } else if let Some(located) = fusion {
            if !located.exists() {
                return Err(EstimatorError::BadConfig {
                    field: "fusion_weights".to_string(),
                    problem: format!("PSMODE fusion weights file {} not found", located.display()),
                });
            }
            let (cfg, vb) = load_fusion_weights(located, est.base.device()).map_err(model_err)?;
            let net = Fusion::new(&cfg, vb).map_err(|e| {
                model_err(ModelError::Weights {
                    path: located.display().to_string(),
                    problem: format!("building the fusion network: {e}"),
                })
            })?;
            est.fusion = PairFusion::Network(Box::new(net));
        }
        Ok(est)
    }

    /// A PSMODE over an already loaded stage-1 network.
    pub fn from_stage1(base: SsmodeEstimator, pairs: PairChoice) -> Self {
        Self {
            stage1_path: locate_weights(base.weights_path()),
            base,
            wide: None,
            pairs,
            fusion: PairFusion::default(),
            setup: None,
            remap: None,
            lens_masks: Vec::new(),
            reference_rotation: None,
        }
    }

    pub fn stage1_weights_path(&self) -> &Path {
        &self.stage1_path
    }

    /// The width stage 1 runs at for an output `output_width` wide: the pair width where the
    /// output is at least that wide, else the network's trained width.
    pub fn stage1_width(&self, output_width: usize) -> usize {
        match &self.wide {
            Some(wide) if output_width >= wide.config().width => wide.config().width,
            _ => self.base.config().width,
        }
    }

    /// Stage 1's network at `width` (one of [`Self::stage1_width`]'s answers).
    fn stage1_at(&self, width: usize) -> &SsmodeEstimator {
        match &self.wide {
            Some(wide) if wide.config().width == width => wide,
            _ => &self.base,
        }
    }

    /// The camera pairs stage 1 matched on the last rig seen (0 before the first frame).
    pub fn pair_count(&self) -> usize {
        self.setup.as_ref().map_or(0, |s| s.stages.len())
    }

    /// The fusion network, when one is loaded.
    pub fn fusion(&self) -> Option<&Fusion> {
        match &self.fusion {
            PairFusion::Network(net) => Some(net),
            PairFusion::MostConfident | PairFusion::Consensus => None,
        }
    }

    /// Builds the pairs of `rig` when it changed: every chosen pair must exist, have two
    /// distinct centres and share some view; with [`PairChoice::All`] pairs that share no view
    /// are left out, and a rig none of whose pairs share one is an error.
    fn refresh_setup(&mut self, rig: &Rig, width: usize) -> Result<(), EstimatorError> {
        if self
            .setup
            .as_ref()
            .is_some_and(|s| &s.rig == rig && s.width == width)
        {
            return Ok(());
        }
        let probe = analysis_grid();
        let mut stages = Vec::new();
        for pair in self.pairs.resolve(rig)? {
            let name = pair_name(rig, pair);
            let view = PairView::new(rig, pair).map_err(|e| EstimatorError::BadConfig {
                field: "pairs".to_string(),
                problem: format!("pair {name}: {e}"),
            })?;
            let left = view.seen_in_pair(PairSide::Left, probe);
            let right = view.seen_in_pair(PairSide::Right, probe);
            let shared = left.iter().zip(&right).any(|(&l, &r)| l && r);
            if !shared {
                if self.pairs == PairChoice::All {
                    continue;
                }
                return Err(EstimatorError::BadConfig {
                    field: "pairs".to_string(),
                    problem: format!("cameras {name} share no view"),
                });
            }
            let network = self.stage1_at(width);
            let stage1 = SsmodeEstimator::from_model_on(
                network.model().clone(),
                self.stage1_path.clone(),
                network.device().clone(),
            )
            .with_occlusion_check(false);
            stages.push(PairStage {
                view,
                stage1,
                rotations: None,
                parallax: None,
                masks: None,
            });
        }
        if stages.is_empty() {
            return Err(EstimatorError::BadConfig {
                field: "rig".to_string(),
                problem: format!(
                    "PSMODE needs two cameras that share a view; none of [{}] do",
                    camera_names(rig)
                ),
            });
        }
        self.setup = Some(Setup {
            rig: rig.clone(),
            width,
            stages,
        });
        self.reference_rotation = None;
        Ok(())
    }

    /// The cameras' panoramas (fisheyes resampled at stage 1's width `net`) and their grid.
    fn panoramas<'a>(
        &mut self,
        rig: &Rig,
        images: &'a [RgbImage],
        net: ErpGrid,
    ) -> Result<(Vec<std::borrow::Cow<'a, RgbImage>>, ErpGrid), EstimatorError> {
        let panoramas = camera_panoramas(&mut self.remap, rig, images, net)?;
        // every panorama must be one ERP size so one rotation table serves each pair side
        let first = &panoramas[0];
        let grid = ErpGrid::new(first.width() as usize)
            .ok()
            .filter(|g| g.height() == first.height() as usize);
        for (cam, img) in panoramas.iter().enumerate() {
            let ok = grid.is_some_and(|g| {
                (img.width() as usize, img.height() as usize) == (g.width(), g.height())
            });
            if !ok {
                return Err(EstimatorError::BadImageSize {
                    camera: rig.cameras[cam].name.clone(),
                    width: img.width(),
                    height: img.height(),
                });
            }
        }
        let grid = grid.ok_or_else(|| EstimatorError::BadImageSize {
            camera: rig.cameras[0].name.clone(),
            width: first.width(),
            height: first.height(),
        })?;
        Ok((panoramas, grid))
    }

    /// Rebuilds each pair's masks when the lens masks changed since they were built.
    fn refresh_masks(&mut self, rig: &Rig) {
        let Some(setup) = &self.setup else {
            return;
        };
        let stale: Vec<bool> = setup
            .stages
            .iter()
            .map(|s| !s.masks.as_ref().is_some_and(|(m, _)| *m == self.lens_masks))
            .collect();
        if !stale.contains(&true) {
            return;
        }
        let built: Vec<Option<PairMasks>> = setup
            .stages
            .iter()
            .zip(&stale)
            .map(|(s, &stale)| stale.then(|| self.pair_masks(rig, &s.view)))
            .collect();
        let lens_masks = self.lens_masks.clone();
        if let Some(setup) = self.setup.as_mut() {
            for (stage, masks) in setup.stages.iter_mut().zip(built) {
                if let Some(masks) = masks {
                    stage.masks = Some((lens_masks.clone(), masks));
                }
            }
        }
    }

    /// The reference camera's panorama (on `src`) turned into the output frame on `grid`, RGB
    /// in [0, 1] (the output frame's own view when it is the reference camera's); the rotation
    /// table is kept for the rig and grids.
    fn reference_rgb(
        &mut self,
        rig: &Rig,
        panoramas: &[std::borrow::Cow<'_, RgbImage>],
        src: ErpGrid,
        grid: ErpGrid,
    ) -> Result<Vec<f32>, EstimatorError> {
        let stale = !self
            .reference_rotation
            .as_ref()
            .is_some_and(|(s, g, _)| (*s, *g) == (src, grid));
        if stale {
            let pano = CameraPanorama::new(&rig.cameras[rig.reference]);
            let pano_from_output =
                pano.rig_from_panorama.rotation.inverse() * rig.rig_from_output.rotation;
            let rotation = ErpRotation::new(src, grid, &pano_from_output.to_rotation_matrix());
            self.reference_rotation = Some((src, grid, rotation));
        }
        let Some((_, _, rotation)) = &self.reference_rotation else {
            return Ok(Vec::new());
        };
        let turned = rotation.apply_rgb(&panoramas[rig.reference]).map_err(|e| {
            EstimatorError::BadImage {
                camera: rig.cameras[rig.reference].name.clone(),
                problem: e.to_string(),
            }
        })?;
        Ok(turned
            .as_raw()
            .iter()
            .map(|&v| f32::from(v) / u8::MAX as f32)
            .collect())
    }

    /// The masks of a pair's two cameras in the pair frame: blocked where the camera's lens does
    /// not see (fisheyes) or its lens mask says blocked; `None` for a side with neither.
    fn pair_masks(&self, rig: &Rig, view: &PairView) -> PairMasks {
        let probe = analysis_grid();
        let pair = view.pair();
        [(PairSide::Left, pair.left), (PairSide::Right, pair.right)].map(|(side, cam)| {
            let mask = self.lens_masks.get(cam).and_then(Option::as_ref);
            let fisheye = !rig.cameras[cam].projection.is_equirectangular();
            if mask.is_none() && !fisheye {
                return None;
            }
            let seen = view.seen_in_pair(side, probe);
            let pano_from_pair = view.panorama_from_pair(side);
            let blocked = (0..probe.len())
                .map(|k| {
                    let p = PixelCoord {
                        u: (k % probe.width()) as f64,
                        v: (k / probe.width()) as f64,
                    };
                    let masked = mask.is_some_and(|m| {
                        let at = probe.pixel_from_dir(&(pano_from_pair * probe.dir_from_pixel(p)));
                        let u = (at.u.round() as i64).rem_euclid(probe.width() as i64) as usize;
                        let v = (at.v.round().max(0.0) as usize).min(probe.height() - 1);
                        m.cells()[v * probe.width() + u]
                    });
                    !seen[k] || masked
                })
                .collect();
            LensMask::from_cells(blocked)
        })
    }
}

impl PsmodeEstimator {
    /// Stage 1 on every pair of `rig`, each pair's range brought into the output frame on
    /// `grid`, with the fusion's inputs (parallax, reference panorama) there.
    pub fn pairwise(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        grid: ErpGrid,
    ) -> Result<PairwiseEstimate, EstimatorError> {
        let mut all = self.pairwise_on(rig, images, &[grid], Some(grid))?;
        all.pop().ok_or_else(|| EstimatorError::BadConfig {
            field: "rig".to_string(),
            problem: "PSMODE's stage 1 returned nothing".to_string(),
        })
    }

    /// Stage 1 once, each pair's range brought into the output frame on each of `grids`; the
    /// estimate on `fusion_grid` also gets the fusion's inputs (parallax, reference panorama).
    pub fn pairwise_on(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        grids: &[ErpGrid],
        fusion_grid: Option<ErpGrid>,
    ) -> Result<Vec<PairwiseEstimate>, EstimatorError> {
        if images.len() != rig.cameras.len() {
            return Err(EstimatorError::ImageCount {
                got: images.len(),
                expected: rig.cameras.len(),
            });
        }
        let widest = grids.iter().map(|g| g.width()).max().unwrap_or(0);
        let net = ErpGrid::new(self.stage1_width(widest))?;
        self.refresh_setup(rig, net.width())?;
        let (panoramas, src) = self.panoramas(rig, images, net)?;
        // stage 1 reads out at the finest grid asked for (or the network's), so that splatting
        // fills it
        let pair_out = grids
            .iter()
            .copied()
            .chain([net])
            .max_by_key(|g| g.width())
            .unwrap_or(net);
        self.refresh_masks(rig);
        let mut out: Vec<PairwiseEstimate> = grids
            .iter()
            .map(|&grid| {
                let reference_rgb = match fusion_grid {
                    Some(g) if g == grid => self.reference_rgb(rig, &panoramas, src, grid)?,
                    _ => Vec::new(),
                };
                Ok(PairwiseEstimate {
                    grid,
                    aligned: Vec::new(),
                    parallax_m: Vec::new(),
                    reference_rgb,
                })
            })
            .collect::<Result<_, EstimatorError>>()?;
        let Some(setup) = self.setup.as_mut() else {
            return Err(EstimatorError::BadConfig {
                field: "rig".to_string(),
                problem: "PSMODE's pairs were not built".to_string(),
            });
        };
        for stage in setup.stages.iter_mut() {
            if !stage.rotations.as_ref().is_some_and(|(g, _)| *g == src) {
                let rot = |side| stage.view.rotation_into_pair(side, src, net);
                stage.rotations = Some((src, [rot(PairSide::Left), rot(PairSide::Right)]));
            }
            let Some((_, rotations)) = &stage.rotations else {
                continue;
            };
            let pair = stage.view.pair();
            let turn = |rot: &ErpRotation, cam: usize| {
                rot.apply_rgb(&panoramas[cam])
                    .map_err(|e| EstimatorError::BadImage {
                        camera: rig.cameras[cam].name.clone(),
                        problem: e.to_string(),
                    })
            };
            let pair_images = [
                turn(&rotations[0], pair.left)?,
                turn(&rotations[1], pair.right)?,
            ];
            if let Some((_, masks)) = &stage.masks {
                stage.stage1.set_lens_masks(masks);
            }
            let est = stage
                .stage1
                .estimate(stage.view.pair_rig(), &pair_images, pair_out)?;
            for pw in &mut out {
                if fusion_grid == Some(pw.grid) {
                    pw.parallax_m
                        .push(stage.parallax(pw.grid, &rig.rig_from_output));
                }
                pw.aligned.push(stage.view.align(
                    pair_out,
                    &est.range_m.data,
                    &est.confidence.data,
                    &rig.rig_from_output,
                    pw.grid,
                )?);
            }
        }
        Ok(out)
    }
}

fn model_err(e: impl Into<ModelError>) -> EstimatorError {
    EstimatorError::Model(e.into())
}

impl DepthEstimator for PsmodeEstimator {
    fn name(&self) -> &str {
        PSMODE_NAME
    }

    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        // the network's weights are shared by the clone
        let fusion = self.fusion.clone();
        match fusion {
            PairFusion::MostConfident | PairFusion::Consensus => {
                let pairwise = self.pairwise_on(rig, images, &[output], None)?;
                let pairwise = pairwise.first().ok_or_else(|| EstimatorError::BadConfig {
                    field: "rig".to_string(),
                    problem: "PSMODE's stage 1 returned nothing".to_string(),
                })?;
                let (range, conf) = if matches!(fusion, PairFusion::Consensus) {
                    let max_range_m = self.base.config().max_depth_m as f32;
                    consensus(&pairwise.aligned, output.len(), max_range_m)
                } else {
                    most_confident(&pairwise.aligned, output.len())
                };
                Ok(DepthEstimate::on_grid(output, range, conf))
            }
            PairFusion::Network(net) => {
                // the network runs on its grid; its correction of the most confident pair is
                // added to that pair's index on the output grid (or its pair weights blend the
                // pairs' ranges there), which keeps the splat's detail
                let cfg = net.config().clone();
                // a select head runs on the output's grid where it can (its pair weights then
                // need no resampling), a correction head on its own
                let fgrid = if cfg.runs_on(output.width()) {
                    output
                } else {
                    ErpGrid::new(cfg.width)?
                };
                let grids = if output == fgrid {
                    vec![fgrid]
                } else {
                    vec![fgrid, output]
                };
                let mut pw = self.pairwise_on(rig, images, &grids, Some(fgrid))?;
                let on_output = pw.pop().ok_or_else(|| EstimatorError::BadConfig {
                    field: "rig".to_string(),
                    problem: "PSMODE's stage 1 returned nothing".to_string(),
                })?;
                let on_net = pw.pop().unwrap_or_else(|| on_output.clone());
                let device = self.base.device().clone();
                let (pairs, base, rgb) = fusion_tensors(&cfg, &on_net, &device)?;
                let out = net.forward(&pairs, &base, &rgb).map_err(model_err)?;
                let to_vec = |t: candle_core::Result<Tensor>| -> Result<Vec<f32>, EstimatorError> {
                    t.and_then(|t| t.flatten_all()?.to_vec1::<f32>())
                        .map_err(model_err)
                };
                let conf = resample_erp(&to_vec(net.confidence(&out))?, 1, fgrid, output);
                if let Some(weights) = &out.pair_weights {
                    // (1, P, H, W) -> (H, W, P) on the network's grid, then on the output's
                    let p = on_output.aligned.len();
                    let weights = to_vec(weights.permute((0, 2, 3, 1)))?;
                    let weights = resample_erp(&weights, p, fgrid, output);
                    let max_range_m = cfg.max_depth_m as f32;
                    let range = blend(&on_output.aligned, &weights, output.len(), max_range_m);
                    return Ok(DepthEstimate::on_grid(output, range, conf));
                }
                // (H, W) on the network's grid: the correction of the base index
                let delta = to_vec(
                    out.index
                        .clamp(0.0, 1.0)
                        .and_then(|i| i - base.narrow(3, 0, 1)?.squeeze(3)?),
                )?;
                let delta = resample_erp(&delta, 1, fgrid, output);
                let (base_range, _) = most_confident(&on_output.aligned, output.len());
                let range = base_range
                    .iter()
                    .zip(&delta)
                    .map(|(&r, &d)| {
                        let t = if r.is_finite() && r > 0.0 {
                            cfg.index_of_range(f64::from(r))
                        } else {
                            0.0
                        };
                        cfg.range_of_index((t + f64::from(d)).clamp(0.0, 1.0)) as f32
                    })
                    .collect();
                Ok(DepthEstimate::on_grid(output, range, conf))
            }
        }
    }

    fn set_lens_masks(&mut self, masks: &[Option<LensMask>]) {
        self.lens_masks = masks.to_vec();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_parse_and_name_what_is_wrong() {
        assert_eq!(PairChoice::parse("all").unwrap(), PairChoice::All);
        assert_eq!(PairChoice::parse("").unwrap(), PairChoice::All);
        assert_eq!(
            PairChoice::parse("front-back, left-right").unwrap(),
            PairChoice::Named(vec![
                ("front".into(), "back".into()),
                ("left".into(), "right".into())
            ])
        );
        for text in ["all", "front-back,left-right"] {
            assert_eq!(PairChoice::parse(text).unwrap().to_string(), text);
        }
        let e = PairChoice::parse("front").unwrap_err().to_string();
        assert!(e.contains("'front'") && e.contains("pairs"), "{e}");
        let e = PairChoice::parse("front-front").unwrap_err().to_string();
        assert!(e.contains("two different cameras"), "{e}");
    }
}
