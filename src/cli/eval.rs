//! `mode360 eval`: score a depth estimator on rig bags with the paper's metrics.
//!
//! Every frame of every bag is run through the estimator; depth metrics compare its range
//! image with the bag's `/ground_truth/depth`; disparity metrics compare both, converted to
//! GEER angular disparity (in GEER pixels, GEER width = ERP height as in Deep360) for the pair
//! (reference camera, next selected camera). Metrics are per-frame means; bags are grouped by
//! condition (clean or soiled, from the bag's `mode360.synth` metadata).
//!
//! [`ViewMode::SameImage`] feeds every camera the reference camera's image (the geometry
//! check of design.md): with no parallax left, a multi-view estimator must collapse.
//! [`geometry_share`] runs both passes and reports δ1(true views) − δ1(same image).

mod geometry_share;
mod obstacle_table;

pub use geometry_share::{geometry_share, GeometryShareReport, GeometryShareRow};

use super::drops::{DropCount, DropTally};
use super::estimator_args::EstimatorArgs;
use super::scores::FrameScores;
use anyhow::{bail, Context, Result};
use clap::Args;
use mode360_core::frame::{FloatImage, RgbImage, RigFrame};
use mode360_core::geometry::{ErpGrid, GeerPair, Rig};
use mode360_core::metrics::{self, DepthMetrics, DisparityMetrics};
use mode360_core::obstacles::ObstacleReport;
use mode360_core::progress::frames_bar;
use mode360_estimator::DepthEstimator;
use mode360_health::lens_guard::LensGuard;
use mode360_health::lens_window::LENS_WINDOW_FRAMES;
use mode360_io::bag::{RigBagReader, DEFAULT_MAX_DEPTH_M, GROUND_TRUTH_TOPIC, SOILED_KEY};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Nearest range of the preview colour map, metres.
pub const PREVIEW_MIN_DEPTH_M: f64 = 1.0;

/// Which images the estimator gets for a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ViewMode {
    /// Every camera's own image (the normal evaluation).
    #[default]
    True,
    /// Every selected camera gets the image of the reference camera of the (selected) rig at
    /// the same stamp; the estimator still gets the true rig. No parallax is left, so a real
    /// multi-view estimator must collapse (the geometry check).
    SameImage,
}

impl ViewMode {
    /// How the report names the views: `true views` or `same-image views`.
    pub fn label(self) -> &'static str {
        match self {
            ViewMode::True => "true views",
            ViewMode::SameImage => "same-image views",
        }
    }

    /// The images the estimator sees: `images` (one per camera of the rig, rig order) as they
    /// are, or the `reference`'s image for every camera.
    pub fn apply(self, images: Vec<RgbImage>, reference: usize) -> Vec<RgbImage> {
        match self {
            ViewMode::True => images,
            ViewMode::SameImage => vec![images[reference].clone(); images.len()],
        }
    }
}

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    pub bags: Vec<PathBuf>,
    /// 0-based camera indices into each bag's rig; `None` = all cameras.
    pub cameras: Option<Vec<usize>>,
    /// Stop after this many frames per bag.
    pub max_frames: Option<usize>,
    pub show_progress: bool,
    /// Write a preview PNG (reference panorama, predicted range, ground truth) of the first
    /// [`PREVIEW_FRAMES`] frames of each bag here.
    pub png_dir: Option<PathBuf>,
    /// True views, or the reference camera's image for every camera.
    pub views: ViewMode,
    /// Give the estimator the lens check's masks of the bag's frames so far, as the node and
    /// replay do (a blocked part of a lens is treated as unseen).
    pub lens_masks: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            bags: Vec::new(),
            cameras: None,
            max_frames: None,
            show_progress: false,
            png_dir: None,
            views: ViewMode::True,
            lens_masks: true,
        }
    }
}

/// How many frames per bag get a preview PNG.
pub const PREVIEW_FRAMES: usize = 3;

