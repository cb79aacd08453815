//! The live ROS 2 node over ros2-client (RustDDS, no ROS install needed).
//!
//! Threads: a DDS thread receives every camera topic (sensor-data QoS: best effort, keep last),
//! validates and decodes each image, feeds [`ApproxTimeSync`] and, at [`TICK`] intervals,
//! times cameras out and publishes `/diagnostics` once a second. Complete groups go to a
//! 1-slot mailbox: a newer group replaces an unprocessed older one (counted as dropped), so
//! no queue grows without bound. An inference worker thread takes the newest group, runs the
//! [`Pipeline`] and publishes `depth`, `points` and `confidence`. A third thread runs the
//! ros2-client spinner (discovery); shutdown stops it and waits for it.

use super::diagnostics::{diagnostic_array, CameraHealth, NodeHealth};
use super::params::{ImageTransport, NodeParams, ParamsError};
use super::pipeline::{Pipeline, PipelineError, PipelineParams};
use super::{
    resolve_topic, CONFIDENCE_TOPIC, DEPTH_TOPIC, DIAGNOSTICS_TOPIC, POINTS_TOPIC, TF_STATIC_TOPIC,
};
use crate::bag::rig_tf_static;
use crate::estimator::{by_name, EstimatorError};
use crate::frame::RgbImage;
use crate::geometry::{Rig, RigError};
use crate::msgs::image::{rgb_from_compressed, rgb_from_image_msg};
use crate::msgs::{CompressedImage, DiagnosticArray, Image, PointCloud2, RosMessage, TFMessage};
use crate::sync::{ApproxTimeSync, SyncConfig, SyncGroup};
use futures::StreamExt;
use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile,
};
use std::net::{IpAddr, Ipv4Addr};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Housekeeping period of the DDS thread (timeouts, shutdown, diagnostics schedule).
pub const TICK: Duration = Duration::from_millis(50);
/// Period of `/diagnostics`.
pub const DIAGNOSTICS_PERIOD: Duration = Duration::from_secs(1);
/// Depth of the sensor-data subscriptions.
pub const SENSOR_QOS_DEPTH: usize = 5;
/// Depth of the output publishers.
pub const OUTPUT_QOS_DEPTH: usize = 2;
/// Environment variable holding the DDS domain.
pub const ROS_DOMAIN_ID_ENV: &str = "ROS_DOMAIN_ID";
/// Fewest cameras the node keeps running with.
pub const MIN_ACTIVE_CAMERAS: usize = 2;
/// Suffix of image_transport's compressed topic.
pub const COMPRESSED_SUFFIX: &str = "compressed";

#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Params(#[from] ParamsError),
    #[error(transparent)]
    Rig(#[from] RigError),
    #[error(transparent)]
    Estimator(#[from] EstimatorError),
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error("environment variable {ROS_DOMAIN_ID_ENV}='{value}' is not a domain id (0..=232)")]
    DomainId { value: String },
    #[error("topic '{topic}': not a valid ROS 2 name: {problem}")]
    TopicName { topic: String, problem: String },
    #[error("DDS: {what}: {problem}")]
    Dds { what: String, problem: String },
    #[error("node thread '{thread}' panicked")]
    ThreadPanic { thread: String },
}

fn dds_err(what: impl Into<String>) -> impl FnOnce(String) -> NodeError {
    let what = what.into();
    move |problem| NodeError::Dds { what, problem }
}

/// How to attach to DDS.
#[derive(Clone, Debug, PartialEq)]
pub struct DdsOptions {
    pub domain_id: u16,
    /// Use only the loopback interface (tests, single-host setups).
    pub loopback_only: bool,
}

impl DdsOptions {
    /// Domain from `ROS_DOMAIN_ID` (default 0), all interfaces.
    pub fn from_env() -> Result<Self, NodeError> {
        let domain_id = match std::env::var(ROS_DOMAIN_ID_ENV) {
            Ok(value) => value
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|d| *d <= MAX_DOMAIN_ID)
                .ok_or(NodeError::DomainId { value })?,
            Err(_) => 0,
        };
        Ok(Self {
            domain_id,
            loopback_only: false,
        })
    }
}

