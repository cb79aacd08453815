//! SSMODE hyper-parameters (the named presets are in [`super::presets`]); the per-rig sweep
//! tables are in [`super::sweep_sampling`].

use serde::{Deserialize, Serialize};

use super::ModelError;
use mode360_core::geometry::{DepthHypotheses, DepthRange, HypothesisSpacing};

/// The feature extractor works at `1 / FEATURE_DOWNSAMPLE` of the input resolution.
pub const FEATURE_DOWNSAMPLE: usize = 4;
/// The hourglass halves D, H and W twice, so they must be multiples of this.
pub const HOURGLASS_DIVISOR: usize = 4;
/// Fewest cameras the sweep can aggregate (mean and variance over views).
pub const MIN_CAMERAS: usize = 2;
/// Cost-volume scales a config may use (input pixels per cost cell along each axis): full,
/// half, or the feature trunk's quarter resolution.
pub const COST_DOWNSAMPLES: [usize; 3] = [1, 2, FEATURE_DOWNSAMPLE];
/// Strides the cost aggregation may enter with.
pub const AGGREGATION_STRIDES: [usize; 2] = [1, 2];
/// A config resolves a baseline at a range when the parallax there spans at least this many
/// cost-volume cells (see [`SsmodeConfig::resolved_range_m`]).
pub const RESOLVED_PARALLAX_CELLS: f64 = 1.0;

/// How the sweep aggregates the cameras' sampled features into the cost volume.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CostKind {
    /// `concat(mean, variance)` over views (`2 C` channels). The mean is close to the
    /// reference view's own appearance, so the aggregation can regress depth from one image.
    #[default]
    MeanVariance,
    /// Variance over views only (`C` channels, as MVSNet): zero wherever the views agree, so
    /// the volume carries matching evidence and nothing of a single view's appearance.
    Variance,
}

impl CostKind {
    /// Cost-volume channels for `c` feature channels.
    pub fn channels(self, c: usize) -> usize {
        match self {
            Self::MeanVariance => 2 * c,
            Self::Variance => c,
        }
    }
}

fn default_cost_downsample() -> usize {
    FEATURE_DOWNSAMPLE
}

fn default_aggregation_stride() -> usize {
    1
}

/// Hyper-parameters of the SSMODE network. A weights file's config with a field this build
/// does not know is refused when it is read ([`super::weights`]): a file written by a newer
/// mode360 with a feature this binary lacks is an error, not a silently wrong network. How the
/// output is read (far-plane test, edge refinement) is not part of the network but an estimator
/// setting: [`super::readout::Readout`].
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
    /// View aggregation of the cost volume (files without it: mean and variance).
    #[serde(default)]
    pub cost: CostKind,
    /// Input pixels per cost-volume cell along each axis (1, 2 or 4; files without it: 4, the
    /// feature trunk's resolution). Below 4, a fine branch computes matching features at this
    /// scale from the image and the upsampled trunk features.
    #[serde(default = "default_cost_downsample")]
    pub cost_downsample: usize,
    /// Channels of the fine branch's convolutions (used when `cost_downsample` < 4).
    #[serde(default)]
    pub fine_channels: usize,
    /// Stride of the first 3-D convolution over the cost volume (1 or 2 along D, H and W): a
    /// fine cost volume is matched at full detail and aggregated at half its size.
    #[serde(default = "default_aggregation_stride")]
    pub aggregation_stride: usize,
    /// Cost-volume cells copied across the longitude seam to each side in the 3-D aggregation
    /// (after its entry convolution, at `1 / aggregation_stride` of them), whose convolutions pad
    /// with zeros, so that cells near longitude ±180° are aggregated with their true neighbours
    /// ([`super::seam`]); 0 turns it off. Twice it must be
    /// a multiple of `4 aggregation_stride`. Files without it get 0, the zero padding they were
    /// trained with; the presets train with [`DEFAULT_SEAM_PAD_CELLS`].
    #[serde(default)]
    pub seam_pad_cells: usize,
    /// Append the learning-free sweep's windowed-ZNCC matching cost as one more cost-volume
    /// channel ([`super::photometric_cost`]; files without it: no). Needs `cost_downsample` 1.
    #[serde(default)]
    pub photometric_cost: bool,
    /// How spheres and output hypotheses are spread between `min_depth_m` and `max_depth_m`
    /// (files without it: uniform in inverse depth, the paper's).
    #[serde(default)]
    pub hypothesis_spacing: HypothesisSpacing,
    /// Hidden channels of the fine head ([`super::fine_head`]), a readout at the cost volume's
    /// own resolution in latitude and longitude after the hourglasses, which decide at
    /// `1 / aggregation_stride` of it; 0 (files without it): none, the coarse cost is upsampled.
    #[serde(default)]
    pub fine_head_channels: usize,
    /// Position channels in the cost volume: an ablation that lost (models/README.md, "Issue
    /// 22") and is no longer built; a file that sets it is refused.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub position_channels: bool,
    /// A learned logit prior by latitude: an ablation that lost (models/README.md) and is no
    /// longer built; a file that sets it is refused.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub logit_prior: bool,
}