/// One line of the report: all frames of one condition.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalRow {
    pub condition: String,
    pub bags: Vec<String>,
    pub cameras: Vec<String>,
    pub frames: usize,
    pub depth: DepthMetrics,
    pub disparity: Option<DisparityMetrics>,
    #[serde(alias = "seconds_per_frame")]
    pub s_per_frame: f64,
    /// δ1 per ground-truth range band over all pixels (reports written before it: empty).
    #[serde(default)]
    pub range_bands: metrics::RangeBands,
    /// The range that scores as the sky.
    #[serde(default = "default_max_depth_m")]
    pub max_depth_m: f64,
    /// Obstacle recall, near δ1 and phantom free space (design.md, "Metrics"); `null` (n/a)
    /// when no frame of the row had ground-truth labels.
    #[serde(default)]
    pub obstacles: Option<ObstacleReport>,
}

fn default_max_depth_m() -> f64 {
    DEFAULT_MAX_DEPTH_M
}

/// The whole report, printed as a table and written as JSON.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalReport {
    pub estimator: String,
    /// Which images the estimator got (reports written before this field read as true views).
    #[serde(default)]
    pub views: ViewMode,
    pub rows: Vec<EvalRow>,
    /// Malformed or mismatched messages and frames dropped (every good frame was scored).
    #[serde(default)]
    pub drops: Vec<DropCount>,
}

struct Group {
    bags: Vec<String>,
    cameras: Vec<String>,
    scores: FrameScores,
    bands: metrics::RangeBands,
    max_depth_m: f64,
    elapsed_s: f64,
}

impl Group {
    /// The report row of a condition's bags.
    fn into_row(self, condition: String) -> EvalRow {
        let frames = self.scores.average.frames();
        EvalRow {
            condition,
            frames,
            depth: self.scores.average.depth(),
            disparity: self.scores.average.disparity(),
            s_per_frame: self.elapsed_s / frames.max(1) as f64,
            range_bands: self.bands,
            obstacles: self.scores.obstacles.report(),
            max_depth_m: self.max_depth_m,
            bags: self.bags,
            cameras: self.cameras,
        }
    }

    /// Scores one frame's estimate against its ground truth (and labels, where it has them).
    fn score(
        &mut self,
        range_m: &FloatImage,
        frame: &RigFrame,
        rig: &Rig,
        pair: &GeerPair,
        bag_name: &str,
    ) -> Result<()> {
        let Some(gt) = frame.ground_truth.as_ref() else {
            bail!("no ground truth");
        };
        let output = ErpGrid::new(gt.width)?;
        let disp_pred = metrics::disparity_image(rig, output, pair, range_m);
        let disp_gt = metrics::disparity_image(rig, output, pair, gt);
        let disparity = metrics::disparity_metrics(&disp_pred, &disp_gt).ok();
        self.scores
            .add(range_m, gt, frame, self.max_depth_m, bag_name, disparity)?;
        self.bands
            .add_frame(&range_m.data, &gt.data, self.max_depth_m);
        Ok(())
    }
}

/// A bag's condition (`soiled` or `clean`) and maximum depth, from its metadata.
fn bag_condition(reader: &RigBagReader) -> Result<(&'static str, f64)> {
    let condition = if reader.info().get(SOILED_KEY).map(String::as_str) == Some("true") {
        "soiled"
    } else {
        "clean"
    };
    Ok((condition, reader.max_depth_m()?))
}

/// Writes a preview: the reference image, the estimate and the ground truth colour-mapped, and
/// the legend, stacked.
fn write_preview(
    png: &Path,
    reference: &RgbImage,
    range_m: &FloatImage,
    gt: &FloatImage,
    max_depth_m: f64,
) -> Result<()> {
    let min_depth_m = PREVIEW_MIN_DEPTH_M as f32;
    let picture = crate::viz::stack_vertical(&[
        reference.clone(),
        crate::viz::colorize_range(range_m, min_depth_m, max_depth_m as f32),
        crate::viz::colorize_range(gt, min_depth_m, max_depth_m as f32),
        crate::viz::depth_legend(range_m.width as u32, min_depth_m, max_depth_m as f32),
    ]);
    if let Some(dir) = png.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    picture
        .save(png)
        .with_context(|| format!("writing preview {}", png.display()))
}

