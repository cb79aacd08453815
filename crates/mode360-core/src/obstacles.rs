//! Obstacle metrics (design.md, "Metrics"): pixel-averaged δ1 hides the few pixels of the
//! things a vehicle must not drive into, so these score object instances and near pixels.
//!
//! With per-pixel labels of the output frame ([`SceneLabels`]), ground truth `g` and
//! prediction `p` (NaN: no estimate; `+Inf` or `p >= max_depth`: out of range, scored as
//! `max_depth`):
//!
//! ```text
//! counted instance:  class Object, median g <= 10 m, pixels >= 20 (W / 512)^2
//! recovered:         |median p - median g| <= 0.25 median g   (NaN pixels left out;
//!                                                             all NaN: not recovered)
//! band:              median g in [0, 2], (2, 5] or (5, 10] m
//! thin:              widest row of the instance < 3 degrees of longitude (count 360 / W)
//! near δ1 (objects): 100 * share of object pixels with g <= 5 m and max(p/g, g/p) < 1.25
//! near δ1 (all):     the same over every pixel with g <= 5 m
//! phantom:           100 * share of non-sky pixels with g <= 50 m and p > 1.25 g
//! out of range:      100 * share of the same pixels with p out of range
//! ```
//!
//! Recall pools instances over frames; the pixel shares are per-frame means, and every
//! measure also keeps its worst frame.

use crate::frame::{SceneLabels, SurfaceClass, NO_INSTANCE};
use crate::metrics::{MetricsError, DELTA_THRESHOLD};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

mod summary;

pub use summary::{
    BandRecall, BandRecallThin, MeasureSummary, ObstacleCounts, ObstacleMeasure, ObstacleMiss,
    ObstacleReport, ObstacleSummary, WorstFrame,
};

/// Instances whose median true range is beyond this are not counted, metres.
pub const OBSTACLE_MAX_RANGE_M: f64 = 10.0;
/// Fewest pixels of a counted instance at [`REFERENCE_WIDTH_PX`] (scaled by area).
pub const OBSTACLE_MIN_PIXELS: f64 = 20.0;
/// The output width at which [`OBSTACLE_MIN_PIXELS`] holds.
pub const REFERENCE_WIDTH_PX: f64 = 512.0;
/// An instance is recovered when its median prediction is within this share of the truth.
pub const RECOVERED_REL_TOLERANCE: f64 = 0.25;
/// Instances whose widest row spans less than this are thin, degrees of longitude.
pub const THIN_MAX_WIDTH_DEG: f64 = 3.0;
/// Upper edge of the near δ1's pixels, metres.
pub const NEAR_RANGE_M: f64 = 5.0;
/// Upper edge of the phantom free space's pixels, metres.
pub const PHANTOM_MAX_RANGE_M: f64 = 50.0;
/// How many of the worst misses a summary lists.
pub const WORST_MISSES: usize = 10;

/// Bands of an instance's median true range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleBand {
    /// [0, 2] m.
    Within2m,
    /// (2, 5] m.
    From2To5m,
    /// (5, 10] m.
    From5To10m,
}

impl ObstacleBand {
    pub const ALL: [ObstacleBand; 3] = [Self::Within2m, Self::From2To5m, Self::From5To10m];
    /// Upper edges of the bands, metres.
    pub const UPPER_EDGES_M: [f64; 3] = [2.0, 5.0, OBSTACLE_MAX_RANGE_M];

    /// The band of median true range `range_m`, `None` beyond the last.
    pub fn of(range_m: f64) -> Option<Self> {
        Self::ALL
            .into_iter()
            .zip(Self::UPPER_EDGES_M)
            .find(|(_, upper)| range_m <= *upper)
            .map(|(band, _)| band)
    }

    pub fn label(self) -> &'static str {
        match self {
            Self::Within2m => "0-2 m",
            Self::From2To5m => "2-5 m",
            Self::From5To10m => "5-10 m",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// A count of hits out of a total.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ratio {
    pub hits: u64,
    pub total: u64,
}

impl Ratio {
    /// `100 hits / total`, `None` when nothing was counted.
    pub fn pct(&self) -> Option<f64> {
        (self.total > 0).then(|| 100.0 * self.hits as f64 / self.total as f64)
    }

