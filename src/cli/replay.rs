//! `mode360 replay`: run every frame of a rig bag through the node's [`Pipeline`] without
//! DDS, deterministically, and write inputs plus outputs to a new bag.
//!
//! Output bag: the input's rig and synth metadata, `/tf_static`, each frame's camera images
//! and ground truth (as recorded), and per frame every topic the node publishes: `/depth`,
//! `/depth/compressedDepth`, `/points`, `/confidence`
//! (relative node topics resolved in the root namespace) and `/diagnostics`, all at the
//! frame's stamp.

use super::drops::DropTally;
use super::estimator_args::EstimatorArgs;
use super::scores::FrameScores;
use anyhow::{bail, Context, Result};
use clap::Args;
use mode360_core::frame::RigFrame;
use mode360_core::geometry::rig_match::check_same_cameras;
use mode360_core::geometry::Rig;
use mode360_core::metrics::DepthMetrics;
use mode360_core::obstacles::{ObstacleMeasure, ObstacleReport};
use mode360_core::sync::SyncStats;
use mode360_estimator::EstimatorSpec;
use mode360_io::bag::{BagWriter, RigBagReader, RigBagWriter};
use mode360_io::msgs::image::float_from_image_msg;
use mode360_io::msgs::Image;
use mode360_node::diagnostics::{diagnostic_array, NodeHealth};
use mode360_node::outputs::{OutputMessage, PerOutput};
use mode360_node::pipeline::{Pipeline, PipelineOutput, PipelineParams};
use mode360_node::{resolve_topic, DIAGNOSTICS_TOPIC};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Namespace the replayed node's relative topics are resolved in.
pub const REPLAY_NAMESPACE: &str = "/";
/// Hardware id written in replayed diagnostics.
pub const REPLAY_HARDWARE_ID: &str = "mode360-replay";

/// What to replay.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    pub input: PathBuf,
    pub output: PathBuf,
    /// The estimator and its weights.
    pub estimator: EstimatorSpec,
    /// Output width; `None`: the input images' width.
    pub output_width: Option<usize>,
    /// `None`: the bag's `max_depth_m` metadata, else [`DEFAULT_MAX_DEPTH_M`].
    pub max_depth_m: Option<f64>,
    /// Stop after this many frames (`None`: all).
    pub max_frames: Option<usize>,
    /// Another calibration of the bag's cameras (same cameras, topics and projections; other
    /// poses), used instead of the bag's and written into the output bag.
    pub rig: Option<PathBuf>,
}

/// What was replayed.
#[derive(Clone, Debug)]
pub struct ReplaySummary {
    pub frames: usize,
    /// Malformed or mismatched messages dropped (every good frame was still replayed).
    pub drops: DropTally,
    /// Per-frame pipeline latency (estimator plus message building).
    pub latencies: Vec<Duration>,
    /// Points per frame.
    pub point_counts: Vec<usize>,
    /// Averaged over frames with ground truth.
    pub metrics: Option<DepthMetrics>,
    /// Obstacle measures over frames with ground-truth labels (`None`: n/a).
    pub obstacles: Option<ObstacleReport>,
    pub max_depth_m: f64,
}

impl ReplaySummary {
    /// Mean latency in milliseconds (0 without frames).
    pub fn mean_latency_ms(&self) -> f64 {
        if self.latencies.is_empty() {
            return 0.0;
        }
        self.latencies.iter().map(|d| d.as_secs_f64()).sum::<f64>() * 1e3
            / self.latencies.len() as f64
    }
}

/// The calibration to run a bag with: the rig file at `rig_file`, which must have the bag's
/// cameras (the error names the camera), or the bag's own; `file` names the bag in errors.
pub fn calibration_for(reader: &RigBagReader, rig_file: Option<&Path>, file: &str) -> Result<Rig> {
    let Some(path) = rig_file else {
        return Ok(reader.rig().clone());
    };
    let rig = Rig::from_file_or_shipped(path)?;
    check_same_cameras(reader.rig(), &rig).with_context(|| {
        format!(
            "rig file {} does not fit the cameras of bag '{file}'",
            path.display()
        )
    })?;
    Ok(rig)
}

