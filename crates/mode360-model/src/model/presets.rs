//! The named network configurations: [`Preset`] and the constructors of
//! [`SsmodeConfig`]'s presets.

use serde::{Deserialize, Serialize};

use super::config::{CostKind, SsmodeConfig, DEFAULT_SEAM_PAD_CELLS, FEATURE_DOWNSAMPLE};
use super::ModelError;

use mode360_core::geometry::HypothesisSpacing;

/// Hidden channels of the `parallax_zncc_log_fine` preset's fine head: its first layer at the
/// cost volume's full resolution costs about 3 GFLOP a frame at 256 with 4 (the aggregation
/// about 10).
pub const FINE_HEAD_CHANNELS: usize = 4;

/// The named network configurations (`train --preset`, `bench-model --presets`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "cli", value(rename_all = "snake_case"))]
///
/// Each variant's text is its `--help` line; the test presets (`tiny*`) are not offered by
/// `train --preset` (their names still parse in checkpoints, weights files and `bench-model`).
/// The ablations that lost (position channels, a learned logit prior; models/README.md) were
/// removed, and a weights file that asks for them is refused by name; the
/// configs are [`SsmodeConfig::parallax`],
/// [`SsmodeConfig::compact`], [`SsmodeConfig::paper`], [`SsmodeConfig::tiny`] and
/// [`SsmodeConfig::tiny_parallax`].
pub enum Preset {
    /// The first multi-view network: variance-only cost volume, 256x128.
    #[default]
    Parallax,
    /// `parallax` with the sweep's ZNCC matching cost as one more cost-volume channel.
    ParallaxZncc,
    /// `parallax_zncc` with spheres and hypotheses uniform in log depth (the shipped weights).
    ParallaxZnccLog,
    /// `parallax_zncc_log` with the fine head: a readout at the cost volume's full resolution.
    ParallaxZnccLogFine,
    /// The earlier small network with a mean + variance volume, 256x128.
    Compact,
    /// The paper's sizes.
    Paper,
    /// For tests: a few channels and spheres.
    #[cfg_attr(feature = "cli", value(skip))]
    Tiny,
    /// For tests: `tiny` with the parallax (variance-only) volume.
    #[cfg_attr(feature = "cli", value(skip))]
    TinyParallax,
    /// For tests: `tiny_parallax` with the photometric cost channel.
    #[cfg_attr(feature = "cli", value(skip))]
    TinyZncc,
}

impl Preset {
    /// Every preset, in the order of [`SsmodeConfig::PRESETS`].
    pub const ALL: [Self; 9] = [
        Self::Parallax,
        Self::ParallaxZncc,
        Self::ParallaxZnccLog,
        Self::ParallaxZnccLogFine,
        Self::Compact,
        Self::Paper,
        Self::Tiny,
        Self::TinyParallax,
        Self::TinyZncc,
    ];

    /// The configuration's `name` and the preset's name on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Parallax => "parallax",
            Self::ParallaxZncc => "parallax_zncc",
            Self::ParallaxZnccLog => "parallax_zncc_log",
            Self::ParallaxZnccLogFine => "parallax_zncc_log_fine",
            Self::Compact => "compact",
            Self::Paper => "paper",
            Self::Tiny => "tiny",
            Self::TinyParallax => "tiny_parallax",
            Self::TinyZncc => "tiny_zncc",
        }
    }

    pub fn config(self) -> SsmodeConfig {
        match self {
            Self::Parallax => SsmodeConfig::parallax(),
            Self::ParallaxZncc => SsmodeConfig::parallax_zncc(),
            Self::ParallaxZnccLog => SsmodeConfig::parallax_zncc_log(),
            Self::ParallaxZnccLogFine => SsmodeConfig::parallax_zncc_log_fine(),
            Self::Compact => SsmodeConfig::compact(),
            Self::Paper => SsmodeConfig::paper(),
            Self::Tiny => SsmodeConfig::tiny(),
            Self::TinyParallax => SsmodeConfig::tiny_parallax(),
            Self::TinyZncc => SsmodeConfig::tiny_zncc(),
        }
    }
}

