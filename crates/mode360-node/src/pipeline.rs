//! The node's processing core, free of DDS: one synchronized group of decoded panoramas in,
//! the published messages (`depth`, `points`, `confidence`) out. The live node's inference
//! worker (`super::worker`) and offline replay (`mode360 replay`) both run this.
//!
//! Depth values follow REP 117: a finite range is a measurement; `+Inf` is "nothing within
//! range" (sky, or a range at or beyond `max_depth_m`); `NaN` is "no valid measurement"
//! (the estimator had none, or its confidence is below `min_confidence`).
//! [`FarValue::MaxDepth`] writes `max_depth_m` instead of `+Inf` for consumers that expect
//! the older convention.
//!
//! Point cloud: for every output pixel `(u, v)` with a finite range `rho < max_depth_m`,
//! `p_out = rho * dir(u, v)` (ERP direction of the design notes) in the output frame. Its colour
//! comes from the reference camera (or the first camera present): `p_cam = cam_from_output *
//! p_out`, projected with that camera's model (ERP or fisheye), nearest pixel; where a fisheye
//! reference does not see the point, the next present camera that does ([`points`]). Images
//! must fit their cameras: panoramas one 2:1 size, fisheye images their `image_size`. The
//! colour is packed as
//! `0x00RRGGBB` and those bits are stored as a float32 field `rgb` (the rviz / Foxglove
//! convention).

use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::rig::MIN_CAMERAS;
use mode360_core::geometry::{ErpGrid, GeometryError, Rig, RigError};
use mode360_estimator::{DepthEstimator, EstimatorError};
use mode360_health::calibration_drift::{CalibrationDrift, CalibrationDriftMonitor};
use mode360_health::lens_guard::LensGuard;
use mode360_health::lens_health::LensHealth;
use mode360_health::lens_window::LENS_WINDOW_FRAMES;
use mode360_io::msgs::compressed_depth::{
    encode_compressed_depth, CompressedDepthError, DEFAULT_DEPTH_QUANTIZATION,
};
use mode360_io::msgs::image::image_msg_from_float;
use mode360_io::msgs::{CompressedImage, Header, Image, PointCloud2};
use std::time::{Duration, Instant};

use super::outputs::{Output, OutputData, OutputMessage};

mod points;
pub use points::*;

/// What `depth` holds where nothing is within range (sky, or at or beyond `max_depth_m`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FarValue {
    /// `+Inf`, as REP 117 asks.
    #[default]
    Inf,
    /// `max_depth_m` (the node's convention before REP 117).
    MaxDepth,
}

impl FarValue {
    /// Parameter spellings, for `depth_far_value`.
    pub const NAMES: [&'static str; 2] = ["inf", "max_depth"];

    /// Its parameter spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Inf => Self::NAMES[0],
            Self::MaxDepth => Self::NAMES[1],
        }
    }

    /// From its parameter spelling.
    pub fn parse(s: &str) -> Option<Self> {
        [Self::Inf, Self::MaxDepth]
            .into_iter()
            .find(|f| f.as_str() == s)
    }
}

/// Which optional outputs to build for a group (the node skips those nobody subscribes to).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutputRequest {
    pub points: bool,
    pub compressed_depth: bool,
}

impl OutputRequest {
    /// Every output (replay).
    pub const ALL: Self = Self {
        points: true,
        compressed_depth: true,
    };
}

/// Settings of the pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct PipelineParams {
    /// Width of the output ERP image (height is half of it).
    pub output_width: usize,
    /// Ranges at or beyond this (sky) are out of range: [`FarValue`] in `depth`, no point.
    pub max_depth_m: f32,
    /// What out-of-range pixels hold in `depth`.
    pub far_value: FarValue,
    /// Pixels whose confidence is below this are NaN in `depth` and have no point (0: keep
    /// every estimate).
    pub min_confidence: f32,
    /// `depth/compressedDepth`'s quantization `Q` (image_transport's `depth_quantization`).
    pub depth_quantization: f32,
    /// Run the lens check (lens masks, `blocked_fraction`) and the calibration drift check on
    /// complete groups; `false` skips both (their figures read n/a).
    pub rig_health_checks: bool,
}