/// Limits a weights file's configuration must keep, so that a file can never make a command
/// or the node allocate more than the machine has (the paper's largest network is 1024 wide
/// with 48 spheres and 192 hypotheses): input width, pixels.
pub const MAX_WIDTH_PX: usize = 8192;
/// Most sweep spheres.
pub const MAX_SPHERES: usize = 1024;
/// Most output hypotheses.
pub const MAX_HYPOTHESES: usize = 1024;
/// Most channels of any layer.
pub const MAX_CHANNELS: usize = 1024;
/// Most residual blocks of a feature stage, and most hourglasses.
pub const MAX_BLOCKS: usize = 64;
/// Most cells of one channel of the cost volume, `spheres * cost_height * cost_width`
/// (the paper's network at 1024 wide: 1.6 M; `parallax` at 2048 wide: 201 M).
pub const MAX_COST_VOLUME_CELLS: usize = 1 << 28;

/// [`SsmodeConfig::seam_pad_cells`] of the presets: 8 cells (11° at the network's 256), the
/// cheaper of 8 and 16, which gain the same on the validation seed at 512 with weights trained
/// without it (models/README.md, "Longitude seam").
pub const DEFAULT_SEAM_PAD_CELLS: usize = 8;

impl SsmodeConfig {
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

    /// Width of the cost volume (input width / `cost_downsample`).
    pub fn cost_width(&self) -> usize {
        self.width / self.cost_downsample.max(1)
    }

    /// Angle of one cost-volume cell, radians: `2 pi / cost_width`.
    pub fn cost_cell_rad(&self) -> f64 {
        std::f64::consts::TAU / self.cost_width() as f64
    }

    /// Height of the cost volume.
    pub fn cost_height(&self) -> usize {
        self.cost_width() / 2
    }

    /// Channels of the features the sweep samples.
    pub fn matching_channels(&self) -> usize {
        self.feature_out_channels
    }

    /// Channels of the cost volume the aggregation takes: the view aggregation of the matching
    /// features, plus one with the photometric cost channel.
    pub fn cost_volume_channels(&self) -> usize {
        self.cost.channels(self.matching_channels()) + usize::from(self.photometric_cost)
    }

    /// Spheres of the aggregated cost the regression heads read (`spheres / aggregation_stride`).
    pub fn aggregated_spheres(&self) -> usize {
        self.spheres / self.aggregation_stride.max(1)
    }

    /// Whether the matching features come from a fine branch (cost finer than the trunk).
    pub fn has_fine_branch(&self) -> bool {
        self.cost_downsample < FEATURE_DOWNSAMPLE
    }

    /// The farthest range at which a baseline of `baseline_m` (seen side-on) is resolved by
    /// the cost volume, metres: its parallax `baseline / rho` must span
    /// [`RESOLVED_PARALLAX_CELLS`] cells of `2 pi / cost_width` radians, and a sphere other
    /// than the far plane must lie at or beyond it, so
    /// `min(baseline cost_width / (2 pi cells), rho(sphere 1))`.
    pub fn resolved_range_m(&self, baseline_m: f64) -> Result<f64, ModelError> {
        let cell_rad = 2.0 * std::f64::consts::PI / self.cost_width() as f64;
        let by_cells = baseline_m / (RESOLVED_PARALLAX_CELLS * cell_rad);
        let sphere1_m = self.sphere_hypotheses()?.depth_m(1.0);
        Ok(by_cells.min(sphere1_m))
    }

