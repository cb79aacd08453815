//! The node's lifecycle and public handle: [`spawn_node`] loads the rig and the estimator,
//! starts the DDS thread (which starts the inference worker) and returns a [`NodeHandle`]
//! once the node is set up; [`NodeHandle::shutdown`] stops it and waits for its threads.
//! [`run_node`] is `mode360 node`: it waits for SIGINT or SIGTERM ([`ShutdownSignals`]) and
//! then shuts everything down, reporting a [`NodeRun`].

use super::dds::{runtime, DdsOptions};
use super::diagnostics::NodeHealth;
use super::live_view::LiveView;
use super::params::{ExtrinsicsSource, NodeParams};
use super::pipeline::Pipeline;
use super::receive::dds_main;
use super::ros_params::{OutputToggles, RuntimeSettings};
use super::shutdown::ShutdownSignals;
use super::tf_extrinsics::wait_for_extrinsics;
use super::topics::{camera_topic, live_view_topics};
use super::worker::{lock, Mailbox, Shared};
use super::NodeError;
use mode360_core::geometry::panorama::rig_coverage_warning;
use mode360_core::geometry::Rig;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use tokio::sync::watch;

/// A running node (in-process); [`NodeHandle::shutdown`] stops it.
pub struct NodeHandle {
    stop: watch::Sender<bool>,
    /// Closed (its sender dropped) when the DDS thread ends.
    done: watch::Receiver<()>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Result<(), NodeError>>>,
    /// The rig the node runs with (extrinsics from the YAML or from TF).
    rig: Rig,
}

impl NodeHandle {
    /// The rig the node runs with: the YAML's cameras with the extrinsics of
    /// `extrinsics_source`.
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The port of the Foxglove live view (`None` without one).
    pub fn foxglove_port(&self) -> Option<u16> {
        self.shared.live.as_ref().map(LiveView::port)
    }

    /// A snapshot of the node's health.
    pub fn health(&self) -> NodeHealth {
        lock(&self.shared.health).clone()
    }

    /// True once the node thread has ended (by error or shutdown).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Resolves when the node thread has ended (by error or shutdown).
    pub async fn finished(&mut self) {
        while self.done.changed().await.is_ok() {}
    }

    /// Stops the node, waits for all its threads and returns its final health.
    pub fn shutdown(mut self) -> Result<NodeHealth, NodeError> {
        self.stop.send_replace(true);
        if let Some(t) = self.thread.take() {
            t.join().map_err(|_| NodeError::ThreadPanic {
                thread: "dds".into(),
            })??;
        }
        Ok(self.health())
    }
}

