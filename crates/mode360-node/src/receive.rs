//! The receive loop on the DDS thread. [`dds_setup`] ([`super::endpoints`]) creates the
//! node, its publishers and subscriptions and sends `/tf_static`; [`dds_main`] starts the
//! inference worker ([`super::worker`]) and then runs a current-thread tokio runtime
//! whose loop (`tokio::select!`) receives every camera topic (sensor-data QoS: best effort,
//! keep last), validates and decodes each image ([`super::decode`]) and feeds
//! [`ApproxTimeSync`] with the node clock's time of receipt (stamps far ahead and clock resets:
//! [`Receiver::on_camera`]); with `use_sim_time` it also follows `/clock` ([`NodeClock`]); a
//! `tokio::time` ticker ([`TICK`]) times cameras out and publishes `/diagnostics` once a
//! second; a watch channel stops it. Complete groups go to the inference worker's mailbox
//! ([`super::worker`]), which this loop starts and, at shutdown, stops and waits for.

use super::clock::{seconds_between, NodeClock};
use super::dds::{runtime, DdsOptions};
use super::decode::{decode_camera, Bad, CameraMsg};
use super::diagnostics::{diagnostic_array, BadImageReason};
use super::endpoints::{dds_setup, DdsSetup};
use super::page_release::{release_freed_pages, TrimPolicy};
use super::params::NodeParams;
use super::pipeline::Pipeline;
use super::worker::{lock, post_groups, spawn_worker, stop_worker, Shared};
use super::NodeError;
use futures::StreamExt;
use mode360_core::frame::RgbImage;
use mode360_core::geometry::{Rig, RigCamera};
use mode360_core::memory::resident_mib;
use mode360_core::sync::{ApproxTimeSync, ClockReset, SyncConfig};

/// The most image bytes one camera's synchronizer queue holds besides its newest image
/// (about ten 2048x1024 panoramas): a burst of large images cannot make the node grow.
pub const MAX_QUEUED_BYTES_PER_CAMERA: usize = 64 << 20;
use mode360_io::bag::rig_tf_static;
use mode360_io::msgs::{Clock, CompressedImage, DiagnosticArray, Image, PointCloud2, TFMessage};
use ros2_client::{Publisher, Subscription};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Housekeeping period of the DDS thread (timeouts, shutdown, diagnostics schedule).
pub const TICK: Duration = Duration::from_millis(50);
/// Period of `/diagnostics`.
pub const DIAGNOSTICS_PERIOD: Duration = Duration::from_secs(1);
/// Fewest cameras the node keeps running with.
pub const MIN_ACTIVE_CAMERAS: usize = 2;
/// Shortest time between two WARN lines about one camera's synchronizer resets; the resets in
/// between are counted in the next line. A looped bag logs each loop; a camera whose stamps
/// keep jumping (two sources with different clocks on one topic) does not log at its frame
/// rate.
pub const RESET_WARN_INTERVAL: Duration = Duration::from_secs(5);
/// Per-camera receive bookkeeping on the DDS thread.
struct CameraState {
    /// Node-clock time of the newest good message.
    last_receipt_ns: Option<u64>,
    received_in_period: u64,
    /// When the newest reset WARN about this camera was logged.
    last_reset_warn: Option<Instant>,
    /// Resets of this camera since that WARN, not logged.
    unlogged_resets: u64,
}

/// Matched subscribers of the outputs built only on demand.
#[derive(Clone, Copy, Debug)]
struct Subscribers {
    points: usize,
    compressed_depth: usize,
}

/// Receive-side state of the DDS loop: synchronizer, clock, per-camera bookkeeping.
struct Receiver {
    sync: ApproxTimeSync<RgbImage>,
    clock: NodeClock,
    cams: Vec<CameraState>,
    /// Node-clock time of the first tick or image (the baseline of cameras never heard).
    started_ns: Option<u64>,
    timeout_ns: u64,
    shared: Arc<Shared>,
    hardware_id: String,
    last_diag: Instant,
    /// When the receive loop started (the baseline of the depth age before any depth).
    created: Instant,
    /// The rig's transforms, for the live view.
    tf_static: TFMessage,
    /// The rig's cameras (rig order), whose models say which image sizes are accepted.
    cameras: Vec<RigCamera>,
    /// When freed memory goes back to the kernel.
    trim: TrimPolicy,
}

