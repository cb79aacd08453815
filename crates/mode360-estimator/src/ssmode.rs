//! The SSMODE network as a [`DepthEstimator`]: loads a weights file, resizes the panoramas to
//! the network's width (bilinear, longitude wraps; fisheye images are first resampled into
//! panoramas of their own frame, [`RigRemap`], and the sweep aggregates only the cameras that
//! see each point; confidence is scaled by the share of spheres that two cameras see), runs the
//! forward pass on the CPU or a CUDA GPU ([`ComputeDevice`]), cleans the range's edges with a
//! confidence-weighted median ([`super::edge_refine`], where the reference image is the output
//! frame's) and resizes the range back to the requested output grid (guided by the reference
//! image where the output is finer, [`super::guided_upsample`]). Sweep tables are cached per rig.

use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};

use super::edge_refine::{self, weighted_median_refine, EdgeRefineParams};
use super::guided_upsample::{grey_on_grid, guided_upsample};
use super::lens_mask::LensMask;
use super::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360_core::frame::RgbImage;
use mode360_core::geometry::occlusion::unoccluded_views;
use mode360_core::geometry::panorama::RigRemap;
pub use mode360_core::geometry::resample_erp;
use mode360_core::geometry::{ErpGrid, Rig};
use mode360_core::shipped::{self, BuiltinFile};
use mode360_model::model::{
    input_tensor, load_weights_and_readout, ComputeDevice, ModelError, ReadoutOverrides, Ssmode,
    SsmodeConfig, SweepSampling,
};

/// The estimator's name on the command line and in reports.
pub const SSMODE_NAME: &str = "ssmode";

/// Weights loaded by `by_name("ssmode")` and by an `EstimatorSpec` without weights, found as
/// [`mode360_core::shipped`] says (the working directory, the data directory, beside the
/// binary, else the copy built in): the `parallax_zncc_log_fine` preset (the ZNCC channel,
/// log-depth hypotheses and the fine head that keeps thin and near obstacles,
/// models/README.md).
pub const DEFAULT_WEIGHTS_PATH: &str = "models/ssmode_parallax_zncc_log_fine.safetensors";

/// The default before the fine head (`parallax_zncc_log`), still shipped: about 100 ms a
/// frame faster at 512 on a 2-core CPU, for fewer thin and near obstacles (models/README.md).
pub const PARALLAX_ZNCC_LOG_WEIGHTS_PATH: &str = "models/ssmode_parallax_zncc_log.safetensors";

/// The earlier `parallax` weights (variance-only volume, hypotheses uniform in inverse depth),
/// still shipped for comparison.
pub const PARALLAX_WEIGHTS_PATH: &str = "models/ssmode_parallax.safetensors";

/// The earlier `compact` weights, still shipped for comparison: accurate on the procedural
/// streets, but read from one panorama's look (geometry share about 3 points, models/README.md).
pub const COMPACT_WEIGHTS_PATH: &str = "models/ssmode_compact.safetensors";

/// PSMODE's stage 1 by default: the default weights fine-tuned on camera pairs in their GEER
/// frame (`train --camera-pairs`, 3,100 steps; models/README.md, the PSMODE card).
pub const PSMODE_STAGE1_WEIGHTS_PATH: &str = "models/psmode_stage1.safetensors";

/// The shipped weights files, built into the binary so that an installed or copied binary
/// runs without its source tree.
pub const BUILTIN_WEIGHTS: &[BuiltinFile] = &[
    BuiltinFile {
        relative: DEFAULT_WEIGHTS_PATH,
        bytes: include_bytes!("../../../models/ssmode_parallax_zncc_log_fine.safetensors"),
    },
    BuiltinFile {
        relative: PARALLAX_ZNCC_LOG_WEIGHTS_PATH,
        bytes: include_bytes!("../../../models/ssmode_parallax_zncc_log.safetensors"),
    },
    BuiltinFile {
        relative: PARALLAX_WEIGHTS_PATH,
        bytes: include_bytes!("../../../models/ssmode_parallax.safetensors"),
    },
    BuiltinFile {
        relative: COMPACT_WEIGHTS_PATH,
        bytes: include_bytes!("../../../models/ssmode_compact.safetensors"),
    },
    BuiltinFile {
        relative: PSMODE_STAGE1_WEIGHTS_PATH,
        bytes: include_bytes!("../../../models/psmode_stage1.safetensors"),
    },
];

