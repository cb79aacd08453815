//! The node's processing core, free of DDS: one synchronized group of decoded panoramas in,
//! the published messages (`depth`, `points`, `confidence`) out. The live node's inference
//! worker (`super::worker`) and offline replay ([`crate::cli::replay`]) both run this.
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
//! p_out`, projected with that camera's ERP model, nearest pixel. The colour is packed as
//! `0x00RRGGBB` and those bits are stored as a float32 field `rgb` (the rviz / Foxglove
//! convention).

use crate::estimator::{DepthEstimator, EstimatorError};
use crate::frame::{FloatImage, RgbImage};
use crate::geometry::rig::MIN_CAMERAS;
use crate::geometry::{ErpGrid, GeometryError, PixelCoord, Rig, RigError};
use crate::msgs::compressed_depth::{
    encode_compressed_depth, CompressedDepthError, DEFAULT_DEPTH_QUANTIZATION,
};
use crate::msgs::image::image_msg_from_float;
use crate::msgs::{CompressedImage, Header, Image, PointCloud2, PointField};
use std::time::{Duration, Instant};

/// Bytes of one float32 value.
const F32_BYTES: u32 = 4;
/// Fields of a published point: x, y, z, rgb (all float32).
pub const POINT_FIELD_NAMES: [&str; 4] = ["x", "y", "z", "rgb"];
/// Bytes of one published point.
pub const POINT_STEP_BYTES: u32 = F32_BYTES * POINT_FIELD_NAMES.len() as u32;

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
            max_depth_m: 1000.0,
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
    #[error("the cameras' images differ in size ({sizes}); all must be the same")]
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
        let first = images[0].dimensions();
        if images.iter().any(|img| img.dimensions() != first) {
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
        let colour_cam = present[colour_slot];
        let header = Header::new(stamp_ns, self.rig.output_frame_id.clone());
        let points = if want.points {
            Some(point_cloud(
                header.clone(),
                &estimate.range_m,
                self.params.max_depth_m,
                &ColourSource {
                    image: &images[colour_slot],
                    cam_from_output: self.rig.cam_from_output(colour_cam),
                },
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

/// The camera image points take their colour from, with its pose.
pub struct ColourSource<'a> {
    pub image: &'a RgbImage,
    pub cam_from_output: nalgebra::Isometry3<f64>,
}

/// Packs an RGB colour as `0x00RRGGBB` and reinterprets the bits as f32.
pub fn pack_rgb(r: u8, g: u8, b: u8) -> f32 {
    f32::from_bits((u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b))
}

/// Inverse of [`pack_rgb`].
pub fn unpack_rgb(packed: f32) -> [u8; 3] {
    let bits = packed.to_bits();
    [(bits >> 16) as u8, (bits >> 8) as u8, bits as u8]
}

/// True when a range becomes a point: finite, positive and nearer than `max_depth_m`.
pub fn is_point_range(range_m: f32, max_depth_m: f32) -> bool {
    range_m.is_finite() && range_m > 0.0 && range_m < max_depth_m
}

/// An unorganized (height 1) cloud of x y z rgb float32 points for every pixel of `range`
/// passing [`is_point_range`].
pub fn point_cloud(
    header: Header,
    range: &FloatImage,
    max_depth_m: f32,
    colour: &ColourSource<'_>,
) -> Result<PointCloud2, PipelineError> {
    let grid = ErpGrid::new(range.width)?;
    let cam_grid = ErpGrid::new(colour.image.width() as usize)?;
    let (cam_w, cam_h) = (colour.image.width(), colour.image.height());
    let mut data = Vec::new();
    let mut count: u32 = 0;
    for v in 0..range.height {
        for u in 0..range.width {
            let rho = range.data[v * range.width + u];
            if !is_point_range(rho, max_depth_m) {
                continue;
            }
            let dir = grid.dir_from_pixel(PixelCoord {
                u: u as f64,
                v: v as f64,
            });
            let p_out = dir * f64::from(rho);
            let p_cam = colour.cam_from_output.transform_point(&p_out.into());
            let px = cam_grid.pixel_from_dir(&p_cam.coords);
            let cu = (px.u.round().max(0.0) as u32).min(cam_w.saturating_sub(1));
            let cv = (px.v.round().max(0.0) as u32).min(cam_h.saturating_sub(1));
            let [r, g, b] = colour.image.get_pixel(cu, cv).0;
            for value in [
                p_out.x as f32,
                p_out.y as f32,
                p_out.z as f32,
                pack_rgb(r, g, b),
            ] {
                data.extend_from_slice(&value.to_le_bytes());
            }
            count += 1;
        }
    }
    Ok(PointCloud2 {
        header,
        height: 1,
        width: count,
        fields: POINT_FIELD_NAMES
            .iter()
            .enumerate()
            .map(|(k, name)| PointField::new(*name, k as u32 * F32_BYTES, PointField::FLOAT32, 1))
            .collect(),
        is_bigendian: false,
        point_step: POINT_STEP_BYTES,
        row_step: POINT_STEP_BYTES * count,
        data,
        is_dense: true,
    })
}

/// One decoded point of a cloud written by [`point_cloud`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecodedPoint {
    pub x_m: f32,
    pub y_m: f32,
    pub z_m: f32,
    pub rgb: [u8; 3],
}

/// Reads back the points of an x y z rgb float32 little-endian cloud (`None` if the layout
/// differs).
pub fn decode_points(cloud: &PointCloud2) -> Option<Vec<DecodedPoint>> {
    if cloud.point_step != POINT_STEP_BYTES || cloud.is_bigendian {
        return None;
    }
    let f = |c: &[u8], k: usize| {
        let o = k * F32_BYTES as usize;
        f32::from_le_bytes([c[o], c[o + 1], c[o + 2], c[o + 3]])
    };
    Some(
        cloud
            .data
            .chunks_exact(POINT_STEP_BYTES as usize)
            .map(|c| DecodedPoint {
                x_m: f(c, 0),
                y_m: f(c, 1),
                z_m: f(c, 2),
                rgb: unpack_rgb(f(c, 3)),
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::DepthEstimate;
    use crate::msgs::image::float_from_image_msg;

    const RIG_YAML: &str = "launch_configs/rig_deep360.yaml";

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
            "the cameras' images differ in size ({} 8x4, {} 16x8, {} 16x8, {} 16x8); all must be \
             the same",
            names[0], names[1], names[2], names[3]
        );
        assert_eq!(err, Some(expected));
    }
}
