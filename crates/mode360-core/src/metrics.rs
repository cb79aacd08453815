//! The paper's depth and disparity metrics (section 6.1.3), per frame and averaged over
//! frames.
//!
//! Depth metrics use pixels whose ground truth `g` is finite and in `(0, max_depth]`; with
//! prediction `p`:
//!
//! ```text
//! MAE    = mean |p - g|                  RMSE  = sqrt(mean (p - g)^2)
//! AbsRel = mean |p - g| / g              SqRel = mean (p - g)^2 / g      (standard form;
//!                                                 the paper's reference code divides by g^2)
//! SILog  = 100 sqrt(mean e^2 - (mean e)^2),  e = ln p - ln g
//! deltaK = 100 * fraction of pixels with max(p/g, g/p) < 1.25^K,  K = 1, 2, 3
//! ```
//!
//! A prediction of `+Inf` (REP 117: nothing within range, as the node publishes the sky)
//! counts as `max_depth`, the range ground truth gives the sky. Any other prediction that is
//! not finite and positive on a valid pixel counts as a failure for the
//! delta accuracies and is left out of the error means; `coverage_pct` says how many valid
//! pixels had a usable prediction.
//!
//! Disparity metrics use pixels with finite, non-negative ground truth `g` (in pixels):
//!
//! ```text
//! MAE = mean |p - g|,  RMSE = sqrt(mean (p - g)^2),
//! PxK = 100 * fraction with |p - g| > K px (K = 1, 3, 5),
//! D1  = 100 * fraction with |p - g| > 3 px and |p - g| > 5% of g   (KITTI 2015)
//! ```

use crate::frame::FloatImage;
use crate::geometry::{ErpGrid, GeerPair, GeometryError, PixelCoord, Rig};
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// The delta accuracy base threshold.
pub const DELTA_THRESHOLD: f64 = 1.25;
/// D1's relative threshold (fraction of the ground-truth disparity).
pub const D1_RELATIVE: f64 = 0.05;
/// D1's absolute threshold, pixels.
pub const D1_ABSOLUTE_PX: f64 = 3.0;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricsError {
    #[error("prediction has {pred} pixels but ground truth has {gt}")]
    SizeMismatch { pred: usize, gt: usize },
    #[error("no valid ground-truth pixels")]
    NoValidPixels,
}

/// Depth metrics of one frame or averaged over frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthMetrics {
    pub mae_m: f64,
    pub rmse_m: f64,
    pub abs_rel: f64,
    pub sq_rel_m: f64,
    pub silog: f64,
    pub delta1_pct: f64,
    pub delta2_pct: f64,
    pub delta3_pct: f64,
    pub coverage_pct: f64,
}

/// Disparity metrics of one frame or averaged over frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DisparityMetrics {
    pub mae_px: f64,
    pub rmse_px: f64,
    pub px1_pct: f64,
    pub px3_pct: f64,
    pub px5_pct: f64,
    pub d1_pct: f64,
}

fn check_sizes(pred: &[f32], gt: &[f32]) -> Result<(), MetricsError> {
    if pred.len() != gt.len() {
        return Err(MetricsError::SizeMismatch {
            pred: pred.len(),
            gt: gt.len(),
        });
    }
    Ok(())
}

/// Upper ends of the ground-truth range bands of [`RangeBands`], metres; the last band runs
/// from the last edge to below `max_depth_m`, and the sky (ground truth at `max_depth_m`) is a
/// band of its own.
pub const RANGE_BAND_EDGES_M: [f64; 4] = [5.0, 20.0, 80.0, 300.0];

/// δ1 per ground-truth range band, counted over pixels (not averaged per frame), so that an
/// estimator's losses can be placed: near objects, the street, the far field or the sky.
/// Bands: `(0, 5]`, `(5, 20]`, `(20, 80]`, `(80, 300]`, `(300, max)`, and `max` (the sky).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RangeBands {
    /// Scored pixels per band.
    pub pixels: Vec<u64>,
    /// Pixels within δ1 per band.
    pub within_delta1: Vec<u64>,
    /// Misses read too far per band: predicted at least `DELTA_THRESHOLD` times the truth
    /// (out of range counts at `max_depth_m`). The rest of a band's misses are too near or
    /// have no usable prediction. Empty in reports written before it was counted.
    #[serde(default)]
    pub too_far: Vec<u64>,
}