/// [`DEFAULT_WEIGHTS_PATH`], located ([`locate_weights`]).
pub fn default_weights_path() -> PathBuf {
    locate_weights(Path::new(DEFAULT_WEIGHTS_PATH))
}

/// Every shipped weights file, default first, located ([`locate_weights`]).
pub fn shipped_weights_paths() -> Vec<PathBuf> {
    BUILTIN_WEIGHTS
        .iter()
        .map(|f| locate_weights(Path::new(f.relative)))
        .collect()
}

/// A weights path as the user gave it, or a shipped file's relative path, looked up as
/// [`mode360_core::shipped`] says: as given, in the data directory, beside the binary, else the
/// shipped copy built in.
pub fn locate_weights(path: &Path) -> PathBuf {
    shipped::locate_path(path, BUILTIN_WEIGHTS)
}

/// SSMODE inference on the CPU or a CUDA GPU.
pub struct SsmodeEstimator {
    weights_path: PathBuf,
    model: Ssmode,
    device: Device,
    /// Sampling tables of the last rig seen.
    cached: Option<(Rig, SweepSampling)>,
    /// Fisheye images into panoramas at the network's width, for the last rig seen.
    remap: Option<RigRemap>,
    /// Blocked parts of the cameras' views ([`DepthEstimator::set_lens_masks`]).
    lens_masks: Vec<Option<LensMask>>,
    /// The cached tables with `lens_masks` applied, and the masks they were built with.
    masked: Option<(Vec<Option<LensMask>>, SweepSampling)>,
    /// Whether the confidence is capped at [`HIDDEN_CONFIDENCE`] where fewer than two cameras
    /// see the estimated point ([`Self::with_occlusion_check`]).
    occlusion_check: bool,
}

/// Highest confidence of a pixel whose estimated point fewer than two cameras see, because a
/// nearer surface of the same estimate stands in the way for the others
/// (`geometry::occlusion`): nothing was matched there, so its range is the network's guess
/// (issue 38: the background hidden behind a near obstacle). With the node's `min_confidence`
/// above it, such pixels are NaN.
pub const HIDDEN_CONFIDENCE: f32 = 0.1;
/// An output pixel is hidden where at least this share of the network cells it is resampled
/// from are.
pub const HIDDEN_SHARE: f32 = 0.5;

fn model_err(e: impl Into<ModelError>) -> EstimatorError {
    EstimatorError::Model(e.into())
}

