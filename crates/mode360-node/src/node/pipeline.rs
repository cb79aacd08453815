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
use mode360_estimator::estimator::{DepthEstimator, EstimatorError};
use mode360_io::msgs::compressed_depth::{
    encode_compressed_depth, CompressedDepthError, DEFAULT_DEPTH_QUANTIZATION,
};
use mode360_io::msgs::image::image_msg_from_float;
use mode360_io::msgs::{CompressedImage, Header, Image, PointCloud2};
use std::time::{Duration, Instant};

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
}

impl Default for PipelineParams {
    fn default() -> Self {
        Self {
            output_width: 512,
            max_depth_m: mode360_core::geometry::DEFAULT_MAX_DEPTH_M as f32,
            far_value: FarValue::Inf,
            min_confidence: 0.0,
            depth_quantization: DEFAULT_DEPTH_QUANTIZATION,
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
    /// Wall time of the estimator plus message building.
    pub latency: Duration,
}

/// Estimator plus message building for a fixed rig.
pub struct Pipeline {
    rig: Rig,
    estimator: Box<dyn DepthEstimator>,
    params: PipelineParams,
    grid: ErpGrid,
}

impl Pipeline {
    pub fn new(
        rig: Rig,
        estimator: Box<dyn DepthEstimator>,
        params: PipelineParams,
    ) -> Result<Self, PipelineError> {
        let grid = ErpGrid::new(params.output_width)?;
        Ok(Self {
            rig,
            estimator,
            params,
            grid,
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
        let t0 = Instant::now();
        if group.len() != self.rig.cameras.len() {
            return Err(PipelineError::GroupSize {
                got: group.len(),
                expected: self.rig.cameras.len(),
            });
        }
        let mut present = Vec::new();
        let mut images = Vec::new();
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
        if !self.sizes_fit(&present, &images) {
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
        let mut estimate = if missing_cameras.is_empty() {
            self.estimator.estimate(&self.rig, &images, self.grid)?
        } else {
            let sub = self.rig.subset(&present)?;
            self.estimator.estimate(&sub, &images, self.grid)?
        };
        apply_rep117(&mut estimate.range_m, &estimate.confidence, &self.params);
        // Colour source: the reference camera when present, else the first camera present.
        let colour_slot = present
            .iter()
            .position(|&i| i == self.rig.reference)
            .unwrap_or(0);
        let header = Header::new(stamp_ns, self.rig.output_frame_id.clone());
        let points = if want.points {
            // The colour source first, then the others for what a fisheye lens does not see.
            let order = std::iter::once(colour_slot)
                .chain((0..present.len()).filter(|&k| k != colour_slot));
            let colours: Vec<ColourSource> = order
                .map(|k| ColourSource {
                    image: &images[k],
                    cam_from_output: self.rig.cam_from_output(present[k]),
                    projection: &self.rig.cameras[present[k]].projection,
                })
                .collect();
            Some(point_cloud(
                header.clone(),
                &estimate.range_m,
                self.params.max_depth_m,
                &colours,
            )?)
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
        Ok(PipelineOutput {
            depth: image_msg_from_float(header.clone(), &estimate.range_m),
            compressed_depth,
            points,
            confidence: image_msg_from_float(header, &estimate.confidence),
            missing_cameras,
            latency: t0.elapsed(),
        })
    }
}

impl Pipeline {
    /// Whether every image fits its camera (a fisheye image is its `image_size`, a panorama
    /// 2:1) and the panoramas share one size.
    fn sizes_fit(&self, present: &[usize], images: &[RgbImage]) -> bool {
        let mut panorama: Option<(u32, u32)> = None;
        present.iter().zip(images).all(|(&i, img)| {
            let projection = &self.rig.cameras[i].projection;
            if projection
                .check_image_size(img.width(), img.height())
                .is_err()
            {
                return false;
            }
            !projection.is_equirectangular()
                || *panorama.get_or_insert(img.dimensions()) == img.dimensions()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::PixelCoord;
    use mode360_estimator::estimator::DepthEstimate;
    use mode360_io::msgs::image::float_from_image_msg;

    const RIG_YAML: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    );

    /// A fake estimator: range grows with the row, the top rows are sky, one pixel NaN.
    struct FakeEstimator {
        max_depth_m: f32,
    }

    impl DepthEstimator for FakeEstimator {
        fn name(&self) -> &str {
            "fake"
        }
        fn estimate(
            &mut self,
            _rig: &Rig,
            _images: &[RgbImage],
            output: ErpGrid,
        ) -> Result<DepthEstimate, EstimatorError> {
            let (w, h) = (output.width(), output.height());
            let mut range = FloatImage::filled(w, h, 0.0);
            for v in 0..h {
                for u in 0..w {
                    range.data[v * w + u] = if v < 2 {
                        self.max_depth_m
                    } else {
                        1.0 + v as f32 + 0.01 * u as f32
                    };
                }
            }
            range.data[3 * w + 5] = f32::NAN;
            Ok(DepthEstimate {
                confidence: FloatImage::filled(w, h, 0.5),
                range_m: range,
            })
        }
    }

    fn test_image(w: u32) -> RgbImage {
        RgbImage::from_fn(w, w / 2, |u, v| image::Rgb([u as u8, v as u8, 7]))
    }

    fn pipeline(width: usize) -> Pipeline {
        let rig = Rig::from_file(RIG_YAML).unwrap();
        let max_depth_m = 100.0;
        Pipeline::new(
            rig,
            Box::new(FakeEstimator { max_depth_m }),
            PipelineParams {
                output_width: width,
                max_depth_m,
                ..Default::default()
            },
        )
        .unwrap()
    }

    #[test]
    fn points_are_valid_pixels_at_range_times_direction() {
        let width = 32;
        let mut p = pipeline(width);
        let n = p.rig().cameras.len();
        let group = (0..n).map(|_| Some(test_image(width as u32))).collect();
        let out = p.process(group, 1_234_567_890).unwrap();
        let range = float_from_image_msg(&out.depth).unwrap();
        let valid = range
            .data
            .iter()
            .filter(|&&r| is_point_range(r, p.params().max_depth_m))
            .count();
        // 16 rows, 2 of sky, one NaN pixel.
        assert_eq!(valid, width * (width / 2 - 2) - 1);
        let points = out.points.as_ref().unwrap();
        assert_eq!(points.width as usize, valid);
        assert_eq!(points.data.len(), valid * POINT_STEP_BYTES as usize);
        assert_eq!(out.depth.header.stamp.to_nanos(), 1_234_567_890);
        assert_eq!(points.header.frame_id, p.rig().output_frame_id);
        let pts = decode_points(out.points.as_ref().unwrap()).unwrap();
        // First point: pixel (0, 2).
        let grid = ErpGrid::new(width).unwrap();
        let dir = grid.dir_from_pixel(PixelCoord { u: 0.0, v: 2.0 });
        let rho = range.get(0, 2) as f64;
        assert!((pts[0].x_m as f64 - rho * dir.x).abs() < 1e-4);
        assert!((pts[0].y_m as f64 - rho * dir.y).abs() < 1e-4);
        assert!((pts[0].z_m as f64 - rho * dir.z).abs() < 1e-4);
        let conf = float_from_image_msg(&out.confidence).unwrap();
        assert!(conf.data.iter().all(|&c| c == 0.5));
    }

    #[test]
    fn depth_follows_rep117_and_only_measurements_become_points() {
        let width = 32;
        let (w, h) = (width, width / 2);
        let mut p = pipeline(width);
        let n = p.rig().cameras.len();
        let group = || (0..n).map(|_| Some(test_image(width as u32))).collect();
        // Default: the two sky rows are +Inf, the invalid pixel NaN, the rest finite.
        let out = p.process(group(), 1).unwrap();
        let range = float_from_image_msg(&out.depth).unwrap();
        assert!(range.data[..2 * w].iter().all(|&r| r == f32::INFINITY));
        assert!(range.data[3 * w + 5].is_nan());
        let finite = range.data.iter().filter(|r| r.is_finite()).count();
        assert_eq!(finite, w * (h - 2) - 1);
        assert_eq!(out.points.as_ref().unwrap().width as usize, finite);
        // The older convention on request: the sky holds max_depth_m, still no point.
        p.params.far_value = FarValue::MaxDepth;
        let out = p.process(group(), 2).unwrap();
        let range = float_from_image_msg(&out.depth).unwrap();
        assert!(range.data[..2 * w].iter().all(|&r| r == 100.0));
        assert_eq!(out.points.as_ref().unwrap().width as usize, finite);
        // Confidence 0.5 everywhere: a threshold above it leaves no measurement and no point.
        p.params.min_confidence = 0.6;
        let out = p.process(group(), 3).unwrap();
        let range = float_from_image_msg(&out.depth).unwrap();
        assert!(range.data.iter().all(|r| r.is_nan()));
        assert_eq!(out.points.as_ref().unwrap().width, 0);
        // Not asked for, not built.
        let none = OutputRequest {
            points: false,
            compressed_depth: false,
        };
        let out = p.process_with(group(), 4, none).unwrap();
        assert!(out.points.is_none() && out.compressed_depth.is_none());
    }

    #[test]
    fn colour_comes_from_reference_camera_pixel() {
        let width = 32;
        let mut p = pipeline(width);
        let n = p.rig().cameras.len();
        let group = (0..n).map(|_| Some(test_image(width as u32))).collect();
        let out = p.process(group, 0).unwrap();
        let pts = decode_points(out.points.as_ref().unwrap()).unwrap();
        let rig = p.rig().clone();
        let cam_from_output = rig.cam_from_output(rig.reference);
        let grid = ErpGrid::new(width).unwrap();
        for pt in pts.iter().step_by(37) {
            let p_cam = cam_from_output.transform_point(&nalgebra::Point3::new(
                pt.x_m as f64,
                pt.y_m as f64,
                pt.z_m as f64,
            ));
            let px = grid.pixel_from_dir(&p_cam.coords);
            let u = (px.u.round() as u32).min(width as u32 - 1);
            let v = (px.v.round() as u32).min(width as u32 / 2 - 1);
            assert_eq!(pt.rgb, [u as u8, v as u8, 7]);
        }
    }

    #[test]
    fn rgb_packing_round_trips() {
        for (r, g, b) in [
            (0, 0, 0),
            (255, 0, 0),
            (1, 2, 3),
            (255, 255, 255),
            (12, 200, 99),
        ] {
            let packed = pack_rgb(r, g, b);
            assert_eq!(
                packed.to_bits(),
                (r as u32) << 16 | (g as u32) << 8 | b as u32
            );
            assert_eq!(unpack_rgb(packed), [r, g, b]);
        }
    }

    #[test]
    fn missing_cameras_are_reported_and_too_few_rejected() {
        let width = 16;
        let mut p = pipeline(width);
        let n = p.rig().cameras.len();
        let mut group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
        group[1] = None;
        let out = p.process(group, 5).unwrap();
        assert_eq!(out.missing_cameras, vec![p.rig().cameras[1].name.clone()]);
        let mut few: Vec<Option<RgbImage>> = vec![None; n];
        few[0] = Some(test_image(width as u32));
        assert!(matches!(
            p.process(few, 5),
            Err(PipelineError::TooFewCameras { present: 1 })
        ));
        assert!(matches!(
            p.process(vec![None], 5),
            Err(PipelineError::GroupSize { got: 1, .. })
        ));
    }

    #[test]
    fn mixed_image_sizes_name_every_camera() {
        let width = 16;
        let mut p = pipeline(width);
        let n = p.rig().cameras.len();
        let mut group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
        // The odd one is the first camera: the error must not blame the others.
        group[0] = Some(test_image(8));
        let err = p.process(group, 5).err().map(|e| e.to_string());
        let names: Vec<String> = p.rig().cameras.iter().map(|c| c.name.clone()).collect();
        let expected = format!(
            "the cameras' images do not fit their cameras ({} 8x4, {} 16x8, {} 16x8, {} 16x8): \
             panoramas must share one 2:1 size, fisheye images must be their image_size",
            names[0], names[1], names[2], names[3]
        );
        assert_eq!(err, Some(expected));
    }

    #[test]
    fn fisheye_points_take_colour_from_a_camera_that_sees_them() {
        let rig = Rig::from_file(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../launch_configs/rig_omnimvs.yaml"
        ))
        .and_then(|r| r.scaled(0.125))
        .unwrap();
        let max_depth_m = 100.0;
        let params = PipelineParams {
            output_width: 32,
            max_depth_m,
            ..PipelineParams::default()
        };
        let estimator = Box::new(FakeEstimator { max_depth_m });
        let mut p = Pipeline::new(rig.clone(), estimator, params).unwrap();
        // Camera k's image is one flat colour; corners outside the lens stay black.
        let colour = |k: usize| [40 + 50 * k as u8, 7, 9];
        let group = || {
            (0..4)
                .map(|k| Some(RgbImage::from_pixel(48, 48, image::Rgb(colour(k)))))
                .collect::<Vec<_>>()
        };
        let out = p.process(group(), 0).unwrap();
        let pts = decode_points(out.points.as_ref().unwrap()).unwrap();
        assert_eq!(pts.len(), 32 * 14 - 1);
        let mut by_camera = [0usize; 4];
        for pt in &pts {
            let k = (0..4)
                .find(|&k| colour(k) == pt.rgb)
                .expect("a camera's colour");
            by_camera[k] += 1;
            // The reference (front-left, yaw +45°) colours all it sees.
            let p_out = nalgebra::Vector3::new(pt.x_m as f64, pt.y_m as f64, pt.z_m as f64);
            let p_cam = rig.cam_from_output(0).transform_point(&p_out.into()).coords;
            let seen = rig.cameras[0]
                .projection
                .fisheye_model()
                .unwrap()
                .project(&p_cam);
            assert_eq!(seen.is_some(), k == 0, "{p_out:?} coloured by camera {k}");
        }
        assert!(by_camera[0] > pts.len() / 3, "{by_camera:?}");
        // Then the next cameras in rig order: front-right and rear-left cover the rest.
        assert!(by_camera[1] > 0 && by_camera[2] > 0, "{by_camera:?}");
        // A fisheye image at the wrong size is refused by name.
        let mut bad = group();
        bad[2] = Some(RgbImage::new(64, 32));
        let err = p.process(bad, 1).err().map(|e| e.to_string()).unwrap();
        assert!(err.contains("rear_left 64x32"), "{err}");
    }
}