impl Drop for NodeHandle {
    fn drop(&mut self) {
        self.stop.send_replace(true);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How [`run_node`] ended.
#[derive(Clone, Debug)]
pub struct NodeRun {
    /// The signal that stopped the node (`SIGINT`, `SIGTERM`).
    pub stopped_by: String,
    pub health: NodeHealth,
}

impl NodeRun {
    /// One line for the terminal: camera groups (frames) synchronized, published and
    /// dropped in the mailbox (including one left unprocessed at shutdown), pipeline errors,
    /// and the image counters. Without pipeline errors `frames_in = frames_out +
    /// frames_dropped`.
    pub fn summary_line(&self) -> String {
        let h = &self.health;
        let images_in: u64 = h.cameras.iter().map(|c| c.received).sum();
        let images_bad: u64 = h.cameras.iter().map(|c| c.bad_messages).sum();
        format!(
            "mode360 node stopped by {}: frames_in={} frames_out={} frames_dropped={} \
             pipeline_errors={} images_in={} images_bad={} images_unmatched={}",
            self.stopped_by,
            h.sync.groups,
            h.groups_processed,
            h.groups_dropped,
            h.pipeline_errors,
            images_in,
            images_bad,
            h.sync.unmatched + h.sync.overflow,
        )
    }
}

/// `mode360 node [--ros-args ...]`: runs until SIGINT (Ctrl-C) or SIGTERM, then shuts down
/// cleanly (inference finishes its group, DDS entities and the participant are disposed).
pub fn run_node(args: Vec<String>) -> Result<NodeRun, NodeError> {
    let params = NodeParams::from_args(&args)?;
    let dds = DdsOptions::from_env()?;
    super::ros_distro::log_ros_distro();
    let rt = runtime()?;
    // Handlers first: a signal during setup is then a clean stop, not a kill.
    let mut signals = {
        let _guard = rt.enter();
        ShutdownSignals::install()?
    };
    let name = params.fully_qualified_name();
    let domain = dds.domain_id;
    let mut handle = spawn_node(params, dds)?;
    tracing::info!("mode360 node {name} up on domain {domain}; stop with Ctrl-C");
    let stopped_by = rt.block_on(async {
        tokio::select! {
            name = signals.recv() => Some(name),
            _ = handle.finished() => None,
        }
    });
    if let Some(signal) = stopped_by {
        tracing::info!("{signal}: shutting down");
    }
    let health = handle.shutdown()?;
    Ok(NodeRun {
        stopped_by: stopped_by.unwrap_or("node thread end").to_string(),
        health,
    })
}

/// Starts the node on its own threads and returns once it is set up (publishers created,
/// `/tf_static` sent).
pub fn spawn_node(mut params: NodeParams, dds: DdsOptions) -> Result<NodeHandle, NodeError> {
    let rig = Rig::from_file_or_shipped(&params.rig_file)?;
    let rig = match params.extrinsics_source {
        ExtrinsicsSource::Yaml => rig,
        ExtrinsicsSource::Tf => {
            if params.publish_tf {
                tracing::warn!(
                    "extrinsics_source is tf: not publishing /tf_static (it would echo the robot's transforms)"
                );
                params.publish_tf = false;
            }
            wait_for_extrinsics(&rig, &dds, Duration::from_secs_f64(params.tf_timeout_s))?
        }
    };
    if let Some(part) = rig_coverage_warning(&rig) {
        tracing::warn!("rig {}: {part}", params.rig_file.display());
    }
    let estimator = params.estimator.build()?;
    let pipeline = Pipeline::new(rig.clone(), estimator, params.pipeline_params())?;
    let live = match params.live_view_address() {
        Some(at) => Some(LiveView::start(&at, &live_view_topics(&params, &rig))?),
        None => None,
    };
    let shared = Arc::new(Shared {
        mailbox: Mutex::new(Mailbox::default()),
        wake: Condvar::new(),
        points_wanted: AtomicBool::new(false),
        compressed_depth_wanted: AtomicBool::new(false),
        live,
        runtime: Arc::new(Mutex::new(RuntimeSettings {
            pipeline: pipeline.params().clone(),
            outputs: OutputToggles::of(&params),
        })),
        health: Mutex::new(NodeHealth {
            lens_warn_fraction: params.lens_warn_fraction,
            calibration_warn_deg: params.calibration_warn_deg,
            ..NodeHealth::of_cameras(
                rig.cameras
                    .iter()
                    .map(|c| (c.name.as_str(), camera_topic(&params, &c.name, &c.topic))),
            )
        }),
    });
    let (stop_tx, stop_rx) = watch::channel(false);
    let (done_tx, done_rx) = watch::channel(());
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), NodeError>>();
    let thread = {
        let shared = shared.clone();
        let rig = rig.clone();
        std::thread::Builder::new()
            .name("mode360-dds".into())
            .spawn(move || {
                let result = dds_main(params, dds, rig, pipeline, shared, stop_rx, ready_tx);
                drop(done_tx);
                result
            })
            .map_err(|e| NodeError::Dds {
                what: "starting the node thread".into(),
                problem: e.to_string(),
            })?
    };
    let handle = NodeHandle {
        stop: stop_tx,
        done: done_rx,
        shared,
        thread: Some(thread),
        rig,
    };
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(handle),
        Ok(Err(e)) => Err(e),
        Err(_) => handle.shutdown().and_then(|_| {
            Err(NodeError::ThreadPanic {
                thread: "dds (setup)".into(),
            })
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::super::diagnostics::CameraHealth;
    use super::*;
    use mode360_core::sync::SyncStats;

    #[test]
    fn summary_line_counts_frames_and_images() {
        let camera = |received, bad_messages| CameraHealth {
            received,
            bad_messages,
            ..Default::default()
        };
        let run = NodeRun {
            stopped_by: "SIGTERM".into(),
            health: NodeHealth {
                cameras: vec![camera(10, 0), camera(9, 2)],
                sync: SyncStats {
                    groups: 9,
                    unmatched: 1,
                    overflow: 2,
                    out_of_order: 2,
                    ..SyncStats::default()
                },
                groups_processed: 6,
                groups_dropped: 3,
                ..Default::default()
            },
        };
        assert_eq!(
            run.summary_line(),
            "mode360 node stopped by SIGTERM: frames_in=9 frames_out=6 frames_dropped=3 \
             pipeline_errors=0 images_in=19 images_bad=2 images_unmatched=3"
        );
    }
}