impl SsmodeEstimator {
    /// Loads weights (with their config) from `path`, to run on the CPU.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, EstimatorError> {
        Self::load_on(path, ComputeDevice::Cpu)
    }

    /// Loads weights (with their config) from `path` onto `device`; an error naming CUDA and
    /// what was found when a CUDA device cannot be opened.
    pub fn load_on(path: impl AsRef<Path>, device: ComputeDevice) -> Result<Self, EstimatorError> {
        Self::load_configured(path, device, None, &ReadoutOverrides::default())
    }

    /// [`Self::load_on`], the network run at input width `width` instead of the width it was
    /// trained at (the far field's threshold kept at the same angle,
    /// [`SsmodeConfig::at_width`]); an error naming the width when the network cannot run
    /// at it.
    pub fn load_at_width(
        path: impl AsRef<Path>,
        device: ComputeDevice,
        width: usize,
    ) -> Result<Self, EstimatorError> {
        Self::load_configured(path, device, Some(width), &ReadoutOverrides::default())
    }

    /// [`Self::load_on`] at input width `width` when given ([`Self::load_at_width`]), with
    /// the readout the file records (else the default, [`Readout::recorded`]) overridden by
    /// `readout` where it says; its far field counted in cells of the width the network was
    /// trained at. An error naming the setting when one is out of range.
    pub fn load_configured(
        path: impl AsRef<Path>,
        device: ComputeDevice,
        width: Option<usize>,
        readout: &ReadoutOverrides,
    ) -> Result<Self, EstimatorError> {
        let located = locate_weights(path.as_ref());
        let path = located.as_path();
        if !path.exists() {
            return Err(EstimatorError::BadConfig {
                field: "weights".to_string(),
                problem: format!(
                    "SSMODE weights file {} not found (train one with the training command or pass another path)",
                    path.display()
                ),
            });
        }
        let device = device.open().map_err(model_err)?;
        let (mut cfg, recorded, vb) = load_weights_and_readout(path, &device).map_err(model_err)?;
        let mut readout = readout.apply(recorded).map_err(model_err)?;
        if let Some(width) = width {
            readout = readout.at_width(cfg.width, width);
            cfg = cfg.at_width(width).map_err(model_err)?;
        }
        let model = Ssmode::new(&cfg, vb).map_err(|e| {
            model_err(ModelError::Weights {
                path: path.display().to_string(),
                problem: format!("building the network: {e}"),
            })
        })?;
        let model = model.with_readout(readout).map_err(model_err)?;
        Ok(Self {
            weights_path: path.to_path_buf(),
            model,
            device,
            cached: None,
            remap: None,
            lens_masks: Vec::new(),
            masked: None,
            occlusion_check: true,
        })
    }

    /// Wraps an already built network on the CPU; `label` names its weights in messages.
    pub fn from_model(model: Ssmode, label: impl Into<PathBuf>) -> Self {
        Self {
            weights_path: label.into(),
            model,
            device: Device::Cpu,
            cached: None,
            remap: None,
            lens_masks: Vec::new(),
            masked: None,
            occlusion_check: true,
        }
    }

    /// Whether the confidence is capped at [`HIDDEN_CONFIDENCE`] where fewer than two cameras
    /// see the estimated point (on by default; PSMODE's first stage turns it off, as its fusion
    /// and pair choice were tuned on the confidence without it).
    pub fn with_occlusion_check(mut self, on: bool) -> Self {
        self.occlusion_check = on;
        self
    }

    /// Wraps an already built network whose weights live on `device`.
    pub fn from_model_on(model: Ssmode, label: impl Into<PathBuf>, device: Device) -> Self {
        let mut estimator = Self::from_model(model, label);
        estimator.device = device;
        estimator
    }

    /// The network (its weights are shared by clones).
    pub fn model(&self) -> &Ssmode {
        &self.model
    }

    /// Where the network's weights live.
    pub fn device(&self) -> &Device {
        &self.device
    }

    pub fn config(&self) -> &SsmodeConfig {
        self.model.config()
    }

    pub fn weights_path(&self) -> &Path {
        &self.weights_path
    }

    /// Rebuilds the cached sampling tables when the rig changed; returns them.
    fn refresh_sampling(&mut self, rig: &Rig) -> Result<(), EstimatorError> {
        let stale = self.cached.as_ref().is_none_or(|(r, _)| r != rig);
        if stale {
            let sampling =
                SweepSampling::with_readout(rig, self.model.config(), self.model.readout())
                    .map_err(|e| {
                        model_err(ModelError::Weights {
                            path: self.weights_path.display().to_string(),
                            problem: format!(
                                "the '{}' network cannot serve the rig of cameras [{}]: {e}",
                                self.model.config().name,
                                rig.cameras
                                    .iter()
                                    .map(|c| c.name.as_str())
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            ),
                        })
                    })?;
            self.cached = Some((rig.clone(), sampling));
            self.masked = None;
        }
        Ok(())
    }

    /// Whether the lens masks apply to the cached tables (set for this many cameras).
    fn masks_apply(&self) -> bool {
        self.cached.as_ref().is_some_and(|(_, base)| {
            self.lens_masks.len() == base.camera_count()
                && self.lens_masks.iter().any(Option::is_some)
        })
    }

    /// Builds the masked tables when the masks apply and changed.
    fn refresh_masked(&mut self) {
        if !self.masks_apply()
            || self
                .masked
                .as_ref()
                .is_some_and(|(m, _)| *m == self.lens_masks)
        {
            return;
        }
        if let Some((_, base)) = &self.cached {
            let grid = base.geometry().output();
            let blocked: Vec<Option<Vec<bool>>> = self
                .lens_masks
                .iter()
                .map(|m| m.as_ref().map(|m| m.blocked_on(grid)))
                .collect();
            self.masked = Some((self.lens_masks.clone(), base.with_blocked(&blocked)));
        }
    }

    /// The cached tables, masked when the masks apply ([`Self::refresh_masked`] first).
    fn sampling(&self) -> Option<&SweepSampling> {
        match &self.masked {
            Some((_, masked)) if self.masks_apply() => Some(masked),
            _ => self.cached.as_ref().map(|(_, s)| s),
        }
    }
}

