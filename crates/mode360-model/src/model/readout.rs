//! How SSMODE's output is read: the far-plane test, the near mode and the edge refinement.
//! Inference settings chosen on the validation split, not the network's shape: an estimator
//! setting with defaults ([`Readout::default`]), overridden per command
//! (`--far-plane-probability`, `--far-parallax-cells`, `--near-mode-probability`,
//! `--refine-radius-cells`). Weights files do not carry them; a file
//! written before they were settings carries the values it was tuned with in its config
//! metadata, which are that file's defaults ([`Readout::recorded`]).

use serde::{Deserialize, Serialize};

use super::ModelError;

/// [`Readout::far_plane_probability`] by default: with the far field of
/// [`DEFAULT_FAR_PARALLAX_CELLS`], the best of 0.4, 0.5, 0.65 and 0.8 on the validation seed
/// 2^63 + 3131 at 512 (models/README.md, "Readout"). Files written before the far field carry
/// 0.8.
pub const DEFAULT_FAR_PLANE_PROBABILITY: f64 = 0.5;
/// [`Readout::far_parallax_cells`] by default: the best of 0.125 to 1 cells on the validation
/// seed (models/README.md, "Readout").
pub const DEFAULT_FAR_PARALLAX_CELLS: f64 = 0.25;
/// [`Readout::near_mode_probability`] by default: the best of 0.05 to 0.3 on the validation
/// seed 2^63 + 3131 at 512 (models/README.md, "The near mode").
pub const DEFAULT_NEAR_MODE_PROBABILITY: f64 = 0.2;
/// [`Readout::near_mode_probability`] that turns the near mode off (any value above 1 does:
/// no window holds more than all the probability).
pub const NEAR_MODE_OFF: f64 = 2.0;
/// [`Readout::refine_radius_cells`] by default: a 5x5 window, the best of 1 to 6 cells on the
/// validation seed 2^63 + 3131 at 512 (models/README.md, "Edge refinement").
pub const DEFAULT_REFINE_RADIUS_CELLS: usize = 2;
/// The largest [`Readout::refine_radius_cells`] accepted: beyond it the median erases whole
/// objects.
pub const MAX_REFINE_RADIUS_CELLS: usize = 8;

/// The readout's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Readout {
    /// Far-plane test: a pixel whose probability on the far field's hypotheses is at least
    /// this is given `max_depth_m` instead of the soft-argmin (see [`super::regression`]);
    /// above 1 turns it off.
    pub far_plane_probability: f64,
    /// Far field: hypotheses whose samples move, for every camera pair, by less than this many
    /// cost-volume cells from the far plane's count as the far plane in the far-plane test
    /// ([`mode360_core::geometry::FarField`]); 0 counts the far plane alone.
    pub far_parallax_cells: f64,
    /// Near mode: a pixel whose nearest local mode of the hypothesis distribution holds at
    /// least this probability reads that mode where it is markedly nearer than the
    /// expectation (see [`super::regression`]); above 1 turns it off.
    pub near_mode_probability: f64,
    /// Edge refinement: the radius in network cells of the confidence-weighted median that
    /// cleans the range before it is upsampled to the output; 0 turns it off.
    pub refine_radius_cells: usize,
}

impl Default for Readout {
    fn default() -> Self {
        Self {
            far_plane_probability: DEFAULT_FAR_PLANE_PROBABILITY,
            far_parallax_cells: DEFAULT_FAR_PARALLAX_CELLS,
            near_mode_probability: DEFAULT_NEAR_MODE_PROBABILITY,
            refine_radius_cells: DEFAULT_REFINE_RADIUS_CELLS,
        }
    }
}

/// The config metadata keys of a file written before the readout was a setting.
pub const RECORDED_KEYS: [&str; 3] = [
    "far_plane_probability",
    "far_parallax_cells",
    "refine_radius_cells",
];

impl Readout {
    /// The readout a weights file's config metadata `config` records (files written before
    /// the readout was a setting), each missing value the default; an error naming the key
    /// for a value of the wrong type or out of range.
    pub fn recorded(
        config: &serde_json::Map<String, serde_json::Value>,
    ) -> Result<Self, ModelError> {
        let mut readout = Self::default();
        let number = |key: &str| -> Result<Option<f64>, ModelError> {
            config
                .get(key)
                .map(|v| {
                    v.as_f64().ok_or_else(|| ModelError::BadConfig {
                        field: key.to_string(),
                        problem: format!("{v} is not a number"),
                    })
                })
                .transpose()
        };
        if let Some(p) = number("far_plane_probability")? {
            readout.far_plane_probability = p;
        }
        if let Some(cells) = number("far_parallax_cells")? {
            readout.far_parallax_cells = cells;
        }
        if let Some(v) = config.get("refine_radius_cells") {
            readout.refine_radius_cells = v
                .as_u64()
                .and_then(|r| usize::try_from(r).ok())
                .ok_or_else(|| ModelError::BadConfig {
                    field: "refine_radius_cells".to_string(),
                    problem: format!("{v} is not a cell count"),
                })?;
        }
        readout.validate()?;
        Ok(readout)
    }