impl Default for PipelineParams {
    fn default() -> Self {
        Self {
            output_width: 512,
            max_depth_m: mode360_core::geometry::DEFAULT_MAX_DEPTH_M as f32,
            far_value: FarValue::Inf,
            min_confidence: 0.0,
            depth_quantization: DEFAULT_DEPTH_QUANTIZATION,
            rig_health_checks: true,
        }
    }
}

/// Applies REP 117 to `range` in place: below `min_confidence` NaN, at or beyond
/// `max_depth_m` (or +Inf) the far value; NaN and finite in-range values stay.
pub fn apply_rep117(range: &mut FloatImage, confidence: &FloatImage, params: &PipelineParams) {
    let far = match params.far_value {
        FarValue::Inf => f32::INFINITY,
        FarValue::MaxDepth => params.max_depth_m,
    };
    for (r, &c) in range.data.iter_mut().zip(&confidence.data) {
        if r.is_nan() || c < params.min_confidence {
            *r = f32::NAN;
        } else if *r >= params.max_depth_m {
            *r = far;
        }
    }
}

/// Why a group could not be processed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("group has {got} slots for a rig of {expected} cameras")]
    GroupSize { got: usize, expected: usize },
    #[error("only {present} cameras present in the group; at least {MIN_CAMERAS} are needed")]
    TooFewCameras { present: usize },
    #[error("the cameras' images do not fit their cameras ({sizes}): panoramas must share one 2:1 size, fisheye images must be their image_size")]
    SizeMismatch {
        /// Every camera of the group with its image size, e.g. `cam1 128x64, cam2 64x32`.
        sizes: String,
    },
    #[error("estimator: {0}")]
    Estimator(#[from] EstimatorError),
    #[error("rig: {0}")]
    Rig(#[from] RigError),
    #[error("output grid: {0}")]
    Geometry(#[from] GeometryError),
    #[error("depth/compressedDepth: {0}")]
    CompressedDepth(#[from] CompressedDepthError),
}

/// The messages published for one group.
#[derive(Clone, Debug)]
pub struct PipelineOutput {
    /// ERP range image, 32FC1, metres (REP 117: +Inf beyond range, NaN invalid).
    pub depth: Image,
    /// Valid, non-sky pixels as coloured points in the output frame (`None` when not asked
    /// for: nobody subscribes).
    pub points: Option<PointCloud2>,
    /// `depth` in image_transport's compressedDepth format (`None` when not asked for).
    pub compressed_depth: Option<CompressedImage>,
    /// Per-pixel confidence, 32FC1 in [0, 1].
    pub confidence: Image,
    /// Names of the rig cameras that were missing from the group.
    pub missing_cameras: Vec<String>,
    /// Each camera's lens health over the newest groups (rig order; checked on complete
    /// groups only, empty before the first).
    pub lens: Vec<LensHealth>,
    /// Each camera's calibration as the drift check sees it (rig order; checked every few
    /// complete groups, empty before the first check).
    pub calibration: Vec<CalibrationDrift>,
    /// Wall time of the estimator plus message building.
    pub latency: Duration,
}

impl PipelineOutput {
    /// Output `o`'s message of this group (`None`: not built, as points and compressed depth
    /// when nobody asked for them).
    pub fn message(&self, o: Output) -> Option<OutputMessage<'_>> {
        match o {
            Output::Depth => Some(OutputMessage::Image(&self.depth)),
            Output::CompressedDepth => self
                .compressed_depth
                .as_ref()
                .map(OutputMessage::CompressedImage),
            Output::Points => self.points.as_ref().map(OutputMessage::PointCloud),
            Output::Confidence => Some(OutputMessage::Image(&self.confidence)),
        }
    }

    /// Output `o`'s message moved out of this group for publishing (`None`: not built);
    /// depth and confidence leave an empty image behind.
    pub fn take_message(&mut self, o: Output) -> Option<OutputData> {
        match o {
            Output::Depth => Some(OutputData::Image(std::mem::take(&mut self.depth))),
            Output::CompressedDepth => self
                .compressed_depth
                .take()
                .map(OutputData::CompressedImage),
            Output::Points => self.points.take().map(OutputData::PointCloud),
            Output::Confidence => Some(OutputData::Image(std::mem::take(&mut self.confidence))),
        }
    }
}

/// Estimator plus message building for a fixed rig.
pub struct Pipeline {
    rig: Rig,
    estimator: Box<dyn DepthEstimator>,
    params: PipelineParams,
    grid: ErpGrid,
    /// The lens check, whose masks the estimator gets.
    lens: LensGuard,
    drift: CalibrationDriftMonitor,
    /// The last group's lens and drift checks when [`Self::process_deferred`] left them to
    /// [`Self::run_deferred_checks`].
    deferred: Option<DeferredChecks>,
    /// Per camera (rig order): whether it is being left out for its image size (warned once
    /// when that starts, told once when it ends).
    size_misfit: Vec<bool>,
}

/// What the rig health checks of one complete group read.
struct DeferredChecks {
    images: Vec<RgbImage>,
    /// The estimate before REP 117.
    range_m: FloatImage,
}

impl Pipeline {
    pub fn new(
        rig: Rig,
        estimator: Box<dyn DepthEstimator>,
        params: PipelineParams,
    ) -> Result<Self, PipelineError> {
        let grid = ErpGrid::new(params.output_width)?;
        let drift = CalibrationDriftMonitor::new(&rig)?;
        Ok(Self {
            drift,
            rig,
            estimator,
            params,
            grid,
            lens: LensGuard::new(LENS_WINDOW_FRAMES, true),
            deferred: None,
            size_misfit: Vec::new(),
        })
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    pub fn params(&self) -> &PipelineParams {
        &self.params
    }

    /// Replaces the settings (the output width must stay: the grid is built once).
    pub fn set_params(&mut self, params: PipelineParams) {
        debug_assert_eq!(params.output_width, self.params.output_width);
        self.params = params;
    }

    /// Runs the estimator on the cameras present in `group` (one slot per rig camera, rig
    /// order) and builds the output messages stamped `stamp_ns` in the rig's output frame.
    pub fn process(
        &mut self,
        group: Vec<Option<RgbImage>>,
        stamp_ns: u64,
    ) -> Result<PipelineOutput, PipelineError> {
        self.process_with(group, stamp_ns, OutputRequest::ALL)
    }

    /// [`Self::process`], building the optional outputs `want` asks for (the node skips those
    /// without a subscriber).
    pub fn process_with(
        &mut self,
        group: Vec<Option<RgbImage>>,
        stamp_ns: u64,
        want: OutputRequest,
    ) -> Result<PipelineOutput, PipelineError> {
        self.process_inner(group, stamp_ns, want, false)
    }

    /// [`Self::process_with`] for the live node: the lens and calibration drift checks of a
    /// complete group (but the first) are left to [`Self::run_deferred_checks`], which the node
    /// runs after publishing, so they stay off the latency path. The outputs are the same: the
    /// masks a check finds apply from the next group either way. The output's `lens` and
    /// `calibration` are then as of the previous group; [`Self::lens_health`] and
    /// [`Self::calibration_drift`] give them after the checks.
    pub fn process_deferred(
        &mut self,
        group: Vec<Option<RgbImage>>,
        stamp_ns: u64,
        want: OutputRequest,
    ) -> Result<PipelineOutput, PipelineError> {
        self.process_inner(group, stamp_ns, want, true)
    }

    /// Runs the checks [`Self::process_deferred`] left for its last group (nothing when none
    /// are pending).
    pub fn run_deferred_checks(&mut self) -> Result<(), PipelineError> {
        let Some(d) = self.deferred.take() else {
            return Ok(());
        };
        self.lens.check(&self.rig, &d.images, &d.range_m)?;
        self.drift.add(&d.images, &d.range_m, self.lens.masks())?;
        Ok(())
    }

    /// Each camera's lens health (rig order; empty with the checks off or before the first).
    pub fn lens_health(&self) -> Vec<LensHealth> {
        if self.params.rig_health_checks {
            self.lens.health()
        } else {
            Vec::new()
        }
    }

    /// Each camera's calibration as the drift check sees it (rig order; empty with the checks
    /// off or before the first check).
    pub fn calibration_drift(&self) -> Vec<CalibrationDrift> {
        if self.params.rig_health_checks {
            self.drift.drift()
        } else {
            Vec::new()
        }
    }

    fn process_inner(
        &mut self,
        group: Vec<Option<RgbImage>>,
        stamp_ns: u64,
        want: OutputRequest,
        defer: bool,
    ) -> Result<PipelineOutput, PipelineError> {
        // The checks of the previous group come first: its masks apply to this one.
        self.run_deferred_checks()?;
        let t0 = Instant::now();
        let UsableImages {
            present,
            images,
            missing_cameras,
        } = self.usable_images(group)?;
        let checked = self.params.rig_health_checks;
        // The estimate before REP 117 that a deferred check reads (with the images, moved in
        // once the point cloud is built).
        let mut deferred_range_m = None;
        let mut estimate = if !missing_cameras.is_empty() {
            let sub = self.rig.subset(&present)?;
            self.lens
                .estimate_partial(self.estimator.as_mut(), &sub, &images, self.grid)?
        } else if checked && defer && self.lens.has_checked() {
            let estimate = self.lens.estimate_masked(
                self.estimator.as_mut(),
                &self.rig,
                &images,
                self.grid,
            )?;
            deferred_range_m = Some(estimate.range_m.clone());
            estimate
        } else if checked {
            // The first group is checked at once: a blocked lens found there is masked in it.
            let estimate =
                self.lens
                    .estimate(self.estimator.as_mut(), &self.rig, &images, self.grid)?;
            self.drift
                .add(&images, &estimate.range_m, self.lens.masks())?;
            estimate
        } else {
            self.lens
                .estimate_partial(self.estimator.as_mut(), &self.rig, &images, self.grid)?
        };
        apply_rep117(&mut estimate.range_m, &estimate.confidence, &self.params);
        let header = Header::new(stamp_ns, self.rig.output_frame_id.clone());
        let points = if want.points {
            Some(self.coloured_points(header.clone(), &estimate.range_m, &present, &images)?)
        } else {
            None
        };
        let compressed_depth = if want.compressed_depth {
            Some(encode_compressed_depth(
                header.clone(),
                &estimate.range_m,
                self.params.depth_quantization,
                self.params.max_depth_m,
            )?)
        } else {
            None
        };
        if let Some(range_m) = deferred_range_m {
            self.deferred = Some(DeferredChecks { images, range_m });
        }
        Ok(PipelineOutput {
            depth: image_msg_from_float(header.clone(), &estimate.range_m),
            compressed_depth,
            points,
            confidence: image_msg_from_float(header, &estimate.confidence),
            missing_cameras,
            lens: self.lens_health(),
            calibration: self.calibration_drift(),
            latency: t0.elapsed(),
        })
    }
    /// The group's images that can be used, with their cameras' positions in the rig, and the
    /// names of the cameras left out: absent ones, and those whose image does not fit their
    /// camera while enough others do (as if they had sent nothing).
    fn usable_images(
        &mut self,
        group: Vec<Option<RgbImage>>,
    ) -> Result<UsableImages, PipelineError> {
        if group.len() != self.rig.cameras.len() {
            return Err(PipelineError::GroupSize {
                got: group.len(),
                expected: self.rig.cameras.len(),
            });
        }
        let mut present = Vec::new();
        let mut images: Vec<RgbImage> = Vec::new();
        let mut missing_cameras = Vec::new();
        for (i, slot) in group.into_iter().enumerate() {
            match slot {
                Some(img) => {
                    present.push(i);
                    images.push(img);
                }
                None => missing_cameras.push(self.rig.cameras[i].name.clone()),
            }
        }
        if present.len() < MIN_CAMERAS {
            return Err(PipelineError::TooFewCameras {
                present: present.len(),
            });
        }
        let misfits = self.misfits(&present, &images);
        let fits_left = misfits
            .as_ref()
            .is_some_and(|m| present.len() - m.len() >= MIN_CAMERAS);
        if !fits_left {
            // Name every camera: which one is "wrong" is not knowable from the sizes alone.
            let sizes = present
                .iter()
                .zip(&images)
                .map(|(&i, img)| {
                    format!(
                        "{} {}x{}",
                        self.rig.cameras[i].name,
                        img.width(),
                        img.height()
                    )
                })
                .collect::<Vec<_>>()
                .join(", ");
            return Err(PipelineError::SizeMismatch { sizes });
        }
        let misfits = misfits.unwrap_or_default();
        self.note_misfits(&present, &images, &misfits);
        // Left out: as if the camera had sent nothing in this group.
        for &k in misfits.iter().rev() {
            let i = present.remove(k);
            images.remove(k);
            missing_cameras.push(self.rig.cameras[i].name.clone());
        }
        Ok(UsableImages {
            present,
            images,
            missing_cameras,
        })
    }

    /// The estimate as a coloured cloud: colours from the reference camera when present (else
    /// the first present), then from the others where a fisheye lens does not see.
    fn coloured_points(
        &self,
        header: Header,
        range_m: &FloatImage,
        present: &[usize],
        images: &[RgbImage],
    ) -> Result<PointCloud2, PipelineError> {
        let colour_slot = present
            .iter()
            .position(|&i| i == self.rig.reference)
            .unwrap_or(0);
        let order =
            std::iter::once(colour_slot).chain((0..present.len()).filter(|&k| k != colour_slot));
        let colours: Vec<ColourSource> = order
            .map(|k| ColourSource {
                image: &images[k],
                cam_from_output: self.rig.cam_from_output(present[k]),
                projection: &self.rig.cameras[present[k]].projection,
            })
            .collect();
        point_cloud(header, range_m, self.params.max_depth_m, &colours)
    }
}

/// What of a group the pipeline can use ([`Pipeline::usable_images`]).
struct UsableImages {
    /// Rig positions of the cameras used, in rig order.
    present: Vec<usize>,
    /// Their images, in the same order.
    images: Vec<RgbImage>,
    /// Names of the cameras left out.
    missing_cameras: Vec<String>,
}

impl Pipeline {
    /// The positions in `present` of the images that do not fit their camera: a fisheye
    /// image that is not its `image_size`, a panorama that is not 2:1, or one of another size
    /// than most of the group's panoramas. `None` when two sizes tie for most (which one is
    /// wrong is not knowable from the sizes alone).
    fn misfits(&self, present: &[usize], images: &[RgbImage]) -> Option<Vec<usize>> {
        let mut misfits = Vec::new();
        let mut panorama_sizes: Vec<((u32, u32), usize)> = Vec::new();
        for (k, (&i, img)) in present.iter().zip(images).enumerate() {
            let projection = &self.rig.cameras[i].projection;
            if projection
                .check_image_size(img.width(), img.height())
                .is_err()
            {
                misfits.push(k);
            } else if projection.is_equirectangular() {
                match panorama_sizes
                    .iter_mut()
                    .find(|(d, _)| *d == img.dimensions())
                {
                    Some((_, count)) => *count += 1,
                    None => panorama_sizes.push((img.dimensions(), 1)),
                }
            }
        }
        let most = panorama_sizes.iter().map(|(_, n)| *n).max().unwrap_or(0);
        let mut winners = panorama_sizes.iter().filter(|(_, n)| *n == most);
        let winner = winners.next().map(|(d, _)| *d);
        if winners.next().is_some() {
            return None;
        }
        for (k, (&i, img)) in present.iter().zip(images).enumerate() {
            let erp = self.rig.cameras[i].projection.is_equirectangular();
            if erp && Some(img.dimensions()) != winner && !misfits.contains(&k) {
                misfits.push(k);
            }
        }
        misfits.sort_unstable();
        Some(misfits)
    }

    /// Logs, once per episode, a camera left out for its image size and its return.
    fn note_misfits(&mut self, present: &[usize], images: &[RgbImage], misfits: &[usize]) {
        if self.size_misfit.len() != self.rig.cameras.len() {
            self.size_misfit = vec![false; self.rig.cameras.len()];
        }
        for (k, (&i, img)) in present.iter().zip(images).enumerate() {
            let misfit = misfits.contains(&k);
            let name = &self.rig.cameras[i].name;
            if misfit && !self.size_misfit[i] {
                tracing::warn!(
                    "camera '{name}': its {}x{} images do not fit (the other panoramas' size, or \
                     its image_size); it is left out of the groups until they do",
                    img.width(),
                    img.height()
                );
            } else if !misfit && self.size_misfit[i] {
                tracing::info!("camera '{name}': its images fit again; it is back in the groups");
            }
            self.size_misfit[i] = misfit;
        }
    }
}

#[cfg(test)]
mod tests;