/// Each camera's image as a panorama of its own frame: fisheye images resampled into `grid`
/// (with `remap`, rebuilt when the rig or grid changed), ERP images as they are; an image of
/// the wrong size is an error naming the camera.
pub(super) fn camera_panoramas<'a>(
    remap: &mut Option<RigRemap>,
    rig: &Rig,
    images: &'a [RgbImage],
    grid: ErpGrid,
) -> Result<Vec<std::borrow::Cow<'a, RgbImage>>, EstimatorError> {
    if !remap.as_ref().is_some_and(|r| r.serves(rig, grid)) {
        *remap = Some(RigRemap::new(rig, grid));
    }
    match remap {
        Some(remap) => remap
            .panoramas(images)
            .map_err(|(camera, e)| EstimatorError::BadImage {
                camera,
                problem: e.to_string(),
            }),
        None => Ok(images.iter().map(std::borrow::Cow::Borrowed).collect()),
    }
}

/// Rotation angle (rad) and translation (m) below which the output frame is the reference
/// camera's.
const SAME_FRAME_TOLERANCE: f64 = 1e-9;

/// The reference camera's image when the output frame is that camera's own and the image is
/// ERP (so a network cell and an image pixel look the same way); `None` otherwise.
fn reference_in_output_frame<'a>(rig: &Rig, images: &'a [RgbImage]) -> Option<&'a RgbImage> {
    let reference = rig.cameras.get(rig.reference)?;
    let offset = reference.rig_from_cam.inverse() * rig.rig_from_output;
    let same_frame = offset.translation.vector.norm() < SAME_FRAME_TOLERANCE
        && offset.rotation.angle() < SAME_FRAME_TOLERANCE;
    if !same_frame || !reference.projection.is_equirectangular() {
        return None;
    }
    images.get(rig.reference)
}

/// The guides of [`guided_upsample`] (the reference camera's grey image on the network's and on
/// the output grid), when the output is finer than the network and the output frame is an ERP
/// reference camera's own; `None` otherwise (plain bilinear upsampling).
fn guide_images(
    rig: &Rig,
    images: &[RgbImage],
    net: ErpGrid,
    output: ErpGrid,
) -> Option<(Vec<f32>, Vec<f32>)> {
    if output.width() <= net.width() {
        return None;
    }
    let image = reference_in_output_frame(rig, images)?;
    Some((grey_on_grid(image, net)?, grey_on_grid(image, output)?))
}