/// Largest valid ROS 2 domain id.
pub const MAX_DOMAIN_ID: u16 = 232;

/// A ros2-client context on `opts`.
pub fn dds_context(opts: &DdsOptions) -> Result<Context, NodeError> {
    if opts.loopback_only {
        let dp = DomainParticipantBuilder::new(opts.domain_id)
            .with_only_networks([IpAddr::V4(Ipv4Addr::LOCALHOST)])
            .build()
            .map_err(|e| NodeError::Dds {
                what: "creating the domain participant".into(),
                problem: e.to_string(),
            })?;
        Context::from_domain_participant(dp).map_err(|e| NodeError::Dds {
            what: "creating the context".into(),
            problem: e.to_string(),
        })
    } else {
        Context::with_options(ContextOptions::new().domain_id(opts.domain_id)).map_err(|e| {
            NodeError::Dds {
                what: "creating the context".into(),
                problem: e.to_string(),
            }
        })
    }
}

/// ros2-client's type name of one of our messages (`sensor_msgs/msg/Image`).
pub fn message_type_name<T: RosMessage>() -> MessageTypeName {
    let mut parts = T::TYPE_NAME.split('/');
    let package = parts.next().unwrap_or_default();
    let name = parts.next_back().unwrap_or_default();
    MessageTypeName::new(package, name)
}

/// A ros2-client [`Name`] of a topic such as `/cam1/image_raw` or `depth`.
pub fn ros_name(topic: &str) -> Result<Name, NodeError> {
    let err = |problem: String| NodeError::TopicName {
        topic: topic.to_string(),
        problem,
    };
    let (ns, base) = match topic.rsplit_once('/') {
        Some(("", base)) => ("/", base),
        Some((ns, base)) => (ns, base),
        None => ("", topic),
    };
    Name::new(ns, base).map_err(|e| err(format!("{e:?}")))
}

/// Sensor-data QoS: best effort, volatile, keep last [`SENSOR_QOS_DEPTH`].
pub fn sensor_qos() -> QosProfile {
    QosProfile::subscription_default().history(ros2_client::qos::History::KeepLast {
        depth: SENSOR_QOS_DEPTH,
    })
}

/// Output QoS: reliable, volatile, keep last [`OUTPUT_QOS_DEPTH`].
pub fn output_qos() -> QosProfile {
    QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast {
        depth: OUTPUT_QOS_DEPTH,
    })
}

/// Latched QoS for `/tf_static`: reliable, transient local, keep last 1.
pub fn latched_qos() -> QosProfile {
    QosProfile::publisher_default()
        .durability(ros2_client::qos::Durability::TransientLocal)
        .history(ros2_client::qos::History::KeepLast { depth: 1 })
}

/// Creates a publisher of `T` on `topic`.
pub fn create_publisher<T: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<Publisher<T>, NodeError> {
    let t = node
        .create_topic(&ros_name(topic)?, message_type_name::<T>(), &qos)
        .map_err(|e| NodeError::Dds {
            what: format!("creating topic '{topic}'"),
            problem: e.to_string(),
        })?;
    node.create_publisher::<T>(&t, Some(qos))
        .map_err(|e| NodeError::Dds {
            what: format!("creating publisher on '{topic}'"),
            problem: e.to_string(),
        })
}

/// Creates a subscription of `T` on `topic`.
pub fn create_subscription<T: RosMessage + 'static>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<ros2_client::Subscription<T>, NodeError> {
    let t = node
        .create_topic(&ros_name(topic)?, message_type_name::<T>(), &qos)
        .map_err(|e| NodeError::Dds {
            what: format!("creating topic '{topic}'"),
            problem: e.to_string(),
        })?;
    node.create_subscription::<T>(&t, Some(qos))
        .map_err(|e| NodeError::Dds {
            what: format!("creating subscription on '{topic}'"),
            problem: e.to_string(),
        })
}