impl Receiver {
    /// The receive loop's state for `rig` under `params`: a synchronizer over its cameras,
    /// the node's clock and the memory trim policy from now.
    fn new(params: &NodeParams, rig: &Rig, shared: Arc<Shared>) -> Self {
        let n = rig.cameras.len();
        Self {
            sync: ApproxTimeSync::new(
                n,
                SyncConfig {
                    tolerance_ns: (params.sync_tolerance_s * 1e9).round() as u64,
                    queue_size: params.sync_queue_size,
                    // max_ahead_ns and reset_jump_ns: not node parameters (yet), the defaults.
                    ..SyncConfig::default()
                },
            )
            .with_bytes_cap(
                |img: &RgbImage| img.as_raw().len(),
                MAX_QUEUED_BYTES_PER_CAMERA,
            ),
            clock: NodeClock::new(params.use_sim_time),
            cams: (0..n)
                .map(|_| CameraState {
                    last_receipt_ns: None,
                    received_in_period: 0,
                    last_reset_warn: None,
                    unlogged_resets: 0,
                })
                .collect(),
            started_ns: None,
            timeout_ns: (params.camera_timeout_s * 1e9).round() as u64,
            shared,
            hardware_id: params.fully_qualified_name(),
            last_diag: Instant::now(),
            created: Instant::now(),
            trim: TrimPolicy::new(Instant::now()),
            tf_static: rig_tf_static(rig),
            cameras: rig.cameras.clone(),
        }
    }

    /// Takes one camera message: decodes it and feeds the synchronizer with its receive time,
    /// the node clock's now. With the system clock that is wall-clock time; with `use_sim_time`
    /// it is the newest `/clock` (none before the first, and then only the other cameras bound
    /// a stamp). Under simulated time the cameras stamp with simulated time, which starts at
    /// zero or in a recording's past: against wall-clock time no stamp would ever look ahead,
    /// against `/clock` the check means what it says. Cameras running ahead of a slowly
    /// published `/clock` lose a few images at most: the synchronizer follows a stream whose
    /// stamps stay ahead ([`mode360_core::sync`]). A reset (a stamp that jumped back: a looped
    /// bag, a simulator or driver restart) is logged once at WARN with the camera and the jump
    /// (at most one line per camera per [`RESET_WARN_INTERVAL`]), and counted on that camera's
    /// diagnostics.
    fn on_camera(&mut self, i: usize, result: Result<CameraMsg, Bad>) {
        let now_ns = self.clock.now_ns();
        if let Some(now) = now_ns {
            self.started_ns.get_or_insert(now);
        }
        if let (Some(live), Ok(msg)) = (&self.shared.live, &result) {
            match msg {
                CameraMsg::Raw(m) => live.log_camera_raw(i, m),
                CameraMsg::Compressed(m) => live.log_camera_compressed(i, m),
            }
        }
        let sync = &mut self.sync;
        let camera = &self.cameras[i];
        let outcome =
            result
                .and_then(|msg| decode_camera(camera, &msg))
                .and_then(|(stamp_ns, img)| {
                    sync.push_at(i, stamp_ns, now_ns, img)
                        .map_err(|e| (BadImageReason::from(&e), e.to_string()))
                });
        let mut groups = Vec::new();
        {
            let mut h = lock(&self.shared.health);
            match outcome {
                Ok(pushed) => {
                    groups = pushed.groups;
                    if let Some(reset) = pushed.reset {
                        let c = &mut self.cams[i];
                        if c.last_reset_warn
                            .is_none_or(|t| t.elapsed() >= RESET_WARN_INTERVAL)
                        {
                            log_reset(camera, &reset, c.unlogged_resets);
                            c.last_reset_warn = Some(Instant::now());
                            c.unlogged_resets = 0;
                        } else {
                            c.unlogged_resets += 1;
                        }
                        h.cameras[i]
                            .record_clock_jump(seconds_between(reset.stamp_ns, reset.last_ns));
                    }
                    if now_ns.is_some() {
                        self.cams[i].last_receipt_ns = now_ns;
                    }
                    self.cams[i].received_in_period += 1;
                    h.cameras[i].record_good();
                    if !self.sync.is_active(i) {
                        h.cameras[i].active = true;
                        groups.extend(self.sync.set_active(i, true));
                    }
                }
                Err((reason, detail)) => h.cameras[i].record_bad(reason, detail),
            }
            h.sync = self.sync.stats();
        }
        post_groups(&self.shared, groups);
    }

