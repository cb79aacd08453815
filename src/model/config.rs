//! SSMODE hyper-parameters (presets) and the per-rig sweep sampling tables.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::sphere_conv::SphereConvTable;
use super::ModelError;
use crate::geometry::{
    DepthRange, ErpGrid, InverseDepthHypotheses, PixelCoord, Rig, SweepGeometry,
};
use crate::model::ops::SampleTable;

/// The feature extractor works at `1 / FEATURE_DOWNSAMPLE` of the input resolution.
pub const FEATURE_DOWNSAMPLE: usize = 4;
/// The hourglass halves D, H and W twice, so they must be multiples of this.
pub const HOURGLASS_DIVISOR: usize = 4;
/// Fewest cameras the sweep can aggregate (mean and variance over views).
pub const MIN_CAMERAS: usize = 2;

/// Hyper-parameters of the SSMODE network.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SsmodeConfig {
    /// Preset name (`paper`, `compact`, or a custom one).
    pub name: String,
    /// Input ERP width; the height is `width / 2`.
    pub width: usize,
    /// Channels of the four feature stages (stage 1 at half, stages 2 to 4 at quarter resolution).
    pub feature_channels: [usize; 4],
    /// Residual blocks per feature stage.
    pub feature_blocks: [usize; 4],
    /// Channels of the fused per-camera feature map.
    pub feature_out_channels: usize,
    /// Sweep spheres at quarter resolution (cost volume depth D).
    pub spheres: usize,
    /// Full-resolution hypotheses after trilinear upsampling of the cost volume.
    pub hypotheses: usize,
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    /// Channels of the 3-D cost aggregation.
    pub hourglass_channels: usize,
    /// Stacked hourglasses (one regression head each).
    pub hourglasses: usize,
    /// Far-plane readout: a pixel whose probability on the farthest hypothesis is at least
    /// this is given `max_depth_m` instead of the soft-argmin (see [`crate::model::regression`]);
    /// above 1 disables it. Chosen on the validation split; files without it get the default.
    #[serde(default = "default_far_plane_probability")]
    pub far_plane_probability: f64,
}

/// [`SsmodeConfig::far_plane_probability`] of the presets.
pub const DEFAULT_FAR_PLANE_PROBABILITY: f64 = 0.8;

fn default_far_plane_probability() -> f64 {
    DEFAULT_FAR_PLANE_PROBABILITY
}

impl SsmodeConfig {
    /// The paper's SSMODE: 1024x512, 48 spheres, 192 hypotheses, features 32/64/64/128 -> 32,
    /// three hourglasses on 32 channels.
    pub fn paper() -> Self {
        Self {
            name: "paper".to_string(),
            width: 1024,
            feature_channels: [32, 64, 64, 128],
            feature_blocks: [3, 16, 3, 7],
            feature_out_channels: 32,
            spheres: 48,
            hypotheses: 192,
            min_depth_m: crate::geometry::sweep::PAPER_MIN_DEPTH_M,
            max_depth_m: crate::geometry::sweep::PAPER_MAX_DEPTH_M,
            hourglass_channels: 32,
            hourglasses: 3,
            far_plane_probability: DEFAULT_FAR_PLANE_PROBABILITY,
        }
    }

    /// The shipped CPU default: 256x128 input, 32 spheres, 64 hypotheses, two hourglasses on
    /// 16 channels, about 0.4M parameters (measured on 2 shared cores: about 0.34 s per 4-camera
    /// forward, 1.1 s per training step).
    pub fn compact() -> Self {
        Self {
            name: "compact".to_string(),
            width: 256,
            feature_channels: [16, 24, 24, 32],
            feature_blocks: [1, 2, 1, 1],
            feature_out_channels: 16,
            spheres: 32,
            hypotheses: 64,
            min_depth_m: crate::geometry::sweep::PAPER_MIN_DEPTH_M,
            max_depth_m: crate::geometry::sweep::PAPER_MAX_DEPTH_M,
            hourglass_channels: 16,
            hourglasses: 2,
            far_plane_probability: DEFAULT_FAR_PLANE_PROBABILITY,
        }
    }

    /// A tiny configuration for tests: 64x32 input, 8 spheres.
    pub fn tiny() -> Self {
        Self {
            name: "tiny".to_string(),
            width: 64,
            feature_channels: [8, 8, 8, 8],
            feature_blocks: [1, 1, 1, 1],
            feature_out_channels: 8,
            spheres: 8,
            hypotheses: 16,
            min_depth_m: 1.0,
            max_depth_m: 100.0,
            hourglass_channels: 8,
            hourglasses: 2,
            far_plane_probability: DEFAULT_FAR_PLANE_PROBABILITY,
        }
    }

    /// The preset called `name` (`paper`, `compact`, `tiny`).
    pub fn preset(name: &str) -> Result<Self, ModelError> {
        match name {
            "paper" => Ok(Self::paper()),
            "compact" => Ok(Self::compact()),
            "tiny" => Ok(Self::tiny()),
            other => Err(ModelError::UnknownPreset {
                name: other.to_string(),
                known: "paper, compact, tiny".to_string(),
            }),
        }
    }

    /// Input height, `width / 2`.
    pub fn height(&self) -> usize {
        self.width / 2
    }

    /// Width of the quarter-resolution feature maps and cost volume.
    pub fn feature_width(&self) -> usize {
        self.width / FEATURE_DOWNSAMPLE
    }