/// A node plus its spinner thread; dropping without [`SpunNode::stop`] still stops the
/// spinner (ros2-client signals it on drop) but does not wait.
pub struct SpunNode {
    pub node: Node,
    spinner: Option<JoinHandle<()>>,
}

impl SpunNode {
    /// Creates node `name` in `namespace` and starts its spinner.
    pub fn new(context: &Context, namespace: &str, name: &str) -> Result<Self, NodeError> {
        let node_name = NodeName::new(namespace, name).map_err(|e| NodeError::TopicName {
            topic: format!("{namespace}/{name}"),
            problem: format!("{e:?}"),
        })?;
        let mut node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false))
            .map_err(|e| NodeError::Dds {
                what: "creating the node".into(),
                problem: format!("{e:?}"),
            })?;
        let spinner = node.spinner().map_err(|e| NodeError::Dds {
            what: "creating the spinner".into(),
            problem: e.to_string(),
        })?;
        let handle = std::thread::Builder::new()
            .name("mode360-spinner".into())
            .spawn(move || {
                if let Err(e) = smol::block_on(spinner.spin()) {
                    tracing::warn!("spinner stopped with error: {e}");
                }
            })
            .map_err(|e| NodeError::Dds {
                what: "starting the spinner thread".into(),
                problem: e.to_string(),
            })?;
        Ok(Self {
            node,
            spinner: Some(handle),
        })
    }

    /// Stops the spinner and waits for it.
    pub fn stop(mut self) -> Result<(), NodeError> {
        self.node.stop_spinner();
        if let Some(h) = self.spinner.take() {
            h.join().map_err(|_| NodeError::ThreadPanic {
                thread: "spinner".into(),
            })?;
        }
        Ok(())
    }
}

/// The 1-slot "latest group" mailbox between the DDS thread and the inference worker.
#[derive(Default)]
struct Mailbox {
    slot: Option<SyncGroup<RgbImage>>,
    shutdown: bool,
}

struct Shared {
    mailbox: Mutex<Mailbox>,
    wake: Condvar,
    health: Mutex<NodeHealth>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A running node (in-process); [`NodeHandle::shutdown`] stops it.
pub struct NodeHandle {
    stop: Arc<AtomicBool>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Result<(), NodeError>>>,
}

impl NodeHandle {
    /// A snapshot of the node's health.
    pub fn health(&self) -> NodeHealth {
        lock(&self.shared.health).clone()
    }