    /// This network run at input width `width` instead of the width it was trained at (the
    /// readout's far field scales with it: [`super::readout::Readout::at_width`]); every other
    /// setting is kept. An error naming the width where the network cannot run at it.
    pub fn at_width(&self, width: usize) -> Result<Self, ModelError> {
        let cfg = Self {
            width,
            ..self.clone()
        };
        cfg.validate().map_err(|e| ModelError::BadConfig {
            field: "width".to_string(),
            problem: format!(
                "the network trained at {} cannot run at {width}: {e}",
                self.width
            ),
        })?;
        Ok(cfg)
    }

    /// Checks the sizes the network needs.
    pub fn validate(&self) -> Result<(), ModelError> {
        self.check_removed()?;
        self.check_limits()?;
        self.check_layout()?;
        self.check_seam()?;
        self.depth_range().map(|_| ())
    }

    /// Refuses the options of ablations that lost and were removed.
    fn check_removed(&self) -> Result<(), ModelError> {
        for (field, set) in [
            ("position_channels", self.position_channels),
            ("logit_prior", self.logit_prior),
        ] {
            if set {
                return bad_config(
                    field,
                    "an ablation that lost (models/README.md) and that this build no longer has"
                        .into(),
                );
            }
        }
        Ok(())
    }

    /// Every size within what this build runs (a weights file cannot make it allocate without bound).
    fn check_limits(&self) -> Result<(), ModelError> {
        let limits = [
            ("width", self.width, MAX_WIDTH_PX),
            ("spheres", self.spheres, MAX_SPHERES),
            ("hypotheses", self.hypotheses, MAX_HYPOTHESES),
            (
                "feature_out_channels",
                self.feature_out_channels,
                MAX_CHANNELS,
            ),
            ("hourglass_channels", self.hourglass_channels, MAX_CHANNELS),
            ("fine_channels", self.fine_channels, MAX_CHANNELS),
            ("fine_head_channels", self.fine_head_channels, MAX_CHANNELS),
            ("hourglasses", self.hourglasses, MAX_BLOCKS),
        ]
        .into_iter()
        .chain(
            self.feature_channels
                .iter()
                .map(|&c| ("feature_channels", c, MAX_CHANNELS)),
        )
        .chain(
            self.feature_blocks
                .iter()
                .map(|&b| ("feature_blocks", b, MAX_BLOCKS)),
        );
        for (field, value, max) in limits {
            if value > max {
                return bad_config(
                    field,
                    format!("{value} is above the largest this build runs, {max}"),
                );
            }
        }
        Ok(())
    }