    /// Height of the quarter-resolution feature maps and cost volume.
    pub fn feature_height(&self) -> usize {
        self.feature_width() / 2
    }

    /// Checks the sizes the network needs.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |field: &str, problem: String| {
            Err(ModelError::BadConfig {
                field: field.to_string(),
                problem,
            })
        };
        // The quarter-res ERP must be even-width and its height divisible by HOURGLASS_DIVISOR.
        let width_multiple = FEATURE_DOWNSAMPLE * 2 * HOURGLASS_DIVISOR;
        if self.width == 0 || !self.width.is_multiple_of(width_multiple) {
            return bad(
                "width",
                format!(
                    "{} must be a positive multiple of {width_multiple}",
                    self.width
                ),
            );
        }
        if self.spheres == 0 || !self.spheres.is_multiple_of(HOURGLASS_DIVISOR) {
            return bad(
                "spheres",
                format!(
                    "{} must be a positive multiple of {HOURGLASS_DIVISOR}",
                    self.spheres
                ),
            );
        }
        if self.hypotheses < crate::geometry::sweep::MIN_HYPOTHESES {
            return bad("hypotheses", format!("{} is fewer than 2", self.hypotheses));
        }
        if self.feature_channels.contains(&0)
            || self.feature_out_channels == 0
            || self.hourglass_channels == 0
        {
            return bad(
                "channels",
                "every channel count must be positive".to_string(),
            );
        }
        if self.far_plane_probability.is_nan() || self.far_plane_probability <= 0.0 {
            return bad(
                "far_plane_probability",
                format!("{} must be positive", self.far_plane_probability),
            );
        }
        if self.hourglasses == 0 {
            return bad(
                "hourglasses",
                "at least one hourglass is needed".to_string(),
            );
        }
        self.depth_range().map(|_| ())
    }

    /// The sweep's depth range.
    pub fn depth_range(&self) -> Result<DepthRange, ModelError> {
        Ok(DepthRange::new(self.min_depth_m, self.max_depth_m)?)
    }

    /// The quarter-resolution sweep spheres, uniform in inverse depth.
    pub fn sphere_hypotheses(&self) -> Result<InverseDepthHypotheses, ModelError> {
        Ok(InverseDepthHypotheses::new(
            self.depth_range()?,
            self.spheres,
        )?)
    }

    /// The full-resolution output hypotheses, uniform in inverse depth.
    pub fn output_hypotheses(&self) -> Result<InverseDepthHypotheses, ModelError> {
        Ok(InverseDepthHypotheses::new(
            self.depth_range()?,
            self.hypotheses,
        )?)
    }
}

/// Sampling tables for one rig at one configuration's resolution, built once:
/// - one sweep table per camera: for every sphere `d` and quarter-res output pixel `(v, u)`
///   (sample index `(d H + v) W + u`), the bilinear taps of
///   `erp_c(cam_from_output * (rho_d * dir(u, v)))` in that camera's feature map;
/// - the SphereNet kernel table of the stage-4 spherical convolution.
#[derive(Clone, Debug)]
pub struct SweepSampling {
    geometry: SweepGeometry,
    sweep_tables: Vec<SampleTable>,
    sphere_conv: SphereConvTable,
}

impl SweepSampling {
    /// Builds the tables for `rig` at `cfg`'s quarter resolution.
    pub fn new(rig: &Rig, cfg: &SsmodeConfig) -> Result<Self, ModelError> {
        cfg.validate()?;
        let cameras = rig.cameras.len();
        if cameras < MIN_CAMERAS {
            return Err(ModelError::TooFewCameras {
                got: cameras,
                min: MIN_CAMERAS,
            });
        }
        let grid = ErpGrid::new(cfg.feature_width())?;
        let geometry =
            SweepGeometry::new(rig, grid, vec![grid; cameras], cfg.sphere_hypotheses()?)?;
        let w = grid.width();
        let pixels = grid.len();
        let sweep_tables = (0..cameras)
            .map(|cam| {
                let camera_grid = geometry.camera_grid(cam);
                // sample index (sphere H + v) W + u
                let taps: Vec<_> = (0..cfg.spheres * pixels)
                    .into_par_iter()
                    .with_min_len(w)
                    .map(|n| {
                        let (sphere, k) = (n / pixels, n % pixels);
                        let p = PixelCoord {
                            u: (k % w) as f64,
                            v: (k / w) as f64,
                        };
                        camera_grid.bilinear_taps(geometry.sample(cam, sphere, p))
                    })
                    .collect();
                SampleTable::new(&taps)
            })
            .collect();
        Ok(Self {
            sweep_tables,
            sphere_conv: SphereConvTable::new(grid),
            geometry,
        })
    }

    /// The sweep geometry at quarter resolution.
    pub fn geometry(&self) -> &SweepGeometry {
        &self.geometry
    }

    pub fn camera_count(&self) -> usize {
        self.sweep_tables.len()
    }

    /// Camera `cam`'s sweep table, `spheres * H * W` samples, sphere-major then row-major.
    pub fn sweep_table(&self, cam: usize) -> Option<&SampleTable> {
        self.sweep_tables.get(cam)
    }

    /// The SphereNet kernel table of the stage-4 spherical convolution.
    pub fn sphere_conv(&self) -> &SphereConvTable {
        &self.sphere_conv
    }
}
