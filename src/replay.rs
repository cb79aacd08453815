//! `mode360 replay`: run every frame of a rig bag through the node's [`Pipeline`] without
//! DDS, deterministically, and write inputs plus outputs to a new bag.
//!
//! Output bag: the input's rig and synth metadata, `/tf_static`, each frame's camera images
//! and ground truth (as recorded), and per frame `/depth`, `/points`, `/confidence`
//! (relative node topics resolved in the root namespace) and `/diagnostics`, all at the
//! frame's stamp.

use crate::bag::{BagError, RigBagReader, RigBagWriter};
use crate::bag::{DEFAULT_MAX_DEPTH_M, MAX_DEPTH_KEY};
use crate::estimator::{EstimatorError, EstimatorSpec};
use crate::metrics::{depth_metrics, DepthMetrics, FrameAverage, MetricsError};
use crate::msgs::image::float_from_image_msg;
use crate::node::diagnostics::{diagnostic_array, CameraHealth, NodeHealth};
use crate::node::pipeline::{Pipeline, PipelineError, PipelineParams};
use crate::node::{resolve_topic, CONFIDENCE_TOPIC, DEPTH_TOPIC, DIAGNOSTICS_TOPIC, POINTS_TOPIC};
use crate::sync::SyncStats;
use std::path::PathBuf;
use std::time::Duration;

/// Namespace the replayed node's relative topics are resolved in.
pub const REPLAY_NAMESPACE: &str = "/";
/// Hardware id written in replayed diagnostics.
pub const REPLAY_HARDWARE_ID: &str = "mode360-replay";

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Estimator(#[from] EstimatorError),
    #[error("frame at {stamp_ns} ns: {source}")]
    Pipeline {
        stamp_ns: u64,
        source: PipelineError,
    },
    #[error("bag '{file}': {problem}")]
    Input { file: String, problem: String },
    #[error("frame at {stamp_ns} ns: metrics: {source}")]
    Metrics { stamp_ns: u64, source: MetricsError },
}

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
}

/// What was replayed.
#[derive(Clone, Debug)]
pub struct ReplaySummary {
    pub frames: usize,
    /// Per-frame pipeline latency (estimator plus message building).
    pub latencies: Vec<Duration>,
    /// Points per frame.
    pub point_counts: Vec<usize>,
    /// Averaged over frames with ground truth.
    pub metrics: Option<DepthMetrics>,
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

/// Replays `opts.input` into `opts.output`.
pub fn replay_bag(opts: &ReplayOptions) -> Result<ReplaySummary, ReplayError> {
    let reader = RigBagReader::open(&opts.input)?;
    let file = opts.input.display().to_string();
    let rig = reader.rig().clone();
    let info = reader.info();
    let max_depth_m = match (opts.max_depth_m, info.get(MAX_DEPTH_KEY)) {
        (Some(m), _) => m,
        (None, Some(text)) => text.parse::<f64>().map_err(|e| ReplayError::Input {
            file: file.clone(),
            problem: format!("metadata '{MAX_DEPTH_KEY}' = '{text}': {e}"),
        })?,
        (None, None) => DEFAULT_MAX_DEPTH_M,
    };
    let mut writer = RigBagWriter::create(&opts.output, &rig, &info)?;
    let mut pipeline: Option<Pipeline> = None;
    let mut summary = ReplaySummary {
        frames: 0,
        latencies: Vec::new(),
        point_counts: Vec::new(),
        metrics: None,
        max_depth_m,
    };
    let mut average = FrameAverage::default();
    let mut health = NodeHealth {
        cameras: rig
            .cameras
            .iter()
            .map(|c| CameraHealth {
                name: c.name.clone(),
                topic: c.topic.clone(),
                active: true,
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    };
    let depth_topic = resolve_topic(REPLAY_NAMESPACE, DEPTH_TOPIC);
    let points_topic = resolve_topic(REPLAY_NAMESPACE, POINTS_TOPIC);
    let confidence_topic = resolve_topic(REPLAY_NAMESPACE, CONFIDENCE_TOPIC);
    let mut total_latency_ms = 0.0;
    for frame in reader.frames() {
        if opts.max_frames.is_some_and(|n| summary.frames >= n) {
            break;
        }
        let frame = frame?;
        writer.write_frame(&frame)?;
        let stamp_ns = frame.stamp_ns;
        let pipe = match &mut pipeline {
            Some(p) => p,
            None => {
                let width = match (opts.output_width, frame.images.first()) {
                    (Some(w), _) => w,
                    (None, Some(img)) => img.width() as usize,
                    (None, None) => {
                        return Err(ReplayError::Input {
                            file,
                            problem: "frame without images".into(),
                        })
                    }
                };
                let params = PipelineParams {
                    output_width: width,
                    max_depth_m: max_depth_m as f32,
                };
                let p = Pipeline::new(rig.clone(), opts.estimator.build()?, params)
                    .map_err(|source| ReplayError::Pipeline { stamp_ns, source })?;
                pipeline.insert(p)
            }
        };
        let out = pipe
            .process(frame.images.iter().cloned().map(Some).collect(), stamp_ns)
            .map_err(|source| ReplayError::Pipeline { stamp_ns, source })?;
        let bag = writer.bag_mut();
        bag.write(&depth_topic, stamp_ns, &out.depth)?;
        bag.write(&points_topic, stamp_ns, &out.points)?;
        bag.write(&confidence_topic, stamp_ns, &out.confidence)?;
        let latency_ms = out.latency.as_secs_f64() * 1e3;
        total_latency_ms += latency_ms;
        summary.frames += 1;
        summary.latencies.push(out.latency);
        summary.point_counts.push(out.points.width as usize);
        for cam in &mut health.cameras {
            cam.received += 1;
        }
        health.groups_processed += 1;
        health.sync = SyncStats {
            groups: summary.frames as u64,
            ..SyncStats::default()
        };
        health.last_latency_ms = Some(latency_ms);
        health.mean_latency_ms = Some(total_latency_ms / summary.frames as f64);
        bag.write(
            DIAGNOSTICS_TOPIC,
            stamp_ns,
            &diagnostic_array(stamp_ns, REPLAY_HARDWARE_ID, &health),
        )?;
        if let Some(gt) = &frame.ground_truth {
            let pred = float_from_image_msg(&out.depth).map_err(|e| ReplayError::Input {
                file: file.clone(),
                problem: format!("own depth output unreadable: {e}"),
            })?;
            if pred.width == gt.width && pred.height == gt.height {
                let m = depth_metrics(&pred.data, &gt.data, max_depth_m)
                    .map_err(|source| ReplayError::Metrics { stamp_ns, source })?;
                average.push(m, None);
            }
        }
    }
    writer.finish()?;
    if average.frames() > 0 {
        summary.metrics = Some(average.depth());
    }
    Ok(summary)
}