    /// Sizes the stages fit together with: widths, strides, sphere and channel counts.
    fn check_layout(&self) -> Result<(), ModelError> {
        // The quarter-res ERP must be even-width and its height divisible by HOURGLASS_DIVISOR.
        let width_multiple = FEATURE_DOWNSAMPLE * 2 * HOURGLASS_DIVISOR;
        if self.width == 0 || !self.width.is_multiple_of(width_multiple) {
            return bad_config(
                "width",
                format!(
                    "{} must be a positive multiple of {width_multiple}",
                    self.width
                ),
            );
        }
        if !COST_DOWNSAMPLES.contains(&self.cost_downsample) {
            return bad_config(
                "cost_downsample",
                format!(
                    "{} must be one of {COST_DOWNSAMPLES:?}",
                    self.cost_downsample
                ),
            );
        }
        if !AGGREGATION_STRIDES.contains(&self.aggregation_stride) {
            return bad_config(
                "aggregation_stride",
                format!(
                    "{} must be one of {AGGREGATION_STRIDES:?}",
                    self.aggregation_stride
                ),
            );
        }
        if self.has_fine_branch() && self.fine_channels == 0 {
            return bad_config(
                "fine_channels",
                format!(
                    "must be positive when cost_downsample ({}) is below {FEATURE_DOWNSAMPLE}",
                    self.cost_downsample
                ),
            );
        }
        if self.photometric_cost && self.cost_downsample != 1 {
            return bad_config(
                "photometric_cost",
                format!(
                    "needs the cost volume at the input resolution (cost_downsample 1), not 1/{}",
                    self.cost_downsample
                ),
            );
        }
        // The aggregation halves D, H and W twice after its entry stride.
        let divisor = HOURGLASS_DIVISOR * self.aggregation_stride;
        if self.spheres == 0 || !self.spheres.is_multiple_of(divisor) {
            return bad_config(
                "spheres",
                format!("{} must be a positive multiple of {divisor}", self.spheres),
            );
        }
        if !self.cost_height().is_multiple_of(divisor) {
            return bad_config(
                "width",
                format!(
                    "{}: the cost volume's height {} must be a multiple of {divisor}",
                    self.width,
                    self.cost_height()
                ),
            );
        }
        if self.hypotheses < mode360_core::geometry::sweep::MIN_HYPOTHESES {
            return bad_config("hypotheses", format!("{} is fewer than 2", self.hypotheses));
        }
        if self.feature_channels.contains(&0)
            || self.feature_out_channels == 0
            || self.hourglass_channels == 0
        {
            return bad_config(
                "channels",
                "every channel count must be positive".to_string(),
            );
        }
        if self.hourglasses == 0 {
            return bad_config(
                "hourglasses",
                "at least one hourglass is needed".to_string(),
            );
        }
        let cells = self.spheres * self.cost_height() * self.cost_width();
        if cells > MAX_COST_VOLUME_CELLS {
            return bad_config(
                "spheres",
                format!(
                    "{} spheres of {}x{} cells make {cells} cost-volume cells, above the \
                     largest this build runs, {MAX_COST_VOLUME_CELLS}",
                    self.spheres,
                    self.cost_width(),
                    self.cost_height()
                ),
            );
        }
        Ok(())
    }

    /// The aggregation's longitude wrap across the seam.
    fn check_seam(&self) -> Result<(), ModelError> {
        let divisor = HOURGLASS_DIVISOR * self.aggregation_stride;
        // The padded volume must stay a multiple of the divisor, the crop a whole cell count.
        let pad = self.seam_pad_cells;
        if !(2 * pad).is_multiple_of(divisor) || !pad.is_multiple_of(self.aggregation_stride) {
            return bad_config(
                "seam_pad_cells",
                format!(
                    "{pad}: twice it must be a multiple of {divisor} and it a multiple of the \
                     aggregation stride {}",
                    self.aggregation_stride
                ),
            );
        }
        if pad > self.cost_width() {
            return bad_config(
                "seam_pad_cells",
                format!(
                    "{pad} is wider than the cost volume ({})",
                    self.cost_width()
                ),
            );
        }
        Ok(())
    }

    /// The sweep's depth range.
    pub fn depth_range(&self) -> Result<DepthRange, ModelError> {
        Ok(DepthRange::new(self.min_depth_m, self.max_depth_m)?)
    }

    /// The sweep spheres, spread by `hypothesis_spacing`.
    pub fn sphere_hypotheses(&self) -> Result<DepthHypotheses, ModelError> {
        Ok(DepthHypotheses::with_spacing(
            self.depth_range()?,
            self.spheres,
            self.hypothesis_spacing,
        )?)
    }

    /// The output hypotheses, spread by `hypothesis_spacing`.
    pub fn output_hypotheses(&self) -> Result<DepthHypotheses, ModelError> {
        Ok(DepthHypotheses::with_spacing(
            self.depth_range()?,
            self.hypotheses,
            self.hypothesis_spacing,
        )?)
    }
}

/// A `BadConfig` error naming `field`.
fn bad_config(field: &str, problem: String) -> Result<(), ModelError> {
    Err(ModelError::BadConfig {
        field: field.to_string(),
        problem,
    })
}