    fn on_tick(&mut self, diagnostics: &Publisher<DiagnosticArray>, subscribers: Subscribers) {
        self.shared
            .points_wanted
            .store(subscribers.points > 0, Ordering::Relaxed);
        self.shared
            .compressed_depth_wanted
            .store(subscribers.compressed_depth > 0, Ordering::Relaxed);
        let now_ns = self.clock.now_ns();
        if let Some(now) = now_ns {
            let started = *self.started_ns.get_or_insert(now);
            // Cameras silent for longer than the timeout are no longer waited for, as long
            // as at least MIN_ACTIVE_CAMERAS stay active.
            let mut groups = Vec::new();
            for i in 0..self.cams.len() {
                let silent_since = self.cams[i].last_receipt_ns.unwrap_or(started);
                let active_count = (0..self.cams.len())
                    .filter(|&k| self.sync.is_active(k))
                    .count();
                if self.sync.is_active(i)
                    && now.saturating_sub(silent_since) > self.timeout_ns
                    && active_count > MIN_ACTIVE_CAMERAS
                {
                    groups.extend(self.sync.set_active(i, false));
                    lock(&self.shared.health).cameras[i].active = false;
                }
            }
            post_groups(&self.shared, groups);
        }
        let period = self.last_diag.elapsed();
        if period >= DIAGNOSTICS_PERIOD {
            let report = {
                let mut h = lock(&self.shared.health);
                for (i, c) in self.cams.iter_mut().enumerate() {
                    h.cameras[i].rate_hz = c.received_in_period as f64 / period.as_secs_f64();
                    h.cameras[i].age_s = match (c.last_receipt_ns, now_ns) {
                        (Some(t), Some(now)) => Some(seconds_between(t, now)),
                        _ => None,
                    };
                    c.received_in_period = 0;
                }
                h.sync = self.sync.stats();
                let since = h.last_depth_at.unwrap_or(self.created);
                h.depth_age_s = Some(since.elapsed().as_secs_f64());
                if let Some(published) = h.last_depth_at {
                    // The first tick after the first output (later calls do nothing).
                    self.trim.outputs_started(published);
                }
                // Stamp 0 with simulated time before the first /clock, as in ROS 2.
                diagnostic_array(now_ns.unwrap_or(0), &self.hardware_id, &h)
            };
            if let Some(live) = &self.shared.live {
                live.diagnostics.log(&report);
                // No latching on the WebSocket: the rig's transforms again for late viewers.
                if live.tf_static.wanted() {
                    live.tf_static.log(&self.tf_static);
                }
            }
            if let Err(e) = diagnostics.publish(report) {
                tracing::warn!("publishing /diagnostics: {e:?}");
            }
            self.last_diag = Instant::now();
            self.trim_memory();
        }
    }

    /// Hands freed memory back to the kernel when [`TrimPolicy`] says so.
    fn trim_memory(&mut self) {
        let Some(before) = resident_mib() else {
            return;
        };
        if !self.trim.observe(before, Instant::now()) {
            return;
        }
        let released = release_freed_pages();
        self.trim.released(Instant::now());
        if let (true, Some(after)) = (released, resident_mib()) {
            tracing::info!(
                "handed freed memory back to the kernel: resident {before:.0} -> {after:.0} MiB"
            );
        }
    }
}

/// The WARN line of a synchronizer reset caused by `camera`, after `unlogged` resets of it
/// that were not logged ([`RESET_WARN_INTERVAL`]).
fn log_reset(camera: &RigCamera, reset: &ClockReset, unlogged: u64) {
    let earlier = if unlogged > 0 {
        format!("; {unlogged} more resets by this camera since its previous warning")
    } else {
        String::new()
    };
    tracing::warn!(
        "camera '{}': stamp jumped back {:.3} s ({} ns -> {} ns): clock reset, looped bag or \
         restarted driver; synchronizer restarted ({} queued images discarded){earlier}",
        camera.name,
        seconds_between(reset.stamp_ns, reset.last_ns),
        reset.last_ns,
        reset.stamp_ns,
        reset.discarded
    );
}

/// What the receive loop listens to and publishes on, borrowed from [`DdsSetup`].
struct LoopIo<'a> {
    node: &'a ros2_client::Node,
    raw_subs: &'a [(usize, Subscription<Image>)],
    compressed_subs: &'a [(usize, Subscription<CompressedImage>)],
    clock_sub: Option<&'a Subscription<Clock>>,
    diagnostics: &'a Publisher<DiagnosticArray>,
    /// The outputs built only on demand, whose matched subscribers the loop counts.
    points_pub: &'a Publisher<PointCloud2>,
    compressed_pub: &'a Publisher<CompressedImage>,
}

impl LoopIo<'_> {
    /// Matched subscribers of the on-demand outputs; 0 for an output that never had one
    /// (`points_matched`, `compressed_matched`), whose count ros2-client would log an ERROR
    /// for.
    fn subscribers(&self, points_matched: bool, compressed_matched: bool) -> Subscribers {
        Subscribers {
            points: if points_matched {
                self.points_pub.get_subscription_count(self.node)
            } else {
                0
            },
            compressed_depth: if compressed_matched {
                self.compressed_pub.get_subscription_count(self.node)
            } else {
                0
            },
        }
    }
}