    /// Checks every setting's range, naming the first one out of it.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |field: &str, problem: String| {
            Err(ModelError::BadConfig {
                field: field.to_string(),
                problem,
            })
        };
        if self.far_plane_probability.is_nan() || self.far_plane_probability <= 0.0 {
            return bad(
                "far_plane_probability",
                format!("{} must be positive", self.far_plane_probability),
            );
        }
        if self.near_mode_probability.is_nan() || self.near_mode_probability <= 0.0 {
            return bad(
                "near_mode_probability",
                format!("{} must be positive", self.near_mode_probability),
            );
        }
        if !(self.far_parallax_cells >= 0.0 && self.far_parallax_cells.is_finite()) {
            return bad(
                "far_parallax_cells",
                format!("{} must be finite and at least 0", self.far_parallax_cells),
            );
        }
        if self.refine_radius_cells > MAX_REFINE_RADIUS_CELLS {
            return bad(
                "refine_radius_cells",
                format!(
                    "{} is above the largest accepted, {MAX_REFINE_RADIUS_CELLS}",
                    self.refine_radius_cells
                ),
            );
        }
        Ok(())
    }

    /// This readout for the network run at input width `width` instead of `trained_width`:
    /// the far field's threshold, counted in cost cells, scales with the width so that it
    /// stays the same angle (`far_parallax_cells width / trained_width`); the rest is kept.
    pub fn at_width(self, trained_width: usize, width: usize) -> Self {
        Self {
            far_parallax_cells: self.far_parallax_cells * width as f64
                / trained_width.max(1) as f64,
            ..self
        }
    }
}

/// Readout settings asked for on a command line or by the node, each replacing the weights
/// file's ([`Readout::recorded`], else the default) where given.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReadoutOverrides {
    pub far_plane_probability: Option<f64>,
    pub far_parallax_cells: Option<f64>,
    pub near_mode_probability: Option<f64>,
    pub refine_radius_cells: Option<usize>,
}

impl ReadoutOverrides {
    /// Whether nothing is overridden.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// `base` with these settings, checked ([`Readout::validate`]).
    pub fn apply(&self, base: Readout) -> Result<Readout, ModelError> {
        let readout = Readout {
            far_plane_probability: self
                .far_plane_probability
                .unwrap_or(base.far_plane_probability),
            far_parallax_cells: self.far_parallax_cells.unwrap_or(base.far_parallax_cells),
            near_mode_probability: self
                .near_mode_probability
                .unwrap_or(base.near_mode_probability),
            refine_radius_cells: self.refine_radius_cells.unwrap_or(base.refine_radius_cells),
        };
        readout.validate()?;
        Ok(readout)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recorded_values_override_the_defaults_and_bad_ones_are_named() {
        let map = |json: serde_json::Value| json.as_object().cloned().unwrap();
        let old =
            Readout::recorded(&map(serde_json::json!({"far_plane_probability": 0.8}))).unwrap();
        assert_eq!(
            old,
            Readout {
                far_plane_probability: 0.8,
                ..Readout::default()
            }
        );
        assert_eq!(
            Readout::recorded(&map(serde_json::json!({}))).unwrap(),
            Readout::default()
        );
        for (json, field) in [
            (
                serde_json::json!({"far_parallax_cells": -1.0}),
                "far_parallax_cells",
            ),
            (
                serde_json::json!({"refine_radius_cells": 9}),
                "refine_radius_cells",
            ),
            (
                serde_json::json!({"refine_radius_cells": 1.5}),
                "refine_radius_cells",
            ),
            (
                serde_json::json!({"far_plane_probability": "high"}),
                "far_plane_probability",
            ),
        ] {
            let e = Readout::recorded(&map(json)).unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
        let set = ReadoutOverrides {
            refine_radius_cells: Some(0),
            ..ReadoutOverrides::default()
        };
        assert_eq!(set.apply(old).unwrap().refine_radius_cells, 0);
        assert_eq!(set.apply(old).unwrap().far_plane_probability, 0.8);
        let e = ReadoutOverrides {
            far_plane_probability: Some(0.0),
            ..ReadoutOverrides::default()
        }
        .apply(old)
        .unwrap_err()
        .to_string();
        assert!(e.contains("far_plane_probability"), "{e}");
        for bad in [0.0, -0.2, f64::NAN] {
            let e = ReadoutOverrides {
                near_mode_probability: Some(bad),
                ..ReadoutOverrides::default()
            }
            .apply(old)
            .unwrap_err()
            .to_string();
            assert!(e.contains("near_mode_probability"), "{e}");
        }
        let off = ReadoutOverrides {
            near_mode_probability: Some(NEAR_MODE_OFF),
            ..ReadoutOverrides::default()
        };
        assert_eq!(off.apply(old).unwrap().near_mode_probability, NEAR_MODE_OFF);
        assert_eq!(
            Readout::default().at_width(256, 512).far_parallax_cells,
            0.5
        );
    }
}