/// Where frame `n`'s preview of `bag` goes in `dir`: the bag's stem, the estimator, `_same_image`
/// for the geometry check's views, the frame number.
fn preview_path(dir: &Path, bag: &Path, views: ViewMode, estimator: &str, n: usize) -> PathBuf {
    let stem = bag
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let views = match views {
        ViewMode::True => "",
        ViewMode::SameImage => "_same_image",
    };
    dir.join(format!("{stem}_{estimator}{views}_{n:03}.png"))
}

/// Runs `estimator` over every frame of the bags and scores it.
pub fn evaluate(opts: &EvalOptions, estimator: &mut dyn DepthEstimator) -> Result<EvalReport> {
    let mut groups: BTreeMap<String, Group> = BTreeMap::new();
    let mut drops = DropTally::default();
    for path in &opts.bags {
        let bag_name = path.display().to_string();
        let reader = RigBagReader::open(path).with_context(|| format!("opening {bag_name}"))?;
        let (condition, max_depth_m) = bag_condition(&reader)?;
        let full_rig = reader.rig().clone();
        let selection: Vec<usize> = opts
            .cameras
            .clone()
            .unwrap_or_else(|| (0..full_rig.cameras.len()).collect());
        let rig = full_rig
            .subset(&selection)
            .with_context(|| bag_name.clone())?;
        let group = groups
            .entry(condition.to_string())
            .or_insert_with(|| Group {
                bags: Vec::new(),
                cameras: rig.cameras.iter().map(|c| c.name.clone()).collect(),
                scores: FrameScores::default(),
                bands: metrics::RangeBands::default(),
                max_depth_m,
                elapsed_s: 0.0,
            });
        group.bags.push(bag_name.clone());
        let progress = frames_bar(
            &format!("{} ({}) {}", estimator.name(), opts.views.label(), bag_name),
            opts.max_frames.unwrap_or(0),
            opts.show_progress,
        );
        let mut pair_cache: Option<(usize, GeerPair)> = None;
        // A fresh lens check per bag, as a node started on it would have.
        let mut lens = LensGuard::new(LENS_WINDOW_FRAMES, opts.lens_masks);
        let mut n = 0;
        for frame in reader.frames() {
            if opts.max_frames.is_some_and(|m| n >= m) {
                break;
            }
            let frame = match frame {
                Ok(frame) => frame,
                Err(err) => {
                    drops.record(&err);
                    continue;
                }
            };
            let at = || format!("{bag_name}: frame at stamp {} ns", frame.stamp_ns);
            let Some(gt) = frame.ground_truth.as_ref() else {
                drops.count(&bag_name, GROUND_TRUTH_TOPIC, "frame without ground truth");
                continue;
            };
            let images = opts.views.apply(
                selection.iter().map(|&i| frame.images[i].clone()).collect(),
                rig.reference,
            );
            let output = ErpGrid::new(gt.width).with_context(at)?;
            let t0 = Instant::now();
            let est = lens
                .estimate(estimator, &rig, &images, output)
                .with_context(at)?;
            group.elapsed_s += t0.elapsed().as_secs_f64();
            let pair = match &pair_cache {
                Some((w, p)) if *w == gt.width => p.clone(),
                _ => {
                    let p = metrics::reference_disparity_pair(&rig, output)
                        .with_context(|| bag_name.clone())?;
                    pair_cache = Some((gt.width, p.clone()));
                    p
                }
            };
            group
                .score(&est.range_m, &frame, &rig, &pair, &bag_name)
                .with_context(at)?;
            if let Some(dir) = opts.png_dir.as_ref().filter(|_| n < PREVIEW_FRAMES) {
                let png = preview_path(dir, path, opts.views, estimator.name(), n);
                write_preview(&png, &images[rig.reference], &est.range_m, gt, max_depth_m)?;
            }
            progress.inc(1);
            n += 1;
        }
        progress.finish_and_clear();
    }
    let rows: Vec<EvalRow> = groups
        .into_iter()
        .filter(|(_, g)| g.scores.average.frames() > 0)
        .map(|(condition, g)| g.into_row(condition))
        .collect();
    if rows.is_empty() {
        bail!("no frames evaluated; {}", drops.summary());
    }
    Ok(EvalReport {
        estimator: estimator.name().to_string(),
        views: opts.views,
        rows,
        drops: drops.counts(),
    })
}