    fn add(&mut self, hit: bool) {
        self.total += 1;
        self.hits += u64::from(hit);
    }

    fn merge(&mut self, other: &Ratio) {
        self.hits += other.hits;
        self.total += other.total;
    }
}

/// One counted object instance of a frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObstacleScore {
    pub instance: u16,
    pub pixels: usize,
    pub true_range_m: f64,
    /// Median prediction over the instance's pixels with an estimate (`None`: none had one).
    pub pred_range_m: Option<f64>,
    /// Longitude span of the instance's widest row, degrees.
    pub width_deg: f64,
    /// Share of its pixels predicted out of range, %.
    pub out_of_range_pct: f64,
    /// Median latitude of its pixels in the output frame, degrees (negative: below the
    /// horizon; about -45 and lower: beneath the rig); 0 in reports written before it existed.
    #[serde(default)]
    pub elevation_deg: f64,
    pub recovered: bool,
}

impl ObstacleScore {
    pub fn band(&self) -> Option<ObstacleBand> {
        ObstacleBand::of(self.true_range_m)
    }

    pub fn is_thin(&self) -> bool {
        self.width_deg < THIN_MAX_WIDTH_DEG
    }

    /// How far off the median prediction is, as `max(p/g, g/p)` (infinite without one).
    pub fn error_factor(&self) -> f64 {
        match self.pred_range_m {
            Some(p) if p > 0.0 => (p / self.true_range_m).max(self.true_range_m / p),
            _ => f64::INFINITY,
        }
    }
}

/// The obstacle measures of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameObstacles {
    /// Every counted instance.
    pub obstacles: Vec<ObstacleScore>,
    /// Object pixels with `g <= 5 m` within δ1.
    pub near_object_delta1: Ratio,
    /// All pixels with `g <= 5 m` within δ1.
    pub near_all_delta1: Ratio,
    /// Non-sky pixels with `g <= 50 m` predicted farther than 1.25 g.
    pub phantom: Ratio,
    /// The same pixels predicted out of range.
    pub phantom_out_of_range: Ratio,
}

/// Per-instance accumulation while scanning a frame.
#[derive(Default)]
struct InstancePixels {
    truth_m: Vec<f64>,
    pred_m: Vec<f64>,
    latitude_deg: Vec<f64>,
    out_of_range: usize,
    widest_row: usize,
    row: usize,
    row_count: usize,
}

/// Median of `values` (sorted in place); `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

/// Latitude of ERP row `v` of `height` rows, degrees: `lat = 90 - 180 (v + 0.5) / height`.
fn row_latitude_deg(v: usize, height: usize) -> f64 {
    90.0 - 180.0 * (v as f64 + 0.5) / height as f64
}

/// The prediction as scored: `+Inf` and anything at or beyond `max_depth_m` is
/// `(max_depth_m, out of range)`, NaN or a non-positive value is no estimate.
fn scored_prediction(p: f32, max_depth_m: f64) -> Option<(f64, bool)> {
    let p = p as f64;
    if p == f64::INFINITY || (p.is_finite() && p >= max_depth_m) {
        Some((max_depth_m, true))
    } else if p.is_finite() && p > 0.0 {
        Some((p, false))
    } else {
        None
    }
}

fn within_delta1(p: Option<(f64, bool)>, g: f64) -> bool {
    p.is_some_and(|(p, _)| (p / g).max(g / p) < DELTA_THRESHOLD)
}