/// The receive loop (see the module docs): camera images, `/clock` and the ticker into `rx`
/// until `stop` changes or its sender is dropped.
async fn receive_loop(rx: &mut Receiver, io: LoopIo<'_>, stop: &mut watch::Receiver<bool>) {
    let raw = futures::stream::select_all(io.raw_subs.iter().map(|(i, s)| {
        let i = *i;
        s.async_stream()
            .map(move |r| (i, r.map(|(m, _)| CameraMsg::Raw(m))))
            .boxed()
    }));
    let compressed = futures::stream::select_all(io.compressed_subs.iter().map(|(i, s)| {
        let i = *i;
        s.async_stream()
            .map(move |r| (i, r.map(|(m, _)| CameraMsg::Compressed(m))))
            .boxed()
    }));
    let mut incoming = futures::stream::select(raw, compressed);
    let mut clock_msgs = match io.clock_sub {
        Some(s) => s.async_stream().boxed(),
        None => futures::stream::pending().boxed(),
    };
    let mut ticker = tokio::time::interval(TICK);
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // ros2-client logs an ERROR for every match count of a publisher that never had a
    // subscriber (it keeps no entry for it), 20 times a second here: count only after
    // the first match.
    let mut first_points_subscriber = Box::pin(io.points_pub.wait_for_subscription(io.node));
    let mut first_compressed_subscriber =
        Box::pin(io.compressed_pub.wait_for_subscription(io.node));
    let (mut points_matched, mut compressed_matched) = (false, false);
    loop {
        tokio::select! {
            _ = &mut first_points_subscriber, if !points_matched => points_matched = true,
            _ = &mut first_compressed_subscriber, if !compressed_matched => {
                compressed_matched = true
            }
            // A stop request, or the handle dropped.
            _ = stop.changed() => break,
            Some((i, result)) = incoming.next() => {
                rx.on_camera(
                    i,
                    result.map_err(|e| {
                        (BadImageReason::Transport, format!("cannot deserialize: {e:?}"))
                    }),
                );
            }
            Some(result) = clock_msgs.next() => match result {
                Ok((clock, _)) => rx.clock.on_clock(clock.clock.to_nanos()),
                Err(e) => tracing::warn!("/clock: cannot deserialize: {e:?}"),
            },
            _ = ticker.tick() => {
                rx.on_tick(io.diagnostics, io.subscribers(points_matched, compressed_matched))
            }
        }
    }
}

/// The DDS thread's runtime and endpoints; a failure is also sent on `ready`.
fn setup_or_report(
    params: &NodeParams,
    dds: &DdsOptions,
    rig: &Rig,
    shared: &Shared,
    ready: &std::sync::mpsc::Sender<Result<(), NodeError>>,
) -> Result<(tokio::runtime::Runtime, DdsSetup), NodeError> {
    let setup =
        runtime().and_then(|rt| Ok((rt, dds_setup(params, dds, rig, shared.runtime.clone())?)));
    match setup {
        Ok(s) => Ok(s),
        Err(e) => {
            let text = e.to_string();
            let _ = ready.send(Err(e));
            Err(NodeError::Dds {
                what: "setup".into(),
                problem: text,
            })
        }
    }
}

/// The DDS thread: sets up the endpoints, starts the inference worker, reports on `ready`,
/// runs [`receive_loop`] until `stop`, then stops the worker and tears the endpoints down.
pub(super) fn dds_main(
    params: NodeParams,
    dds: DdsOptions,
    rig: Rig,
    pipeline: Pipeline,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
    ready: std::sync::mpsc::Sender<Result<(), NodeError>>,
) -> Result<(), NodeError> {
    let (rt, setup) = setup_or_report(&params, &dds, &rig, &shared, &ready)?;
    let DdsSetup {
        context,
        spun,
        publishers,
        points_pub,
        compressed_pub,
        tf_static,
        diagnostics,
        raw_subs,
        compressed_subs,
        clock_sub,
        // Bound last, so dropped first: no record goes out once the node is going.
        rosout: _rosout,
    } = setup;
    let worker = spawn_worker(pipeline, publishers, shared.clone())?;
    let _ = ready.send(Ok(()));

    let mut rx = Receiver::new(&params, &rig, shared.clone());
    let io = LoopIo {
        node: &spun.node,
        raw_subs: &raw_subs,
        compressed_subs: &compressed_subs,
        clock_sub: clock_sub.as_ref(),
        diagnostics: &diagnostics,
        points_pub: &points_pub,
        compressed_pub: &compressed_pub,
    };
    rt.block_on(receive_loop(&mut rx, io, &mut stop));

    let worker_result = stop_worker(&shared, worker);
    drop(clock_sub);
    drop(raw_subs);
    drop(compressed_subs);
    drop(tf_static);
    drop(diagnostics);
    spun.stop()?;
    drop(context);
    drop(rt);
    worker_result.map_err(|_| NodeError::ThreadPanic {
        thread: "inference".into(),
    })
}