impl std::fmt::Display for Preset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Preset {
    type Err = ModelError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|p| p.as_str() == name)
            .ok_or_else(|| ModelError::UnknownPreset {
                name: name.to_string(),
                known: SsmodeConfig::PRESETS.to_string(),
            })
    }
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
            min_depth_m: mode360_core::geometry::sweep::PAPER_MIN_DEPTH_M,
            max_depth_m: mode360_core::geometry::sweep::PAPER_MAX_DEPTH_M,
            hourglass_channels: 32,
            hourglasses: 3,
            cost: CostKind::MeanVariance,
            cost_downsample: FEATURE_DOWNSAMPLE,
            fine_channels: 0,
            aggregation_stride: 1,
            seam_pad_cells: DEFAULT_SEAM_PAD_CELLS,
            photometric_cost: false,
            hypothesis_spacing: HypothesisSpacing::InverseDepth,
            position_channels: false,
            fine_head_channels: 0,
            logit_prior: false,
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
            min_depth_m: mode360_core::geometry::sweep::PAPER_MIN_DEPTH_M,
            max_depth_m: mode360_core::geometry::sweep::PAPER_MAX_DEPTH_M,
            hourglass_channels: 16,
            hourglasses: 2,
            cost: CostKind::MeanVariance,
            cost_downsample: FEATURE_DOWNSAMPLE,
            fine_channels: 0,
            aggregation_stride: 1,
            seam_pad_cells: DEFAULT_SEAM_PAD_CELLS,
            photometric_cost: false,
            hypothesis_spacing: HypothesisSpacing::InverseDepth,
            position_channels: false,
            fine_head_channels: 0,
            logit_prior: false,
        }
    }

    /// The multi-view default: 256x128 input matched at full resolution. Its cost volume has
    /// 256x128 cells (1.4 degrees, so a 1 m baseline's parallax spans a cell out to 40 m) and
    /// 96 spheres (sphere 1 at 45 m), holds only the variance over views (no monocular path),
    /// and is aggregated at half size (48 x 64 x 128) by two hourglasses of 8 channels.
    pub fn parallax() -> Self {
        Self {
            name: "parallax".to_string(),
            width: 256,
            feature_channels: [16, 24, 24, 32],
            feature_blocks: [1, 2, 1, 1],
            feature_out_channels: 8,
            spheres: 96,
            hypotheses: 96,
            min_depth_m: mode360_core::geometry::sweep::PAPER_MIN_DEPTH_M,
            max_depth_m: mode360_core::geometry::sweep::PAPER_MAX_DEPTH_M,
            hourglass_channels: 8,
            hourglasses: 2,
            cost: CostKind::Variance,
            cost_downsample: 1,
            fine_channels: 16,
            aggregation_stride: 2,
            seam_pad_cells: DEFAULT_SEAM_PAD_CELLS,
            photometric_cost: false,
            hypothesis_spacing: HypothesisSpacing::InverseDepth,
            position_channels: false,
            fine_head_channels: 0,
            logit_prior: false,
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
            cost: CostKind::MeanVariance,
            cost_downsample: FEATURE_DOWNSAMPLE,
            fine_channels: 0,
            aggregation_stride: 1,
            // Zero padding, as before the seam wrap: the tests that train a tiny network for a
            // few steps at a high learning rate were measured on it (the wrap has its own).
            seam_pad_cells: 0,
            photometric_cost: false,
            hypothesis_spacing: HypothesisSpacing::InverseDepth,
            position_channels: false,
            fine_head_channels: 0,
            logit_prior: false,
        }
    }

    /// [`Self::tiny`] with the parallax preset's layout (variance-only, fine cost volume,
    /// strided aggregation), for tests.
    pub fn tiny_parallax() -> Self {
        Self {
            name: "tiny_parallax".to_string(),
            feature_out_channels: 4,
            spheres: 16,
            cost: CostKind::Variance,
            cost_downsample: 1,
            fine_channels: 4,
            aggregation_stride: 2,
            ..Self::tiny()
        }
    }

    /// [`Self::parallax`] with the photometric cost channel: the cost volume holds the
    /// variance of the learned features and the sweep's ZNCC matching cost
    /// ([`super::photometric_cost`]), so the aggregation starts from evidence that needs no
    /// training.
    pub fn parallax_zncc() -> Self {
        Self {
            name: "parallax_zncc".to_string(),
            photometric_cost: true,
            ..Self::parallax()
        }
    }

    /// [`Self::parallax_zncc`] with spheres and hypotheses uniform in log depth: every range
    /// gets the same relative resolution (8.3 % per hypothesis), where uniform inverse depth
    /// leaves 10 of 96 spheres (5 of the 48 the aggregation decides on) beyond 5 m.
    pub fn parallax_zncc_log() -> Self {
        Self {
            name: "parallax_zncc_log".to_string(),
            hypothesis_spacing: HypothesisSpacing::LogDepth,
            ..Self::parallax_zncc()
        }
    }

    /// [`Self::parallax_zncc_log`] with the fine head ([`super::fine_head`]) of
    /// [`FINE_HEAD_CHANNELS`]: the hourglasses decide on 2.8-degree cells at 256, a pole at 5
    /// to 8 m is 0.7 to 2 degrees wide, the cost volume's own cells are 1.4.
    pub fn parallax_zncc_log_fine() -> Self {
        Self {
            name: "parallax_zncc_log_fine".to_string(),
            fine_head_channels: FINE_HEAD_CHANNELS,
            ..Self::parallax_zncc_log()
        }
    }

    /// [`Self::tiny_parallax`] with the photometric cost channel, for tests.
    pub fn tiny_zncc() -> Self {
        Self {
            name: "tiny_zncc".to_string(),
            photometric_cost: true,
            ..Self::tiny_parallax()
        }
    }

    /// Names of the presets, for messages.
    pub const PRESETS: &'static str =
        "parallax, parallax_zncc, parallax_zncc_log, parallax_zncc_log_fine, compact, paper, tiny, tiny_parallax, tiny_zncc";

    /// The preset called `name` (see [`Preset`]).
    pub fn preset(name: &str) -> Result<Self, ModelError> {
        Ok(name.parse::<Preset>()?.config())
    }
}