/// Scores one frame (see the module docs).
pub fn frame_obstacles(
    pred: &[f32],
    gt: &[f32],
    labels: &SceneLabels,
    max_depth_m: f64,
) -> Result<FrameObstacles, MetricsError> {
    let n = labels.width * labels.height;
    if !labels.is_consistent() || gt.len() != n {
        return Err(MetricsError::SizeMismatch {
            pred: labels.class.len().min(labels.instance.len()),
            gt: gt.len(),
        });
    }
    if pred.len() != n {
        return Err(MetricsError::SizeMismatch {
            pred: pred.len(),
            gt: gt.len(),
        });
    }
    let mut out = FrameObstacles::default();
    let mut instances: BTreeMap<u16, InstancePixels> = BTreeMap::new();
    for (i, (&p, &g)) in pred.iter().zip(gt).enumerate() {
        let g = g as f64;
        if !(g.is_finite() && g > 0.0 && g <= max_depth_m) {
            continue;
        }
        let class = labels.class[i];
        let p = scored_prediction(p, max_depth_m);
        if g <= NEAR_RANGE_M {
            let hit = within_delta1(p, g);
            out.near_all_delta1.add(hit);
            if class == SurfaceClass::Object {
                out.near_object_delta1.add(hit);
            }
        }
        if class != SurfaceClass::Sky && g <= PHANTOM_MAX_RANGE_M {
            out.phantom
                .add(p.is_some_and(|(p, _)| p > DELTA_THRESHOLD * g));
            out.phantom_out_of_range
                .add(p.is_some_and(|(_, out_of_range)| out_of_range));
        }
        let id = labels.instance[i];
        if class != SurfaceClass::Object || id == NO_INSTANCE {
            continue;
        }
        let row = i / labels.width;
        let acc = instances.entry(id).or_default();
        if acc.row != row || acc.row_count == 0 {
            acc.row = row;
            acc.row_count = 0;
        }
        acc.row_count += 1;
        acc.widest_row = acc.widest_row.max(acc.row_count);
        acc.truth_m.push(g);
        acc.latitude_deg.push(row_latitude_deg(row, labels.height));
        if let Some((p, out_of_range)) = p {
            acc.pred_m.push(p);
            acc.out_of_range += usize::from(out_of_range);
        }
    }
    let scale = labels.width as f64 / REFERENCE_WIDTH_PX;
    let min_pixels = (OBSTACLE_MIN_PIXELS * scale * scale).round() as usize;
    let deg_per_px = 360.0 / labels.width as f64;
    for (id, mut acc) in instances {
        let pixels = acc.truth_m.len();
        let Some(true_range_m) = median(&mut acc.truth_m) else {
            continue;
        };
        if pixels < min_pixels || true_range_m > OBSTACLE_MAX_RANGE_M {
            continue;
        }
        let pred_range_m = median(&mut acc.pred_m);
        let recovered = pred_range_m
            .is_some_and(|p| (p - true_range_m).abs() <= RECOVERED_REL_TOLERANCE * true_range_m);
        out.obstacles.push(ObstacleScore {
            instance: id,
            pixels,
            true_range_m,
            pred_range_m,
            width_deg: acc.widest_row as f64 * deg_per_px,
            out_of_range_pct: 100.0 * acc.out_of_range as f64 / pixels as f64,
            elevation_deg: median(&mut acc.latitude_deg).unwrap_or(0.0),
            recovered,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 512;
    const H: usize = 256;
    const MAX_M: f64 = 1000.0;

    /// A street-like frame: ground at 20 m, sky in the top half, and `objects` boxes
    /// `(id, u0, v0, width, height, range)`.
    fn scene(objects: &[(u16, usize, usize, usize, usize, f32)]) -> (Vec<f32>, SceneLabels) {
        let mut gt = vec![MAX_M as f32; W * H];
        let mut labels = SceneLabels::sky(W, H);
        for v in H / 2..H {
            for u in 0..W {
                gt[v * W + u] = 20.0;
                labels.class[v * W + u] = SurfaceClass::Ground;
            }
        }
        for &(id, u0, v0, w, h, r) in objects {
            for v in v0..v0 + h {
                for u in u0..u0 + w {
                    gt[v * W + u] = r;
                    labels.class[v * W + u] = SurfaceClass::Object;
                    labels.instance[v * W + u] = id;
                }
            }
        }
        (gt, labels)
    }

    #[test]
    fn bands_edges_are_inclusive_above() {
        assert_eq!(ObstacleBand::of(2.0), Some(ObstacleBand::Within2m));
        assert_eq!(ObstacleBand::of(2.01), Some(ObstacleBand::From2To5m));
        assert_eq!(ObstacleBand::of(10.0), Some(ObstacleBand::From5To10m));
        assert_eq!(ObstacleBand::of(10.01), None);
    }

    #[test]
    fn melted_obstacle_is_a_miss_and_a_phantom() {
        // A pole at 1.5 m (2 px wide = 1.4°, thin), a car at 4 m, a box at 8 m, a box at
        // 30 m (not counted) and a 3-pixel speck at 3 m (too small).
        let objects = [
            (1, 100, 100, 2, 40, 1.5),
            (2, 200, 130, 30, 20, 4.0),
            (3, 300, 120, 10, 10, 8.0),
            (4, 400, 120, 10, 10, 30.0),
            (5, 450, 120, 3, 1, 3.0),
        ];
        let (gt, labels) = scene(&objects);
        // The prediction melts the pole into the sky, gets the car 10 % too far and the
        // 8 m box right; every other pixel is exact.
        let mut pred = gt.clone();
        for v in 100..140 {
            for u in 100..102 {
                pred[v * W + u] = f32::INFINITY;
            }
        }
        for v in 130..150 {
            for u in 200..230 {
                pred[v * W + u] = 4.4;
            }
        }
        let f = frame_obstacles(&pred, &gt, &labels, MAX_M).unwrap();
        assert_eq!(f.obstacles.len(), 3, "{:?}", f.obstacles);
        let pole = &f.obstacles[0];
        assert_eq!(pole.instance, 1);
        assert!(!pole.recovered && pole.is_thin());
        assert_eq!(pole.pred_range_m, Some(MAX_M));
        assert_eq!(pole.out_of_range_pct, 100.0);
        assert!((pole.width_deg - 2.0 * 360.0 / W as f64).abs() < 1e-9);
        // rows 100..140 of 256, two pixels each: the median lies between rows 119 and 120
        let lat = |v: f64| 90.0 - 180.0 * (v + 0.5) / H as f64;
        assert!((pole.elevation_deg - 0.5 * (lat(119.0) + lat(120.0))).abs() < 1e-9);
        // the car (rows 130..150) lies below the horizon (row 128)
        assert!(f.obstacles[1].elevation_deg < 0.0);
        assert!(f.obstacles[1].recovered && !f.obstacles[1].is_thin());
        assert!(f.obstacles[2].recovered);
        let c = ObstacleCounts::of_frame(&f);
        assert_eq!(c.bands[0], Ratio { hits: 0, total: 1 });
        assert_eq!(c.bands[1], Ratio { hits: 1, total: 1 });
        assert_eq!(c.bands[2], Ratio { hits: 1, total: 1 });
        assert_eq!(c.thin, Ratio { hits: 0, total: 1 });
        // Near object pixels: pole 80 (all wrong), car 600 (4.4/4 < 1.25: right), speck 3.
        assert_eq!(
            c.near_object_delta1,
            Ratio {
                hits: 603,
                total: 683
            }
        );
        // Phantom: every non-sky pixel lies within 50 m; only the pole's are too far.
        let non_sky = labels
            .class
            .iter()
            .filter(|c| **c != SurfaceClass::Sky)
            .count() as u64;
        assert_eq!(
            non_sky,
            (W * H / 2) as u64 + 80 - 24 + 100 - 20 + 100 - 20 + 3
        );
        assert_eq!(
            c.phantom,
            Ratio {
                hits: 80,
                total: non_sky
            }
        );
        assert_eq!(
            c.phantom_out_of_range,
            Ratio {
                hits: 80,
                total: non_sky
            }
        );
    }

    #[test]
    fn nan_pixels_are_left_out_of_the_median_and_all_nan_is_a_miss() {
        let (gt, labels) = scene(&[(7, 10, 100, 10, 10, 3.0), (8, 40, 100, 10, 10, 6.0)]);
        let mut pred = gt.clone();
        // Instance 7: half NaN, the rest right. Instance 8: all NaN.
        for v in 100..110 {
            for u in 10..15 {
                pred[v * W + u] = f32::NAN;
            }
            for u in 40..50 {
                pred[v * W + u] = f32::NAN;
            }
        }
        let f = frame_obstacles(&pred, &gt, &labels, MAX_M).unwrap();
        assert!(f.obstacles[0].recovered);
        assert_eq!(f.obstacles[1].pred_range_m, None);
        assert!(!f.obstacles[1].recovered);
        // NaN is no estimate: not a phantom, but a δ1 miss.
        assert_eq!(f.phantom.hits, 0);
        assert_eq!(
            f.near_object_delta1,
            Ratio {
                hits: 50,
                total: 100
            }
        );
    }

    #[test]
    fn the_pixel_floor_scales_with_width() {
        // 15 pixels: below 20 at 512, above 20 / 4 = 5 at 256.
        let labels_at = |w: usize| {
            let h = w / 2;
            let mut labels = SceneLabels::sky(w, h);
            let mut gt = vec![MAX_M as f32; w * h];
            for u in 0..15 {
                labels.class[10 * w + u] = SurfaceClass::Object;
                labels.instance[10 * w + u] = 1;
                gt[10 * w + u] = 3.0;
            }
            (gt, labels)
        };
        let (gt, labels) = labels_at(512);
        assert!(frame_obstacles(&gt, &gt, &labels, MAX_M)
            .unwrap()
            .obstacles
            .is_empty());
        let (gt, labels) = labels_at(256);
        assert_eq!(
            frame_obstacles(&gt, &gt, &labels, MAX_M)
                .unwrap()
                .obstacles
                .len(),
            1
        );
    }

    #[test]
    fn summary_pools_keeps_the_worst_frame_and_misses() {
        let (gt, labels) = scene(&[(1, 10, 100, 10, 10, 3.0)]);
        let far: Vec<f32> = gt.iter().map(|g| g * 2.0).collect();
        let mut s = ObstacleSummary::default();
        s.add_frame(
            "a.mcap",
            1,
            &frame_obstacles(&gt, &gt, &labels, MAX_M).unwrap(),
        );
        s.add_frame(
            "a.mcap",
            2,
            &frame_obstacles(&far, &gt, &labels, MAX_M).unwrap(),
        );
        assert_eq!(s.frames, 2);
        assert_eq!(s.band_recall_pct()[1], Some(50.0));
        let m = s.measures();
        let recall = &m[0];
        assert_eq!(recall.measure, ObstacleMeasure::RecallWithin5m);
        assert_eq!(recall.pooled_pct, Some(50.0));
        assert_eq!(recall.frame_mean_pct, Some(50.0));
        assert_eq!(recall.worst.as_ref().unwrap().stamp_ns, 2);
        let phantom = &m[5];
        assert_eq!(phantom.worst.as_ref().unwrap().stamp_ns, 2);
        assert_eq!(phantom.worst.as_ref().unwrap().value_pct, 100.0);
        assert_eq!(s.worst_misses.len(), 1);
        assert_eq!(s.worst_misses[0].stamp_ns, 2);
        assert!((s.worst_misses[0].score.error_factor() - 2.0).abs() < 1e-9);
        let report = s.report().unwrap();
        assert_eq!(report.bands[1].instances, 2);
        assert_eq!(report.bands[0].recall_pct, None);
        assert_eq!(report.thin.instances, 0);
        // Nothing with no labels: n/a, not zero.
        let empty = ObstacleSummary::default();
        assert!(empty.measures().iter().all(|m| m.pooled_pct.is_none()));
        assert!(empty.report().is_none());
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let labels = SceneLabels::sky(8, 4);
        assert!(frame_obstacles(&[1.0; 32], &[1.0; 31], &labels, MAX_M).is_err());
        assert!(frame_obstacles(&[1.0; 31], &[1.0; 32], &labels, MAX_M).is_err());
    }
}