/// Replays `opts.input` into `opts.output`.
pub fn replay_bag(opts: &ReplayOptions) -> Result<ReplaySummary> {
    let reader = RigBagReader::open(&opts.input)?;
    let file = opts.input.display().to_string();
    let rig = calibration_for(&reader, opts.rig.as_deref(), &file)?;
    let info = reader.info();
    let max_depth_m = match opts.max_depth_m {
        Some(m) => m,
        None => reader.max_depth_m()?,
    };
    let mut writer = RigBagWriter::create(&opts.output, &rig, &info)
        .with_context(|| format!("creating {}", opts.output.display()))?;
    let mut pipeline: Option<Pipeline> = None;
    let mut summary = ReplaySummary {
        frames: 0,
        drops: DropTally::default(),
        latencies: Vec::new(),
        point_counts: Vec::new(),
        metrics: None,
        obstacles: None,
        max_depth_m,
    };
    let mut scores = FrameScores::default();
    let mut health = NodeHealth::of_cameras(
        rig.cameras
            .iter()
            .map(|c| (c.name.as_str(), c.topic.clone())),
    );
    let topics = ReplayTopics::new();
    for frame in reader.frames() {
        if opts.max_frames.is_some_and(|n| summary.frames >= n) {
            break;
        }
        let frame = match frame {
            Ok(frame) => frame,
            Err(err) => {
                summary.drops.record(&err);
                continue;
            }
        };
        writer.write_frame(&frame)?;
        let stamp_ns = frame.stamp_ns;
        let pipe = match &mut pipeline {
            Some(p) => p,
            None => pipeline.insert(replay_pipeline(opts, &rig, &frame, max_depth_m, &file)?),
        };
        let out = pipe
            .process(frame.images.iter().cloned().map(Some).collect(), stamp_ns)
            .with_context(|| format!("frame at {stamp_ns} ns"))?;
        let bag = writer.bag_mut();
        topics.write(bag, stamp_ns, &out)?;
        summary.frames += 1;
        summary.latencies.push(out.latency);
        // replay always builds the cloud (process asks for it)
        summary
            .point_counts
            .push(out.points.as_ref().map_or(0, |p| p.width as usize));
        for cam in &mut health.cameras {
            cam.record_good();
        }
        health.record_group(out.latency, out.points.is_some());
        health.record_checks(&out.lens, &out.calibration);
        health.sync = SyncStats {
            groups: summary.frames as u64,
            ..SyncStats::default()
        };
        bag.write(
            DIAGNOSTICS_TOPIC,
            stamp_ns,
            &diagnostic_array(stamp_ns, REPLAY_HARDWARE_ID, &health),
        )?;
        score_frame(&frame, &out.depth, max_depth_m, &file, &mut scores)?;
    }
    writer.finish()?;
    if summary.frames == 0 {
        bail!(
            "bag '{file}': no frame could be replayed; {}",
            summary.drops.summary()
        );
    }
    if scores.average.frames() > 0 {
        summary.metrics = Some(scores.average.depth());
    }
    summary.obstacles = scores.obstacles.report();
    Ok(summary)
}

/// The pipeline of a replay, sized by its first frame unless the output width is given.
fn replay_pipeline(
    opts: &ReplayOptions,
    rig: &Rig,
    frame: &RigFrame,
    max_depth_m: f64,
    file: &str,
) -> Result<Pipeline> {
    let stamp_ns = frame.stamp_ns;
    let width = match (opts.output_width, frame.images.first()) {
        (Some(w), _) => w,
        (None, Some(img)) => img.width() as usize,
        (None, None) => bail!("bag '{file}': frame at {stamp_ns} ns without images"),
    };
    let params = PipelineParams {
        output_width: width,
        max_depth_m: max_depth_m as f32,
        ..PipelineParams::default()
    };
    Pipeline::new(rig.clone(), opts.estimator.build()?, params)
        .with_context(|| format!("frame at {stamp_ns} ns"))
}

/// The replay's output topics, in the node's namespace for replays.
struct ReplayTopics(PerOutput<String>);

