//! The inference worker and its mailbox. The receive loop posts complete camera groups to a
//! 1-slot mailbox ([`post_groups`]): a newer group replaces an unprocessed older one (counted
//! as dropped), so no queue grows without bound and inference never blocks DDS. The worker
//! thread ([`worker_main`]) takes the newest group, runs the [`Pipeline`] and publishes
//! `depth`, `points` and `confidence`. The point cloud is built only while `points` has a
//! subscriber (the DDS thread checks the match count every tick, [`Shared::points_wanted`]).

use super::diagnostics::NodeHealth;
use super::live_view::LiveView;
use super::outputs::{Output, OutputData, PerOutput};
use super::pipeline::{OutputRequest, Pipeline, PipelineOutput};
use super::ros_params::RuntimeParams;
use mode360_core::frame::RgbImage;
use mode360_core::sync::SyncGroup;
use mode360_io::msgs::{CompressedImage, Image, PointCloud2};
use ros2_client::Publisher;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Instant;

use super::error::dds_err;
use super::NodeError;

/// The 1-slot "latest group" mailbox between the DDS thread and the inference worker.
#[derive(Default)]
pub(super) struct Mailbox {
    /// The newest complete group and when it was posted.
    pub(super) slot: Option<(SyncGroup<RgbImage>, Instant)>,
    pub(super) shutdown: bool,
}

/// What the DDS thread, the inference worker and the node handle share.
pub(super) struct Shared {
    pub(super) mailbox: Mutex<Mailbox>,
    pub(super) wake: Condvar,
    pub(super) health: Mutex<NodeHealth>,
    /// Whether `points` has a matched subscriber (set by the DDS thread every tick).
    pub(super) points_wanted: AtomicBool,
    /// Whether `depth/compressedDepth` has a matched subscriber.
    pub(super) compressed_depth_wanted: AtomicBool,
    /// Pipeline settings as the parameter services last set them (read before each group).
    pub(super) runtime: RuntimeParams,
    /// The Foxglove live view (`foxglove_port` set).
    pub(super) live: Option<LiveView>,
}

/// Locks `m`, also after a thread panicked while holding it.
pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Posts complete groups to the mailbox; each one replacing an unprocessed group counts as
/// dropped.
pub(super) fn post_groups(shared: &Shared, groups: Vec<SyncGroup<RgbImage>>) {
    if groups.is_empty() {
        return;
    }
    let mut replaced = 0u64;
    {
        let mut mb = lock(&shared.mailbox);
        let now = Instant::now();
        for g in groups {
            if mb.slot.replace((g, now)).is_some() {
                replaced += 1;
            }
        }
    }
    shared.wake.notify_one();
    if replaced > 0 {
        lock(&shared.health).groups_dropped += replaced;
    }
}

/// An output's publisher, of the output's message type ([`Output::message_type`]); points and
/// compressed depth are shared with the DDS thread, which counts their matched subscribers.
pub(super) enum OutputPublisher {
    Image(Arc<Publisher<Image>>),
    CompressedImage(Arc<Publisher<CompressedImage>>),
    PointCloud(Arc<Publisher<PointCloud2>>),
}

impl OutputPublisher {
    /// Publishes `msg`, moved: no copy of the group's largest messages on the hot path.
    fn publish(&self, msg: OutputData) -> Result<(), String> {
        match (self, msg) {
            (Self::Image(p), OutputData::Image(m)) => p.publish(m).map_err(|e| format!("{e:?}")),
            (Self::CompressedImage(p), OutputData::CompressedImage(m)) => {
                p.publish(m).map_err(|e| format!("{e:?}"))
            }
            (Self::PointCloud(p), OutputData::PointCloud(m)) => {
                p.publish(m).map_err(|e| format!("{e:?}"))
            }
            _ => Err("a message of another type than the topic's".into()),
        }
    }
}

/// The publishers of the worker's outputs.
pub(super) type OutputPublishers = PerOutput<OutputPublisher>;

/// The outputs that go out, in table order: every output, confidence when asked for (of
/// these, what the pipeline built).
fn outgoing(confidence: bool) -> impl Iterator<Item = Output> {
    Output::ALL
        .into_iter()
        .filter(move |&o| confidence || o != Output::Confidence)
}

