//! Obstacle measures pooled over frames: the counts of each frame's [`FrameObstacles`] in one
//! row, their totals, per-frame means and worst frames, the worst misses, and the report an
//! evaluation writes.

use super::{FrameObstacles, ObstacleBand, ObstacleScore, Ratio, WORST_MISSES};
use serde::{Deserialize, Serialize};

/// A missed instance, for the list of worst misses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObstacleMiss {
    /// Where it was: the bag (or source) and the frame's stamp.
    pub source: String,
    pub stamp_ns: u64,
    #[serde(flatten)]
    pub score: ObstacleScore,
}

/// A measure's worst frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WorstFrame {
    pub value_pct: f64,
    pub source: String,
    pub stamp_ns: u64,
}

/// The measures of [`FrameObstacles`] in one row: recall per band and thin, near δ1,
/// phantom free space. Used for pooled totals and for one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ObstacleCounts {
    /// Recall per [`ObstacleBand`] (instances).
    pub bands: [Ratio; 3],
    /// Thin instances within 10 m.
    pub thin: Ratio,
    pub near_object_delta1: Ratio,
    pub near_all_delta1: Ratio,
    pub phantom: Ratio,
    pub phantom_out_of_range: Ratio,
}

impl ObstacleCounts {
    pub fn of_frame(f: &FrameObstacles) -> Self {
        let mut c = ObstacleCounts {
            near_object_delta1: f.near_object_delta1,
            near_all_delta1: f.near_all_delta1,
            phantom: f.phantom,
            phantom_out_of_range: f.phantom_out_of_range,
            ..Default::default()
        };
        for o in &f.obstacles {
            if let Some(band) = o.band() {
                c.bands[band.index()].add(o.recovered);
                if o.is_thin() {
                    c.thin.add(o.recovered);
                }
            }
        }
        c
    }

    /// Instances within 5 m (the first two bands).
    pub fn within_5m(&self) -> Ratio {
        let mut r = self.bands[0];
        r.merge(&self.bands[1]);
        r
    }

    /// Every counted instance (within 10 m).
    pub fn within_10m(&self) -> Ratio {
        let mut r = self.within_5m();
        r.merge(&self.bands[2]);
        r
    }

    fn merge(&mut self, o: &ObstacleCounts) {
        for (a, b) in self.bands.iter_mut().zip(&o.bands) {
            a.merge(b);
        }
        for (a, b) in [
            (&mut self.thin, &o.thin),
            (&mut self.near_object_delta1, &o.near_object_delta1),
            (&mut self.near_all_delta1, &o.near_all_delta1),
            (&mut self.phantom, &o.phantom),
            (&mut self.phantom_out_of_range, &o.phantom_out_of_range),
        ] {
            a.merge(b);
        }
    }
}

/// The named measures a summary reports with a per-frame mean and worst frame; for the
/// phantom shares the worst frame is the highest, for the others the lowest.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleMeasure {
    RecallWithin5m,
    Recall5To10m,
    RecallThin,
    NearObjectDelta1,
    NearAllDelta1,
    Phantom,
    PhantomOutOfRange,
}

impl ObstacleMeasure {
    pub const ALL: [ObstacleMeasure; 7] = [
        Self::RecallWithin5m,
        Self::Recall5To10m,
        Self::RecallThin,
        Self::NearObjectDelta1,
        Self::NearAllDelta1,
        Self::Phantom,
        Self::PhantomOutOfRange,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Self::RecallWithin5m => "recall within 5 m",
            Self::Recall5To10m => "recall 5-10 m",
            Self::RecallThin => "recall thin (< 3°) within 10 m",
            Self::NearObjectDelta1 => "δ1 object pixels within 5 m",
            Self::NearAllDelta1 => "δ1 all pixels within 5 m",
            Self::Phantom => "phantom free space within 50 m",
            Self::PhantomOutOfRange => "  of which out of range",
        }
    }

    /// Whether a higher value is worse.
    pub fn higher_is_worse(self) -> bool {
        matches!(self, Self::Phantom | Self::PhantomOutOfRange)
    }

    /// The measure's ratio in `c`.
    pub fn ratio(self, c: &ObstacleCounts) -> Ratio {
        match self {
            Self::RecallWithin5m => c.within_5m(),
            Self::Recall5To10m => c.bands[2],
            Self::RecallThin => c.thin,
            Self::NearObjectDelta1 => c.near_object_delta1,
            Self::NearAllDelta1 => c.near_all_delta1,
            Self::Phantom => c.phantom,
            Self::PhantomOutOfRange => c.phantom_out_of_range,
        }
    }
}

/// One measure over frames: pooled, per-frame mean and worst frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasureSummary {
    pub measure: ObstacleMeasure,
    /// Pooled over every frame's instances or pixels, % (`None`: nothing counted).
    pub pooled_pct: Option<f64>,
    /// Mean of the frames that counted anything, %.
    pub frame_mean_pct: Option<f64>,
    pub worst: Option<WorstFrame>,
}