impl EvalReport {
    /// The paper's table layout, one line per condition.
    pub fn to_table(&self) -> String {
        let mut s = format!(
            "estimator: {} ({})\n| condition | cameras | frames | MAE (m) | RMSE (m) | AbsRel | SqRel | SILog | δ1 % | δ2 % | δ3 % | disp MAE (px) | disp RMSE | Px1 % | Px3 % | Px5 % | D1 % | s/frame |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
            self.estimator,
            self.views.label()
        );
        for r in &self.rows {
            let d = &r.depth;
            let p = r.disparity.unwrap_or_default();
            s.push_str(&format!(
                "| {} | {} | {} | {:.3} | {:.3} | {:.4} | {:.4} | {:.3} | {:.2} | {:.2} | {:.2} | {:.3} | {:.3} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |\n",
                r.condition,
                r.cameras.join(","),
                r.frames,
                d.mae_m,
                d.rmse_m,
                d.abs_rel,
                d.sq_rel_m,
                d.silog,
                d.delta1_pct,
                d.delta2_pct,
                d.delta3_pct,
                p.mae_px,
                p.rmse_px,
                p.px1_pct,
                p.px3_pct,
                p.px5_pct,
                p.d1_pct,
                r.s_per_frame
            ));
        }
        s.push_str(&self.range_band_table());
        s.push_str(&self.obstacle_table());
        s.push_str(&super::drops::summary(&self.drops));
        s.push('\n');
        s
    }

    /// δ1 per ground-truth range band (pixels pooled over frames), with each band's share of
    /// the pixels: where the estimator loses; then the share of each band's misses read too
    /// far: which way.
    pub fn range_band_table(&self) -> String {
        let Some(first) = self.rows.iter().find(|r| !r.range_bands.pixels.is_empty()) else {
            return String::new();
        };
        let labels = metrics::RangeBands::labels(first.max_depth_m);
        let mut s = self.band_table(
            "δ1 % by ground-truth range (share of pixels %)",
            &labels,
            |bands| {
                bands
                    .delta1_pct()
                    .iter()
                    .zip(bands.share_pct())
                    .map(|(d, share)| match d {
                        Some(d) => format!("{d:.1} ({share:.1})"),
                        None => "- (0)".to_string(),
                    })
                    .collect()
            },
        );
        s.push_str(&self.band_table(
            "of each band's misses, read too far % (the rest too near or without a range)",
            &labels,
            |bands| {
                bands
                    .too_far_pct()
                    .iter()
                    .map(|far| far.map_or_else(|| "-".to_string(), |f| format!("{f:.0}")))
                    .collect()
            },
        ));
        s
    }

    /// One table of `title` with a column per range band and a row per condition that has
    /// band counts, its cells from `cells`.
    fn band_table(
        &self,
        title: &str,
        labels: &[String],
        cells: impl Fn(&metrics::RangeBands) -> Vec<String>,
    ) -> String {
        let mut s = format!(
            "{title}\n| condition | {} |\n|---|{}\n",
            labels.join(" | "),
            "---|".repeat(labels.len())
        );
        for r in self
            .rows
            .iter()
            .filter(|r| !r.range_bands.pixels.is_empty())
        {
            s.push_str(&format!(
                "| {} | {} |\n",
                r.condition,
                cells(&r.range_bands).join(" | ")
            ));
        }
        s
    }
}