    /// True once the node thread has ended (by error or shutdown).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Stops the node, waits for all its threads and returns its final health.
    pub fn shutdown(mut self) -> Result<NodeHealth, NodeError> {
        self.stop.store(true, Ordering::SeqCst);
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
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// `mode360 node [--ros-args ...]`: runs until the process is stopped.
pub fn run_node(args: Vec<String>) -> Result<(), NodeError> {
    let params = NodeParams::from_args(&args)?;
    let dds = DdsOptions::from_env()?;
    let handle = spawn_node(params, dds)?;
    tracing::info!("mode360 node running; stop with Ctrl-C");
    while !handle.is_finished() {
        std::thread::sleep(TICK);
    }
    handle.shutdown().map(|_| ())
}

/// Starts the node on its own threads and returns once it is set up (publishers created,
/// `/tf_static` sent).
pub fn spawn_node(params: NodeParams, dds: DdsOptions) -> Result<NodeHandle, NodeError> {
    let rig = Rig::from_file(&params.rig_file)?;
    let estimator = by_name(&params.estimator)?;
    let pipeline = Pipeline::new(
        rig.clone(),
        estimator,
        PipelineParams {
            output_width: params.output_width,
            max_depth_m: params.max_depth_m as f32,
        },
    )?;
    let shared = Arc::new(Shared {
        mailbox: Mutex::new(Mailbox::default()),
        wake: Condvar::new(),
        health: Mutex::new(NodeHealth {
            cameras: rig
                .cameras
                .iter()
                .map(|c| CameraHealth {
                    name: c.name.clone(),
                    topic: camera_topic(&params, &c.name, &c.topic),
                    active: true,
                    ..Default::default()
                })
                .collect(),
            ..Default::default()
        }),
    });
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), NodeError>>();
    let thread = {
        let shared = shared.clone();
        let stop = stop.clone();
        std::thread::Builder::new()
            .name("mode360-dds".into())
            .spawn(move || dds_main(params, dds, rig, pipeline, shared, stop, ready_tx))
            .map_err(|e| NodeError::Dds {
                what: "starting the node thread".into(),
                problem: e.to_string(),
            })?
    };
    let handle = NodeHandle {
        stop,
        shared,
        thread: Some(thread),
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

/// The topic camera `name` is received on (after remapping and transport suffix).
fn camera_topic(params: &NodeParams, name: &str, topic: &str) -> String {
    let base = params.remap(topic);
    match params.image_transport(name) {
        ImageTransport::Raw => base,
        ImageTransport::Compressed => format!("{base}/{COMPRESSED_SUFFIX}"),
    }
}

/// A received camera message.
enum CameraMsg {
    Raw(Image),
    Compressed(CompressedImage),
}

/// Per-camera receive bookkeeping on the DDS thread.
struct CameraState {
    last_receipt: Option<Instant>,
    received_in_period: u64,
}

/// Validates and decodes one camera message: ERP size, encoding, step and data length.
fn decode_camera(msg: &CameraMsg) -> Result<(u64, RgbImage), String> {
    let (stamp_ns, image) = match msg {
        CameraMsg::Raw(m) => (
            m.header.stamp.to_nanos(),
            rgb_from_image_msg(m).map_err(|e| e.to_string())?,
        ),
        CameraMsg::Compressed(m) => (
            m.header.stamp.to_nanos(),
            rgb_from_compressed(m).map_err(|e| e.to_string())?,
        ),
    };
    if image.width() != 2 * image.height() || image.width() == 0 {
        return Err(format!(
            "{}x{} is not an equirectangular image (width must be 2 x height)",
            image.width(),
            image.height()
        ));
    }
    Ok((stamp_ns, image))
}

fn post_groups(shared: &Shared, groups: Vec<SyncGroup<RgbImage>>) {
    if groups.is_empty() {
        return;
    }
    let mut replaced = 0u64;
    {
        let mut mb = lock(&shared.mailbox);
        for g in groups {
            if mb.slot.replace(g).is_some() {
                replaced += 1;
            }
        }
    }
    shared.wake.notify_one();
    if replaced > 0 {
        lock(&shared.health).groups_dropped += replaced;
    }
}

struct OutputPublishers {
    depth: Publisher<Image>,
    points: Publisher<PointCloud2>,
    confidence: Publisher<Image>,
}

fn worker_main(mut pipeline: Pipeline, publishers: OutputPublishers, shared: Arc<Shared>) {
    let mut total_ms = 0.0;
    loop {
        let group = {
            let mut mb = lock(&shared.mailbox);
            loop {
                if mb.shutdown {
                    return;
                }
                if let Some(g) = mb.slot.take() {
                    break g;
                }
                mb = shared
                    .wake
                    .wait(mb)
                    .unwrap_or_else(|poisoned| poisoned.into_inner());
            }
        };
        let images = group
            .messages
            .into_iter()
            .map(|m| m.map(|(_, img)| img))
            .collect();
        match pipeline.process(images, group.stamp_ns) {
            Ok(out) => {
                let mut errors = Vec::new();
                if let Err(e) = publishers.depth.publish(out.depth) {
                    errors.push(format!("publishing depth: {e:?}"));
                }
                if let Err(e) = publishers.points.publish(out.points) {
                    errors.push(format!("publishing points: {e:?}"));
                }
                if let Err(e) = publishers.confidence.publish(out.confidence) {
                    errors.push(format!("publishing confidence: {e:?}"));
                }
                let ms = out.latency.as_secs_f64() * 1e3;
                let mut h = lock(&shared.health);
                h.groups_processed += 1;
                total_ms += ms;
                h.last_latency_ms = Some(ms);
                h.mean_latency_ms = Some(total_ms / h.groups_processed as f64);
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

#[allow(clippy::too_many_arguments)]
fn dds_main(
    params: NodeParams,
    dds: DdsOptions,
    rig: Rig,
    pipeline: Pipeline,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    ready: std::sync::mpsc::Sender<Result<(), NodeError>>,
) -> Result<(), NodeError> {
    let setup = (|| {
        let context = dds_context(&dds)?;
        let mut spun = SpunNode::new(&context, &params.namespace, &params.node_name)?;
        let ns = params.namespace.clone();
        let topic = |name: &str| match params.remaps.get(name) {
            // `-r depth:=range` remaps the relative name; the result resolves in the namespace.
            Some(to) => resolve_topic(&ns, to),
            None => params.remap(&resolve_topic(&ns, name)),
        };
        let node = &mut spun.node;
        let publishers = OutputPublishers {
            depth: create_publisher(node, &topic(DEPTH_TOPIC), output_qos())?,
            points: create_publisher(node, &topic(POINTS_TOPIC), output_qos())?,
            confidence: create_publisher(node, &topic(CONFIDENCE_TOPIC), output_qos())?,
        };
        let tf_static: Publisher<TFMessage> =
            create_publisher(node, TF_STATIC_TOPIC, latched_qos())?;
        let diagnostics: Publisher<DiagnosticArray> =
            create_publisher(node, DIAGNOSTICS_TOPIC, output_qos())?;
        let mut raw_subs = Vec::new();
        let mut compressed_subs = Vec::new();
        for (i, cam) in rig.cameras.iter().enumerate() {
            let t = camera_topic(&params, &cam.name, &cam.topic);
            match params.image_transport(&cam.name) {
                ImageTransport::Raw => {
                    raw_subs.push((i, create_subscription::<Image>(node, &t, sensor_qos())?))
                }
                ImageTransport::Compressed => compressed_subs.push((
                    i,
                    create_subscription::<CompressedImage>(node, &t, sensor_qos())?,
                )),
            }
        }
        tf_static
            .publish(rig_tf_static(&rig))
            .map_err(|e| format!("{e:?}"))
            .map_err(dds_err("publishing /tf_static"))?;
        Ok::<_, NodeError>((
            context,
            spun,
            publishers,
            tf_static,
            diagnostics,
            raw_subs,
            compressed_subs,
        ))
    })();
    let (context, spun, publishers, tf_static, diagnostics, raw_subs, compressed_subs) = match setup
    {
        Ok(s) => s,
        Err(e) => {
            let text = e.to_string();
            let _ = ready.send(Err(e));
            return Err(NodeError::Dds {
                what: "setup".into(),
                problem: text,
            });
        }
    };
    let worker = {
        let shared = shared.clone();
        std::thread::Builder::new()
            .name("mode360-inference".into())
            .spawn(move || worker_main(pipeline, publishers, shared))
            .map_err(|e| e.to_string())
            .map_err(dds_err("starting the inference thread"))?
    };
    let _ = ready.send(Ok(()));

    let hardware_id = params.fully_qualified_name();
    let n = rig.cameras.len();
    let timeout = Duration::from_secs_f64(params.camera_timeout_secs);
    let mut sync: ApproxTimeSync<RgbImage> = ApproxTimeSync::new(
        n,
        SyncConfig {
            tolerance_ns: (params.sync_tolerance_secs * 1e9).round() as u64,
            queue_size: params.sync_queue_size,
        },
    );
    let mut cams: Vec<CameraState> = (0..n)
        .map(|_| CameraState {
            last_receipt: None,
            received_in_period: 0,
        })
        .collect();
    let started = Instant::now();
    let mut last_diag = Instant::now();

    smol::block_on(async {
        let raw = futures::stream::select_all(raw_subs.iter().map(|(i, s)| {
            let i = *i;
            s.async_stream()
                .map(move |r| (i, r.map(|(m, _)| CameraMsg::Raw(m))))
                .boxed()
        }));
        let compressed = futures::stream::select_all(compressed_subs.iter().map(|(i, s)| {
            let i = *i;
            s.async_stream()
                .map(move |r| (i, r.map(|(m, _)| CameraMsg::Compressed(m))))
                .boxed()
        }));
        let mut incoming = futures::stream::select(raw, compressed).fuse();
        let mut ticker = smol::Timer::interval(TICK).fuse();
        loop {
            futures::select! {
                item = incoming.next() => {
                    let Some((i, result)) = item else { continue };
                    let now = Instant::now();
                    let outcome = result
                        .map_err(|e| format!("cannot deserialize: {e:?}"))
                        .and_then(|msg| decode_camera(&msg))
                        .and_then(|(stamp_ns, img)| {
                            sync.push(i, stamp_ns, img).map_err(|e| e.to_string())
                        });
                    let mut groups = Vec::new();
                    {
                        let mut h = lock(&shared.health);
                        match outcome {
                            Ok(g) => {
                                groups = g;
                                cams[i].last_receipt = Some(now);
                                cams[i].received_in_period += 1;
                                h.cameras[i].received += 1;
                                if !sync.is_active(i) {
                                    h.cameras[i].active = true;
                                    groups.extend(sync.set_active(i, true));
                                }
                            }
                            Err(reason) => {
                                h.cameras[i].bad_messages += 1;
                                h.cameras[i].last_bad_reason = Some(reason);
                            }
                        }
                        h.sync = sync.stats();
                    }
                    post_groups(&shared, groups);
                }
                _ = ticker.next() => {
                    if stop.load(Ordering::SeqCst) {
                        break;
                    }
                    let now = Instant::now();
                    // Cameras silent for longer than the timeout are no longer waited for,
                    // as long as at least MIN_ACTIVE_CAMERAS stay active.
                    let mut groups = Vec::new();
                    for (i, cam) in cams.iter().enumerate() {
                        let silent_since = cam.last_receipt.unwrap_or(started);
                        let active_count = (0..n).filter(|&k| sync.is_active(k)).count();
                        if sync.is_active(i)
                            && now.duration_since(silent_since) > timeout
                            && active_count > MIN_ACTIVE_CAMERAS
                        {
                            groups.extend(sync.set_active(i, false));
                            lock(&shared.health).cameras[i].active = false;
                        }
                    }
                    post_groups(&shared, groups);
                    let period = now.duration_since(last_diag);
                    if period >= DIAGNOSTICS_PERIOD {
                        let report = {
                            let mut h = lock(&shared.health);
                            for (i, c) in cams.iter_mut().enumerate() {
                                h.cameras[i].rate_hz =
                                    c.received_in_period as f64 / period.as_secs_f64();
                                h.cameras[i].age_secs =
                                    c.last_receipt.map(|t| now.duration_since(t).as_secs_f64());
                                c.received_in_period = 0;
                            }
                            h.sync = sync.stats();
                            diagnostic_array(wall_clock_ns(), &hardware_id, &h)
                        };
                        if let Err(e) = diagnostics.publish(report) {
                            tracing::warn!("publishing /diagnostics: {e:?}");
                        }
                        last_diag = now;
                    }
                }
            }
        }
    });

    {
        let mut mb = lock(&shared.mailbox);
        mb.shutdown = true;
    }
    shared.wake.notify_all();
    let worker_result = worker.join();
    drop(raw_subs);
    drop(compressed_subs);
    drop(tf_static);
    drop(diagnostics);
    spun.stop()?;
    drop(context);
    worker_result.map_err(|_| NodeError::ThreadPanic {
        thread: "inference".into(),
    })
}

/// Wall-clock time in ns since the epoch (0 if the clock is before it).
fn wall_clock_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
