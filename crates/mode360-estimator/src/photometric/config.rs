//! Settings of the photometric sweep ([`PhotometricConfig`], with its semi-global
//! aggregation's [`AggregationConfig`]) and their validation.

use crate::EstimatorError;
use mode360_core::geometry::{DepthHypotheses, DepthRange};
use serde::{Deserialize, Serialize};

/// Semi-global aggregation settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AggregationConfig {
    /// Aggregate along rows and columns; `false` gives plain windowed winner-take-all.
    pub enabled: bool,
    /// Penalty for a one-hypothesis change between neighbouring pixels (cost units).
    pub p1: f32,
    /// Penalty for a larger change (cost units).
    pub p2: f32,
    /// Guide-image intensity step (in [0, 1]) at which `p2` is halved; 0 keeps `p2` fixed.
    pub edge_scale: f32,
    /// Columns a row path runs before it starts accumulating, so the longitude seam is seamless.
    pub row_warmup_px: usize,
}

impl Default for AggregationConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            p1: 0.03,
            p2: 0.6,
            edge_scale: 0.02,
            row_warmup_px: 64,
        }
    }
}

/// Settings of [`PhotometricSweep`](super::PhotometricSweep).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PhotometricConfig {
    /// Number of spheres, uniform in inverse depth.
    pub hypotheses: usize,
    /// Swept depth range; the farthest sphere is `max_depth_m` (sky).
    pub depth_range: DepthRange,
    /// ZNCC window is `(2 r + 1)^2` pixels.
    pub window_radius_px: usize,
    /// Added to each window variance (intensity in [0, 1]) so flat windows score ZNCC 0.
    pub variance_floor: f32,
    /// Weight of the window-mean difference term in the pair cost, in [0, 1].
    pub mean_weight: f32,
    /// Mean intensity difference at which the mean term saturates.
    pub mean_scale: f32,
    /// Fraction of camera pairs (the best ones) averaged per pixel, in (0, 1] (of the pairs
    /// that see the pixel).
    pub best_pair_fraction: f32,
    /// Blend each pair's cost toward undecided by `1 - sin(angle(ray, baseline))^k`, with
    /// `k = parallax_exponent`; 0 turns the weighting off.
    pub parallax_exponent: f32,
    pub aggregation: AggregationConfig,
    /// Cost added per unit of normalized hypothesis index (`i / (D - 1)`), so that flat,
    /// undecided cost curves (sky) resolve to the far end.
    pub far_prior: f32,
    /// Cost margin (per pixel and path) at which the confidence reaches 1/2.
    pub confidence_margin: f32,
}

impl Default for PhotometricConfig {
    fn default() -> Self {
        Self {
            hypotheses: 128,
            depth_range: DepthRange::paper(),
            window_radius_px: 2,
            variance_floor: 1e-6,
            mean_weight: 0.3,
            mean_scale: 0.03,
            best_pair_fraction: 0.5,
            parallax_exponent: 1.0,
            aggregation: AggregationConfig::default(),
            far_prior: 0.02,
            confidence_margin: 0.05,
        }
    }
}

impl PhotometricConfig {
    /// The swept hypotheses, or an error naming the first field out of its range.
    pub(super) fn validate(&self) -> Result<DepthHypotheses, EstimatorError> {
        let bad = |field: &str, problem: String| EstimatorError::BadConfig {
            field: field.to_string(),
            problem,
        };
        let range = DepthRange::new(self.depth_range.min_depth_m, self.depth_range.max_depth_m)?;
        let hypotheses = DepthHypotheses::new(range, self.hypotheses)?;
        let unit = |field: &str, x: f32, allow_zero: bool| {
            if x.is_finite() && x <= 1.0 && (x > 0.0 || (allow_zero && x == 0.0)) {
                Ok(())
            } else {
                Err(bad(field, format!("{x} is outside its range (0, 1]")))
            }
        };
        unit("mean_weight", self.mean_weight, true)?;
        unit("best_pair_fraction", self.best_pair_fraction, false)?;
        for (field, x) in [
            ("variance_floor", self.variance_floor),
            ("mean_scale", self.mean_scale),
            ("confidence_margin", self.confidence_margin),
            ("parallax_exponent", self.parallax_exponent + 1.0),
            ("far_prior", self.far_prior + 1.0),
            ("aggregation.edge_scale", self.aggregation.edge_scale + 1.0),
        ] {
            if !(x.is_finite() && x > 0.0) {
                return Err(bad(field, format!("{x} must be finite and positive")));
            }
        }
        let agg = &self.aggregation;
        if !(agg.p1.is_finite() && agg.p2.is_finite() && agg.p1 >= 0.0 && agg.p2 >= agg.p1) {
            return Err(bad(
                "aggregation",
                format!("need 0 <= p1 <= p2, got p1 {} p2 {}", agg.p1, agg.p2),
            ));
        }
        Ok(hypotheses)
    }
}