#[derive(Args)]
pub struct EvalArgs {
    /// Bag(s) to evaluate (repeat for clean and soiled bags).
    #[arg(long = "bag", required = true)]
    pub bags: Vec<PathBuf>,
    #[command(flatten)]
    pub estimator: EstimatorArgs,
    /// Cameras to use, 1-based in rig order, e.g. 1,2,3 (default: all).
    #[arg(long, value_delimiter = ',')]
    pub cameras: Option<Vec<usize>>,
    /// Evaluate at most this many frames per bag.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Write the table as JSON here.
    #[arg(long, default_value = "eval.json")]
    pub json: PathBuf,
    /// Write preview PNGs (panorama, predicted and true range) of the first frames here.
    #[arg(long)]
    pub png_dir: Option<PathBuf>,
    /// Feed every camera the reference camera's image (no parallax; the geometry check).
    #[arg(long, conflicts_with = "geometry_share")]
    pub same_image: bool,
    /// Evaluate with true views and with --same-image views; print both and the δ1 difference.
    #[arg(long)]
    pub geometry_share: bool,
    /// Do not mask the blocked parts of lenses that the lens check finds (the node and replay
    /// mask them).
    #[arg(long)]
    pub no_lens_mask: bool,
}

/// `mode360 eval`: builds the estimator, scores it (or its geometry share) and writes the JSON.
pub fn run(a: EvalArgs) -> Result<()> {
    let cameras = match a.cameras {
        None => None,
        Some(list) => {
            if list.contains(&0) {
                bail!("--cameras is 1-based: camera 0 does not exist");
            }
            Some(list.iter().map(|c| c - 1).collect())
        }
    };
    let mut est: Box<dyn DepthEstimator> = a.estimator.spec().build()?;
    let opts = EvalOptions {
        bags: a.bags,
        cameras,
        max_frames: a.max_frames,
        show_progress: true,
        png_dir: a.png_dir,
        views: if a.same_image {
            ViewMode::SameImage
        } else {
            ViewMode::True
        },
        lens_masks: !a.no_lens_mask,
    };
    let json = if a.geometry_share {
        let report = geometry_share(&opts, est.as_mut())?;
        print!("{}", report.to_table());
        serde_json::to_string_pretty(&report)?
    } else {
        let report = evaluate(&opts, est.as_mut())?;
        print!("{}", report.to_table());
        serde_json::to_string_pretty(&report)?
    };
    mode360_core::atomic_file::write_atomic(&a.json, json)
        .with_context(|| format!("writing {}", a.json.display()))?;
    println!("wrote {}", a.json.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_modes_name_themselves_and_pick_the_reference() {
        assert_eq!(serde_json::to_string(&ViewMode::True).unwrap(), "\"true\"");
        let same: ViewMode = serde_json::from_str("\"same-image\"").unwrap();
        assert_eq!(same, ViewMode::SameImage);
        assert_eq!(same.label(), "same-image views");
        let images: Vec<RgbImage> = (0..3u8)
            .map(|k| RgbImage::from_pixel(4, 2, image::Rgb([k, k, k])))
            .collect();
        let fed = ViewMode::SameImage.apply(images.clone(), 1);
        assert!(fed.iter().all(|i| i.get_pixel(0, 0).0 == [1, 1, 1]) && fed.len() == 3);
        assert_eq!(ViewMode::True.apply(images.clone(), 1), images);
        // Reports written before `views` existed read as true views.
        let old: EvalReport = serde_json::from_str(r#"{"estimator":"x","rows":[]}"#).unwrap();
        assert_eq!(old.views, ViewMode::True);
    }
}