impl RangeBands {
    /// Number of bands: one per edge, the rest below the maximum, and the sky.
    pub const COUNT: usize = RANGE_BAND_EDGES_M.len() + 2;

    /// Band names for tables.
    pub fn labels(max_depth_m: f64) -> Vec<String> {
        let mut labels = Vec::with_capacity(Self::COUNT);
        let mut lower = 0.0;
        for edge in RANGE_BAND_EDGES_M {
            labels.push(format!("{lower:.0}-{edge:.0} m"));
            lower = edge;
        }
        labels.push(format!("{lower:.0}-{max_depth_m:.0} m"));
        labels.push(format!("sky ({max_depth_m:.0} m)"));
        labels
    }

    /// Adds one frame (same validity rules as [`depth_metrics`]; a pixel without a usable
    /// prediction counts as a miss).
    pub fn add_frame(&mut self, pred: &[f32], gt: &[f32], max_depth_m: f64) {
        if self.pixels.len() != Self::COUNT {
            self.pixels = vec![0; Self::COUNT];
            self.within_delta1 = vec![0; Self::COUNT];
            self.too_far = vec![0; Self::COUNT];
        }
        for (&p, &g) in pred.iter().zip(gt) {
            let (p, g) = (p as f64, g as f64);
            if !(g.is_finite() && g > 0.0 && g <= max_depth_m) {
                continue;
            }
            let band = if g >= max_depth_m {
                Self::COUNT - 1
            } else {
                RANGE_BAND_EDGES_M
                    .iter()
                    .position(|&edge| g <= edge)
                    .unwrap_or(RANGE_BAND_EDGES_M.len())
            };
            self.pixels[band] += 1;
            let p = if p == f64::INFINITY { max_depth_m } else { p };
            if p.is_finite() && p > 0.0 && (p / g).max(g / p) < DELTA_THRESHOLD {
                self.within_delta1[band] += 1;
            } else if p.is_finite() && p / g >= DELTA_THRESHOLD {
                self.too_far[band] += 1;
            }
        }
    }

    /// Share (%) of each band's misses that read too far (the obstacle melted into what
    /// stands behind it, or read as sky): `100 too_far / (pixels - within_delta1)`; `None`
    /// for a band without misses or a report without the count.
    pub fn too_far_pct(&self) -> Vec<Option<f64>> {
        if self.too_far.len() != self.pixels.len() {
            return vec![None; self.pixels.len()];
        }
        self.pixels
            .iter()
            .zip(&self.within_delta1)
            .zip(&self.too_far)
            .map(|((&n, &k), &far)| {
                let misses = n.saturating_sub(k);
                (misses > 0).then(|| 100.0 * far as f64 / misses as f64)
            })
            .collect()
    }

    /// δ1 (%) per band, `None` for a band without pixels.
    pub fn delta1_pct(&self) -> Vec<Option<f64>> {
        self.pixels
            .iter()
            .zip(&self.within_delta1)
            .map(|(&n, &k)| (n > 0).then(|| 100.0 * k as f64 / n as f64))
            .collect()
    }

    /// Share (%) of the scored pixels in each band.
    pub fn share_pct(&self) -> Vec<f64> {
        let total = self.pixels.iter().sum::<u64>().max(1) as f64;
        self.pixels
            .iter()
            .map(|&n| 100.0 * n as f64 / total)
            .collect()
    }
}