/// Publishes a group's outgoing messages, moving them out of `out`; returns what failed.
fn publish_outputs(
    publishers: &OutputPublishers,
    mut out: PipelineOutput,
    confidence: bool,
) -> Vec<String> {
    outgoing(confidence)
        .filter_map(|o| {
            let msg = out.take_message(o)?;
            publishers[o]
                .publish(msg)
                .err()
                .map(|e| format!("publishing {}: {e}", o.topic()))
        })
        .collect()
}

/// The inference thread: takes the newest group until shutdown, runs the pipeline, publishes,
/// runs the group's lens and drift checks (after publishing: off the latency path) and updates
/// the health counters.
pub(super) fn worker_main(
    mut pipeline: Pipeline,
    publishers: OutputPublishers,
    shared: Arc<Shared>,
) {
    loop {
        let (group, posted) = {
            let mut mb = lock(&shared.mailbox);
            loop {
                if mb.shutdown {
                    return;
                }
                if let Some(taken) = mb.slot.take() {
                    break taken;
                }
                mb = shared
                    .wake
                    .wait(mb)
                    .unwrap_or_else(|poisoned| poisoned.into_inner());
            }
        };
        lock(&shared.health).record_mailbox_wait(posted.elapsed());
        let images = group
            .messages
            .into_iter()
            .map(|m| m.map(|(_, img)| img))
            .collect();
        let current = lock(&shared.runtime).clone();
        if pipeline.params() != &current.pipeline {
            pipeline.set_params(current.pipeline);
        }
        let outputs = current.outputs;
        let live = shared.live.as_ref();
        let want = OutputRequest {
            points: outputs.points
                && (shared.points_wanted.load(Ordering::Relaxed)
                    || live.is_some_and(|l| l.outputs[Output::Points].wanted())),
            compressed_depth: outputs.compressed_depth
                && (shared.compressed_depth_wanted.load(Ordering::Relaxed)
                    || live.is_some_and(|l| l.outputs[Output::CompressedDepth].wanted())),
        };
        match pipeline.process_deferred(images, group.stamp_ns, want) {
            Ok(out) => {
                // Counted before the messages go out, so that whoever receives them sees them
                // counted.
                {
                    let mut h = lock(&shared.health);
                    h.record_group(out.latency, out.points.is_some());
                }
                if let Some(live) = live {
                    for o in outgoing(outputs.confidence) {
                        if let Some(msg) = out.message(o) {
                            live.outputs[o].log(msg);
                        }
                    }
                }
                let mut errors = publish_outputs(&publishers, out, outputs.confidence);
                // The lens and drift checks of this group, after its messages are out.
                if let Err(e) = pipeline.run_deferred_checks() {
                    errors.push(format!("rig health checks: {e}"));
                }
                let (lens, calibration) = (pipeline.lens_health(), pipeline.calibration_drift());
                let mut h = lock(&shared.health);
                h.record_checks(&lens, &calibration);
                if let Some(e) = errors.pop() {
                    h.pipeline_errors += 1;
                    h.last_pipeline_error = Some(e);
                }
            }
            Err(e) => {
                let mut h = lock(&shared.health);
                h.pipeline_errors += 1;
                h.last_pipeline_error = Some(e.to_string());
            }
        }
    }
}

/// Starts the inference worker thread ([`worker_main`]).
pub(super) fn spawn_worker(
    pipeline: Pipeline,
    publishers: OutputPublishers,
    shared: Arc<Shared>,
) -> Result<JoinHandle<()>, NodeError> {
    std::thread::Builder::new()
        .name("mode360-inference".into())
        .spawn(move || worker_main(pipeline, publishers, shared))
        .map_err(|e| e.to_string())
        .map_err(dds_err("starting the inference thread"))
}

/// Tells the worker to stop, drops a group still waiting for inference (counted), and waits
/// for the thread; `Err` if it panicked.
pub(super) fn stop_worker(shared: &Shared, worker: JoinHandle<()>) -> std::thread::Result<()> {
    {
        let mut mb = lock(&shared.mailbox);
        mb.shutdown = true;
        if mb.slot.take().is_some() {
            lock(&shared.health).groups_dropped += 1;
        }
    }
    shared.wake.notify_all();
    worker.join()
}