impl ReplayTopics {
    fn new() -> Self {
        Self(PerOutput::new(|o| {
            resolve_topic(REPLAY_NAMESPACE, o.topic())
        }))
    }

    /// Writes one frame's outputs into the bag (every output the pipeline built).
    fn write(&self, bag: &mut BagWriter, stamp_ns: u64, out: &PipelineOutput) -> Result<()> {
        for (o, topic) in self.0.iter() {
            match out.message(o) {
                Some(OutputMessage::Image(m)) => bag.write(topic, stamp_ns, m)?,
                Some(OutputMessage::CompressedImage(m)) => bag.write(topic, stamp_ns, m)?,
                Some(OutputMessage::PointCloud(m)) => bag.write(topic, stamp_ns, m)?,
                None => {}
            }
        }
        Ok(())
    }
}

/// Scores a frame's published depth against its ground truth (and labels) where it has them.
fn score_frame(
    frame: &RigFrame,
    depth: &Image,
    max_depth_m: f64,
    file: &str,
    scores: &mut FrameScores,
) -> Result<()> {
    let Some(gt) = &frame.ground_truth else {
        return Ok(());
    };
    let stamp_ns = frame.stamp_ns;
    let pred = float_from_image_msg(depth)
        .with_context(|| format!("frame at {stamp_ns} ns: own depth output unreadable"))?;
    if pred.width != gt.width || pred.height != gt.height {
        return Ok(());
    }
    scores
        .add(&pred, gt, frame, max_depth_m, file, None)
        .with_context(|| format!("frame at {stamp_ns} ns: metrics"))
}

#[derive(Args)]
pub struct ReplayArgs {
    /// Input rig bag.
    pub input: PathBuf,
    /// Output bag: inputs plus depth, points, confidence, /tf_static, /diagnostics.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub estimator: EstimatorArgs,
    /// Output panorama width (default: the input width).
    #[arg(long)]
    pub output_width: Option<usize>,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Replay with this rig calibration instead of the bag's (same cameras; e.g. from
    /// `mode360 rig refine`); the output bag records it.
    #[arg(long)]
    pub rig: Option<PathBuf>,
}

/// `mode360 replay`: replays the bag and prints the latency and the accuracy against ground truth.
pub fn run(a: ReplayArgs) -> Result<()> {
    let summary = replay_bag(&ReplayOptions {
        input: a.input,
        output: a.out.clone(),
        estimator: a.estimator.spec(),
        output_width: a.output_width,
        max_depth_m: None,
        max_frames: a.max_frames,
        rig: a.rig,
    })?;
    println!(
        "replayed {} frames into {} (mean latency {:.0} ms)",
        summary.frames,
        a.out.display(),
        summary.mean_latency_ms()
    );
    println!("{}", summary.drops.summary());
    if let Some(m) = summary.metrics {
        println!(
            "against ground truth: delta1 {:.2} %, AbsRel {:.4}, MAE {:.3} m",
            m.delta1_pct, m.abs_rel, m.mae_m
        );
        println!("{}", obstacle_line(summary.obstacles.as_ref()));
    }
    Ok(())
}

/// One line of obstacle measures for the summary (n/a without ground-truth labels).
pub fn obstacle_line(report: Option<&ObstacleReport>) -> String {
    let Some(o) = report else {
        return "obstacles: n/a (the bag has no ground-truth labels)".to_string();
    };
    let pct = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.1} %"));
    let bands: Vec<String> = o
        .bands
        .iter()
        .map(|b| {
            format!(
                "{} {} ({}/{})",
                b.band.label(),
                pct(b.recall_pct),
                b.recovered,
                b.instances
            )
        })
        .collect();
    let measure = |m| pct(o.measure(m).and_then(|s| s.pooled_pct));
    format!(
        "obstacles: recall {}, thin {} ({}/{}); δ1 object pixels within 5 m {}; phantom free space {} (out of range {})",
        bands.join(", "),
        pct(o.thin.recall_pct),
        o.thin.recovered,
        o.thin.instances,
        measure(ObstacleMeasure::NearObjectDelta1),
        measure(ObstacleMeasure::Phantom),
        measure(ObstacleMeasure::PhantomOutOfRange)
    )
}