/// Obstacle measures over the frames of a row of an evaluation.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ObstacleSummary {
    /// Frames that had labels.
    pub frames: usize,
    /// Pooled counts.
    pub totals: ObstacleCounts,
    /// Each frame's counts with its source and stamp.
    #[serde(skip)]
    per_frame: Vec<(String, u64, ObstacleCounts)>,
    /// The worst misses so far (largest error factor first).
    pub worst_misses: Vec<ObstacleMiss>,
}

impl ObstacleSummary {
    /// Adds one frame's scores.
    pub fn add_frame(&mut self, source: &str, stamp_ns: u64, frame: &FrameObstacles) {
        let counts = ObstacleCounts::of_frame(frame);
        self.totals.merge(&counts);
        self.per_frame.push((source.to_string(), stamp_ns, counts));
        self.frames += 1;
        self.worst_misses
            .extend(
                frame
                    .obstacles
                    .iter()
                    .filter(|o| !o.recovered)
                    .map(|o| ObstacleMiss {
                        source: source.to_string(),
                        stamp_ns,
                        score: o.clone(),
                    }),
            );
        self.worst_misses.sort_by(|a, b| {
            b.score
                .error_factor()
                .total_cmp(&a.score.error_factor())
                .then(a.score.true_range_m.total_cmp(&b.score.true_range_m))
        });
        self.worst_misses.truncate(WORST_MISSES);
    }

    /// Recall per band (pooled), %.
    pub fn band_recall_pct(&self) -> [Option<f64>; 3] {
        self.totals.bands.map(|r| r.pct())
    }

    /// Pooled, per-frame mean and worst frame of every [`ObstacleMeasure`].
    pub fn measures(&self) -> Vec<MeasureSummary> {
        ObstacleMeasure::ALL
            .into_iter()
            .map(|measure| {
                let frames: Vec<(&str, u64, f64)> = self
                    .per_frame
                    .iter()
                    .filter_map(|(src, stamp, c)| {
                        measure.ratio(c).pct().map(|v| (src.as_str(), *stamp, v))
                    })
                    .collect();
                let frame_mean_pct = (!frames.is_empty())
                    .then(|| frames.iter().map(|f| f.2).sum::<f64>() / frames.len() as f64);
                let worst = frames
                    .iter()
                    .copied()
                    .reduce(|a, b| {
                        let b_worse = if measure.higher_is_worse() {
                            b.2 > a.2
                        } else {
                            b.2 < a.2
                        };
                        if b_worse {
                            b
                        } else {
                            a
                        }
                    })
                    .map(|(source, stamp_ns, value_pct)| WorstFrame {
                        value_pct,
                        source: source.to_string(),
                        stamp_ns,
                    });
                MeasureSummary {
                    measure,
                    pooled_pct: measure.ratio(&self.totals).pct(),
                    frame_mean_pct,
                    worst,
                }
            })
            .collect()
    }
}

/// Recall of one band, pooled over frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BandRecall {
    pub band: ObstacleBand,
    pub recovered: u64,
    pub instances: u64,
    /// `None` (n/a) when the band held no instance.
    pub recall_pct: Option<f64>,
}

/// What an evaluation reports of the obstacles of a row (its JSON form).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObstacleReport {
    /// Frames that had labels.
    pub frames: usize,
    pub bands: Vec<BandRecall>,
    pub thin: BandRecallThin,
    /// Pooled, per-frame mean and worst frame of each measure.
    pub measures: Vec<MeasureSummary>,
    pub worst_misses: Vec<ObstacleMiss>,
}

/// Recall of thin instances within 10 m, pooled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BandRecallThin {
    pub recovered: u64,
    pub instances: u64,
    pub recall_pct: Option<f64>,
}

impl ObstacleReport {
    /// The measure `m` of this report.
    pub fn measure(&self, m: ObstacleMeasure) -> Option<&MeasureSummary> {
        self.measures.iter().find(|s| s.measure == m)
    }
}

impl ObstacleSummary {
    /// The report of the frames so far; `None` when no frame had labels (n/a, not zero).
    pub fn report(&self) -> Option<ObstacleReport> {
        (self.frames > 0).then(|| ObstacleReport {
            frames: self.frames,
            bands: ObstacleBand::ALL
                .into_iter()
                .map(|band| {
                    let r = self.totals.bands[band.index()];
                    BandRecall {
                        band,
                        recovered: r.hits,
                        instances: r.total,
                        recall_pct: r.pct(),
                    }
                })
                .collect(),
            thin: BandRecallThin {
                recovered: self.totals.thin.hits,
                instances: self.totals.thin.total,
                recall_pct: self.totals.thin.pct(),
            },
            measures: self.measures(),
            worst_misses: self.worst_misses.clone(),
        })
    }
}
