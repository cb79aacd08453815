//! What to render: the scene kind and the [`SynthConfig`] of a synthetic sequence, its bag
//! metadata and its validation ([`SynthError`]).

use super::blockers::{self, BlockedLens, BlockerError};
use super::street::StreetStyle;
use super::BLOCKED_LENSES_KEY;
use mode360_core::geometry::{ErpGrid, GeometryError};
use std::collections::BTreeMap;

/// Errors of the synthetic renderer's configuration.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("synth config: {0}")]
    Width(#[from] GeometryError),
    #[error("synth config: field '{field}' must be {requirement}, got {value}")]
    BadParameter {
        field: &'static str,
        requirement: &'static str,
        value: f64,
    },
    #[error("synth config: field 'blockers': {0}")]
    Blocker(#[from] BlockerError),
}

/// What a synthetic frame shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum SceneKind {
    /// A procedural street driven along by the rig (see the `world` module).
    #[default]
    Street,
    /// Random textured objects all around the rig, new every frame (see `objects`).
    Objects,
}

impl SceneKind {
    pub fn as_str(self) -> &'static str {
        match self {
            SceneKind::Street => "street",
            SceneKind::Objects => "objects",
        }
    }
}

/// How to render a synthetic sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    /// World seed: everything (layout, textures, traffic, soiling) is a function of it.
    pub seed: u64,
    /// ERP width in pixels; height is `width / 2`.
    pub width: usize,
    /// Apply lens soiling to one or two cameras per frame.
    pub soiled: bool,
    /// Ground-truth range of sky pixels and the clamp for all ranges, metres.
    pub max_depth_m: f64,
    /// Time between frames, seconds.
    pub frame_period_s: f64,
    /// Ego speed along +x, metres per second.
    pub speed_mps: f64,
    /// Street or random objects.
    pub scene: SceneKind,
    /// Street layout variation (street scenes only).
    pub street: StreetStyle,
    /// Lenses blocked in every frame (at most one blocker per camera; cameras the rig lacks
    /// are skipped).
    pub blockers: Vec<BlockedLens>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            width: 512,
            soiled: false,
            max_depth_m: mode360_core::geometry::DEFAULT_MAX_DEPTH_M,
            frame_period_s: 0.1,
            speed_mps: 8.0,
            scene: SceneKind::Street,
            street: StreetStyle::Regular,
            blockers: Vec::new(),
        }
    }
}

impl SynthConfig {
    /// The configuration as text key/value pairs (for bag metadata).
    pub fn to_info(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert(
            "generator".into(),
            format!("mode360::synth {} v1", self.scene.as_str()),
        );
        m.insert("seed".into(), self.seed.to_string());
        m.insert("width".into(), self.width.to_string());
        m.insert("height".into(), (self.width / 2).to_string());
        m.insert("soiled".into(), self.soiled.to_string());
        m.insert("max_depth_m".into(), self.max_depth_m.to_string());
        m.insert("frame_period_s".into(), self.frame_period_s.to_string());
        m.insert("speed_mps".into(), self.speed_mps.to_string());
        m.insert("scene".into(), self.scene.as_str().into());
        m.insert("street".into(), self.street.as_str().into());
        if !self.blockers.is_empty() {
            let specs: Vec<String> = self.blockers.iter().map(BlockedLens::to_spec).collect();
            m.insert(BLOCKED_LENSES_KEY.into(), specs.join(","));
        }
        m
    }

    pub(super) fn validate(&self) -> Result<(), SynthError> {
        ErpGrid::new(self.width)?;
        blockers::validate_blockers(&self.blockers)?;
        let checks: [(&'static str, f64, bool, &'static str); 3] = [
            (
                "max_depth_m",
                self.max_depth_m,
                self.max_depth_m.is_finite() && self.max_depth_m > 0.0,
                "finite and > 0",
            ),
            (
                "frame_period_s",
                self.frame_period_s,
                self.frame_period_s.is_finite() && self.frame_period_s >= 0.0,
                "finite and >= 0",
            ),
            (
                "speed_mps",
                self.speed_mps,
                self.speed_mps.is_finite(),
                "finite",
            ),
        ];
        for (field, value, ok, requirement) in checks {
            if !ok {
                return Err(SynthError::BadParameter {
                    field,
                    requirement,
                    value,
                });
            }
        }
        Ok(())
    }
}