/// Depth metrics of one frame (see the module docs).
pub fn depth_metrics(
    pred: &[f32],
    gt: &[f32],
    max_depth_m: f64,
) -> Result<DepthMetrics, MetricsError> {
    check_sizes(pred, gt)?;
    let (mut n_valid, mut n_used) = (0usize, 0usize);
    let (mut abs, mut sq, mut abs_rel, mut sq_rel, mut e_sum, mut e2_sum) =
        (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut within = [0usize; 3];
    let thresholds = [
        DELTA_THRESHOLD,
        DELTA_THRESHOLD.powi(2),
        DELTA_THRESHOLD.powi(3),
    ];
    for (&p, &g) in pred.iter().zip(gt) {
        let (p, g) = (p as f64, g as f64);
        if !(g.is_finite() && g > 0.0 && g <= max_depth_m) {
            continue;
        }
        n_valid += 1;
        let p = if p == f64::INFINITY { max_depth_m } else { p };
        if !(p.is_finite() && p > 0.0) {
            continue;
        }
        n_used += 1;
        let diff = p - g;
        abs += diff.abs();
        sq += diff * diff;
        abs_rel += diff.abs() / g;
        sq_rel += diff * diff / g;
        let e = p.ln() - g.ln();
        e_sum += e;
        e2_sum += e * e;
        let ratio = (p / g).max(g / p);
        for (w, t) in within.iter_mut().zip(thresholds) {
            if ratio < t {
                *w += 1;
            }
        }
    }
    if n_valid == 0 {
        return Err(MetricsError::NoValidPixels);
    }
    let pct = |k: usize| 100.0 * k as f64 / n_valid as f64;
    let used = n_used.max(1) as f64;
    let mean_e = e_sum / used;
    Ok(DepthMetrics {
        mae_m: abs / used,
        rmse_m: (sq / used).sqrt(),
        abs_rel: abs_rel / used,
        sq_rel_m: sq_rel / used,
        silog: 100.0 * (e2_sum / used - mean_e * mean_e).max(0.0).sqrt(),
        delta1_pct: pct(within[0]),
        delta2_pct: pct(within[1]),
        delta3_pct: pct(within[2]),
        coverage_pct: pct(n_used),
    })
}

/// Disparity metrics of one frame (see the module docs). A non-finite prediction is read as
/// disparity 0 (a point at infinity).
pub fn disparity_metrics(pred_px: &[f32], gt_px: &[f32]) -> Result<DisparityMetrics, MetricsError> {
    check_sizes(pred_px, gt_px)?;
    let mut n = 0usize;
    let (mut abs, mut sq) = (0.0f64, 0.0f64);
    let mut outliers = [0usize; 4];
    for (&p, &g) in pred_px.iter().zip(gt_px) {
        let g = g as f64;
        if !(g.is_finite() && g >= 0.0) {
            continue;
        }
        n += 1;
        let p = if p.is_finite() { p as f64 } else { 0.0 };
        let err = (p - g).abs();
        abs += err;
        sq += err * err;
        for (o, k) in outliers.iter_mut().zip([1.0, 3.0, 5.0]) {
            if err > k {
                *o += 1;
            }
        }
        if err > D1_ABSOLUTE_PX && err > D1_RELATIVE * g {
            outliers[3] += 1;
        }
    }
    if n == 0 {
        return Err(MetricsError::NoValidPixels);
    }
    let pct = |k: usize| 100.0 * k as f64 / n as f64;
    Ok(DisparityMetrics {
        mae_px: abs / n as f64,
        rmse_px: (sq / n as f64).sqrt(),
        px1_pct: pct(outliers[0]),
        px3_pct: pct(outliers[1]),
        px5_pct: pct(outliers[2]),
        d1_pct: pct(outliers[3]),
    })
}

/// Averages per-frame metrics over frames (the paper reports per-frame means).
#[derive(Clone, Debug, Default)]
pub struct FrameAverage {
    depth: Vec<DepthMetrics>,
    disparity: Vec<DisparityMetrics>,
}

macro_rules! mean_of {
    ($items:expr, $ty:ident { $($f:ident),* }) => {{
        let n = $items.len().max(1) as f64;
        $ty { $($f: $items.iter().map(|m| m.$f).sum::<f64>() / n),* }
    }};
}

impl FrameAverage {
    pub fn push(&mut self, depth: DepthMetrics, disparity: Option<DisparityMetrics>) {
        self.depth.push(depth);
        self.disparity.extend(disparity);
    }

    pub fn frames(&self) -> usize {
        self.depth.len()
    }

    pub fn depth(&self) -> DepthMetrics {
        mean_of!(
            self.depth,
            DepthMetrics {
                mae_m,
                rmse_m,
                abs_rel,
                sq_rel_m,
                silog,
                delta1_pct,
                delta2_pct,
                delta3_pct,
                coverage_pct
            }
        )
    }

    pub fn disparity(&self) -> Option<DisparityMetrics> {
        (!self.disparity.is_empty()).then(|| {
            mean_of!(
                self.disparity,
                DisparityMetrics {
                    mae_px,
                    rmse_px,
                    px1_pct,
                    px3_pct,
                    px5_pct,
                    d1_pct
                }
            )
        })
    }
}

/// GEER pair for the disparity metrics: the reference camera and the next camera of the rig, GEER width = ERP height.
pub fn reference_disparity_pair(rig: &Rig, output: ErpGrid) -> Result<GeerPair, GeometryError> {
    let other = (rig.reference + 1) % rig.cameras.len();
    GeerPair::new(
        rig.camera_origin(rig.reference),
        rig.camera_origin(other),
        Vector3::z(),
        output.height(),
    )
}

/// Converts an output-frame range image to the pair's angular disparity in GEER pixels.
/// Non-finite ranges give NaN.
pub fn disparity_image(
    rig: &Rig,
    output: ErpGrid,
    pair: &GeerPair,
    range_m: &FloatImage,
) -> Vec<f32> {
    range_m
        .data
        .iter()
        .enumerate()
        .map(|(k, &rho)| {
            if !(rho.is_finite() && rho > 0.0) {
                return f32::NAN;
            }
            let p = PixelCoord {
                u: (k % output.width()) as f64,
                v: (k / output.width()) as f64,
            };
            let p_out = output.dir_from_pixel(p) * rho as f64;
            let p_rig = rig.rig_from_output * Point3::from(p_out);
            pair.disparity_px(pair.point_disparity(&p_rig.coords).disparity_rad) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// Three valid pixels worked by hand, one invalid (beyond max depth), one NaN gt.
    /// p = [2, 9, 5], g = [1, 10, 4]
    #[test]
    fn depth_metrics_by_hand() {
        let pred = [2.0, 9.0, 5.0, 7.0, 3.0];
        let gt = [1.0, 10.0, 4.0, 2000.0, f32::NAN];
        let m = depth_metrics(&pred, &gt, 1000.0).unwrap();
        // |p-g| = 1, 1, 1
        assert_relative_eq!(m.mae_m, 1.0, epsilon = 1e-12);
        assert_relative_eq!(m.rmse_m, 1.0, epsilon = 1e-12);
        // AbsRel = (1/1 + 1/10 + 1/4) / 3 = 1.35 / 3
        assert_relative_eq!(m.abs_rel, 1.35 / 3.0, epsilon = 1e-12);
        // SqRel = (1/1 + 1/10 + 1/4) / 3 as well (all squared errors are 1)
        assert_relative_eq!(m.sq_rel_m, 1.35 / 3.0, epsilon = 1e-12);
        // e = ln2, ln0.9, ln1.25
        let e = [2f64.ln(), 0.9f64.ln(), 1.25f64.ln()];
        let mean = e.iter().sum::<f64>() / 3.0;
        let var = e.iter().map(|x| x * x).sum::<f64>() / 3.0 - mean * mean;
        assert_relative_eq!(m.silog, 100.0 * var.sqrt(), epsilon = 1e-9);
        // ratios 2, 1.111, 1.25: < 1.25 only the second; < 1.5625 the second and third (1.25);
        // < 1.953 still two (2 is not below 1.953125).
        assert_relative_eq!(m.delta1_pct, 100.0 / 3.0, epsilon = 1e-9);
        assert_relative_eq!(m.delta2_pct, 200.0 / 3.0, epsilon = 1e-9);
        assert_relative_eq!(m.delta3_pct, 200.0 / 3.0, epsilon = 1e-9);
        assert_relative_eq!(m.coverage_pct, 100.0, epsilon = 1e-12);
    }

    #[test]
    fn nan_prediction_is_a_failure_not_an_average_term() {
        let m = depth_metrics(&[f32::NAN, 10.0], &[5.0, 10.0], 100.0).unwrap();
        assert_relative_eq!(m.mae_m, 0.0);
        assert_relative_eq!(m.delta1_pct, 50.0);
        assert_relative_eq!(m.coverage_pct, 50.0);
    }

    #[test]
    fn an_infinite_prediction_is_the_sky_at_max_depth() {
        // REP 117's +Inf scores as max_depth: right for the sky, wrong for a near wall.
        let m = depth_metrics(&[f32::INFINITY, f32::INFINITY], &[100.0, 10.0], 100.0).unwrap();
        assert_eq!(m.delta1_pct, 50.0);
        assert_eq!(m.coverage_pct, 100.0);
        assert!((m.mae_m - 45.0).abs() < 1e-9, "{m:?}");
    }

    #[test]
    fn errors() {
        assert_eq!(
            depth_metrics(&[1.0], &[1.0, 2.0], 10.0),
            Err(MetricsError::SizeMismatch { pred: 1, gt: 2 })
        );
        assert_eq!(
            depth_metrics(&[1.0], &[f32::NAN], 10.0),
            Err(MetricsError::NoValidPixels)
        );
    }

    /// p = [10, 12, 0.5, 40, NaN], g = [10, 10, 2, 50, 4]:
    /// errors 0, 2, 1.5, 10, 4 (NaN read as 0).
    #[test]
    fn disparity_metrics_by_hand() {
        let m = disparity_metrics(
            &[10.0, 12.0, 0.5, 40.0, f32::NAN],
            &[10.0, 10.0, 2.0, 50.0, 4.0],
        )
        .unwrap();
        assert_relative_eq!(m.mae_px, 17.5 / 5.0, epsilon = 1e-12);
        assert_relative_eq!(
            m.rmse_px,
            ((4.0 + 2.25 + 100.0 + 16.0) / 5.0f64).sqrt(),
            epsilon = 1e-12
        );
        assert_relative_eq!(m.px1_pct, 80.0); // 2, 1.5, 10, 4
        assert_relative_eq!(m.px3_pct, 40.0); // 10, 4
        assert_relative_eq!(m.px5_pct, 20.0); // 10
                                              // D1: >3 px and >5% of g: 10 (>2.5) yes; 4 (>0.2) yes.
        assert_relative_eq!(m.d1_pct, 40.0);
    }

    #[test]
    fn frame_average_is_a_per_frame_mean() {
        let mut avg = FrameAverage::default();
        let a = depth_metrics(&[2.0], &[1.0], 10.0).unwrap();
        let b = depth_metrics(&[1.0, 1.0, 1.0], &[1.0, 1.0, 1.0], 10.0).unwrap();
        avg.push(a, None);
        avg.push(b, None);
        assert_eq!(avg.frames(), 2);
        assert_relative_eq!(avg.depth().mae_m, 0.5);
        assert_relative_eq!(avg.depth().delta1_pct, 50.0);
        assert!(avg.disparity().is_none());
    }

    #[test]
    fn range_bands_split_misses_into_too_far_and_too_near() {
        // 10 m read at 5 m (too near), 20 m (too far) and 11 m (a hit); 3 m read as NaN (a
        // miss, neither way)
        let gt = [10.0, 10.0, 10.0, 3.0];
        let pred = [5.0, 20.0, 11.0, f32::NAN];
        let mut bands = RangeBands::default();
        bands.add_frame(&pred, &gt, 1000.0);
        assert_eq!(bands.within_delta1[1], 1);
        assert_eq!(bands.too_far[1], 1);
        let far = bands.too_far_pct();
        assert_eq!(far[1], Some(50.0));
        assert_eq!(far[0], Some(0.0));
        // a report written before the count: no share, not zero
        let old = RangeBands {
            too_far: Vec::new(),
            ..bands
        };
        assert!(old.too_far_pct().iter().all(Option::is_none));
    }

    #[test]
    fn range_bands_place_each_pixel_and_count_misses() {
        // gt 2 m: hit; 10 m: miss; 50 m: hit; 200 m predicted +Inf (scored as 1000 m): miss;
        // 500 m: hit; the sky: hit; NaN ground truth: ignored.
        let gt = [2.0, 10.0, 50.0, 200.0, 500.0, 1000.0, f32::NAN];
        let pred = [2.1, 20.0, 45.0, f32::INFINITY, 450.0, f32::INFINITY, 3.0];
        let mut bands = RangeBands::default();
        bands.add_frame(&pred, &gt, 1000.0);
        bands.add_frame(&pred, &gt, 1000.0);
        assert_eq!(bands.pixels, vec![2, 2, 2, 2, 2, 2]);
        assert_eq!(bands.within_delta1, vec![2, 0, 2, 0, 2, 2]);
        // both misses read too far (20 m for 10 m, out of range for 200 m)
        assert_eq!(bands.too_far, vec![0, 2, 0, 2, 0, 0]);
        let far = bands.too_far_pct();
        assert_eq!(far[0], None);
        assert_eq!(far[1], Some(100.0));
        assert_eq!(far[3], Some(100.0));
        let d = bands.delta1_pct();
        assert_eq!(d[1], Some(0.0));
        assert_eq!(d[5], Some(100.0));
        assert_relative_eq!(bands.share_pct().iter().sum::<f64>(), 100.0);
        assert_eq!(RangeBands::labels(1000.0).len(), RangeBands::COUNT);
        assert_eq!(RangeBands::labels(1000.0)[4], "300-1000 m");
    }
}