impl DepthEstimator for SsmodeEstimator {
    fn name(&self) -> &str {
        SSMODE_NAME
    }

    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        if images.len() != rig.cameras.len() {
            return Err(EstimatorError::ImageCount {
                got: images.len(),
                expected: rig.cameras.len(),
            });
        }
        let cfg = self.model.config().clone();
        let net_grid = ErpGrid::new(cfg.width)?;
        let panoramas = camera_panoramas(&mut self.remap, rig, images, net_grid)?;
        let mut tensors = Vec::with_capacity(images.len());
        for (cam, img) in panoramas.iter().enumerate() {
            let t = input_tensor(img, cfg.width, &self.device).map_err(|e| match e {
                ModelError::BadImage { width, height } => EstimatorError::BadImageSize {
                    camera: rig.cameras[cam].name.clone(),
                    width,
                    height,
                },
                other => model_err(other),
            })?;
            tensors.push(t);
        }
        self.refresh_sampling(rig)?;
        self.refresh_masked();
        let sampling = match self.sampling() {
            Some(s) => s,
            None => {
                return Err(model_err(ModelError::BadConfig {
                    field: "rig".to_string(),
                    problem: "sweep sampling cache is empty".to_string(),
                }))
            }
        };
        let out = self
            .model
            .forward(&tensors, sampling, false)
            .map_err(model_err)?;
        let final_range = out.stages.last().ok_or_else(|| {
            model_err(ModelError::BadConfig {
                field: "hourglasses".to_string(),
                problem: "the network produced no stage".to_string(),
            })
        })?;
        let to_vec = |t: &Tensor| -> Result<Vec<f32>, EstimatorError> {
            t.flatten_all()
                .and_then(|f| f.to_vec1::<f32>())
                .map_err(model_err)
        };
        let mut range = to_vec(final_range)?;
        let refine_radius_cells = self.model.readout().refine_radius_cells;
        if refine_radius_cells > 0 {
            if let Some(rgb) = reference_in_output_frame(rig, images)
                .and_then(|image| edge_refine::rgb_on_grid(image, net_grid))
            {
                let params = EdgeRefineParams::with_radius(refine_radius_cells);
                let conf_net = to_vec(&out.confidence)?;
                range = weighted_median_refine(&range, &conf_net, &rgb, net_grid, &params);
            }
        }
        // 1 where a nearer surface of this estimate hides the point from all cameras but one
        // (on the network's grid, a quarter of the output's pixels at 512: 5.6 ms a frame on
        // the idle 2-core machine, 21 ms on the 512 grid; not yet measured in `bench-node`).
        let hidden = if self.occlusion_check {
            let views = unoccluded_views(rig, net_grid, &range)?;
            let flags: Vec<f32> = views
                .iter()
                .zip(&range)
                .map(|(&n, r)| f32::from(u8::from(r.is_finite() && *r > 0.0 && n < 2)))
                .collect();
            Some(resample_erp(&flags, 1, net_grid, output))
        } else {
            None
        };
        let range = match guide_images(rig, images, net_grid, output) {
            Some((guide_net, guide_out)) => {
                guided_upsample(&range, &guide_net, net_grid, &guide_out, output)
            }
            None => resample_erp(&range, 1, net_grid, output),
        };
        let mut conf = resample_erp(&to_vec(&out.confidence)?, 1, net_grid, output);
        // Where fewer than two cameras see a direction at any range, the estimate is a guess.
        if let Some(coverage) = sampling.coverage() {
            let coverage = resample_erp(coverage, 1, sampling.geometry().output(), output);
            for (c, k) in conf.iter_mut().zip(coverage) {
                *c *= k.clamp(0.0, 1.0);
            }
        }
        if let Some(hidden) = hidden {
            for (c, h) in conf.iter_mut().zip(hidden) {
                if h >= HIDDEN_SHARE {
                    *c = c.min(HIDDEN_CONFIDENCE);
                }
            }
        }
        Ok(DepthEstimate::on_grid(output, range, conf))
    }

    fn set_lens_masks(&mut self, masks: &[Option<LensMask>]) {
        if self.lens_masks != masks {
            self.lens_masks = masks.to_vec();
        }
    }
}
