//! The live ROS 2 node over ros2-client (RustDDS, no ROS install needed).
//!
//! Threads: a DDS thread runs a current-thread tokio runtime whose loop (`tokio::select!`)
//! receives every camera topic (sensor-data QoS: best effort, keep last), validates and
//! decodes each image and feeds [`ApproxTimeSync`]; with `use_sim_time` it also follows
//! `/clock` ([`NodeClock`]); a `tokio::time` ticker ([`TICK`]) times cameras out and publishes
//! `/diagnostics` once a second; a watch channel stops it. Complete groups go to a 1-slot
//! mailbox: a newer group replaces an unprocessed older one (counted as dropped), so no queue
//! grows without bound and inference never blocks DDS. An inference worker thread takes the
//! newest group, runs the [`Pipeline`] and publishes `depth`, `points` and `confidence`. A
//! third thread runs the ros2-client spinner (discovery) on its own tokio runtime; shutdown
//! stops it and waits for it. [`run_node`] waits for SIGINT or SIGTERM ([`ShutdownSignals`])
//! and then shuts everything down.

use super::clock::{secs_between, NodeClock};
use super::diagnostics::{diagnostic_array, CameraHealth, NodeHealth};
use super::params::{ImageTransport, NodeParams, ParamsError};
use super::pipeline::{Pipeline, PipelineError, PipelineParams};
use super::{
    resolve_topic, CLOCK_TOPIC, CONFIDENCE_TOPIC, DEPTH_TOPIC, DIAGNOSTICS_TOPIC, POINTS_TOPIC,
    TF_STATIC_TOPIC,
};
use crate::bag::rig_tf_static;
use crate::estimator::EstimatorError;
use crate::frame::RgbImage;
use crate::geometry::{Rig, RigError};
use crate::msgs::image::{rgb_from_compressed, rgb_from_image_msg};
use crate::msgs::{
    Clock, CompressedImage, DiagnosticArray, Image, PointCloud2, RosMessage, TFMessage,
};
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
use tokio::sync::watch;

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
    #[error("tokio: {what}: {problem}")]
    Runtime { what: String, problem: String },
}

/// A current-thread tokio runtime with timers and the I/O driver (signals need it).
pub fn runtime() -> Result<tokio::runtime::Runtime, NodeError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| NodeError::Runtime {
            what: "building the runtime".into(),
            problem: e.to_string(),
        })
}

/// SIGINT (Ctrl-C) and SIGTERM as one stream; install it before announcing that the
/// process is up so that no signal can hit the default handler (which kills the process).
pub struct ShutdownSignals {
    #[cfg(unix)]
    interrupt: tokio::signal::unix::Signal,
    #[cfg(unix)]
    terminate: tokio::signal::unix::Signal,
}

impl ShutdownSignals {
    /// Installs the handlers; must be called inside a tokio runtime (`Runtime::enter`).
    pub fn install() -> Result<Self, NodeError> {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            let err = |e: std::io::Error| NodeError::Runtime {
                what: "installing signal handlers".into(),
                problem: e.to_string(),
            };
            Ok(Self {
                interrupt: signal(SignalKind::interrupt()).map_err(err)?,
                terminate: signal(SignalKind::terminate()).map_err(err)?,
            })
        }
        #[cfg(not(unix))]
        Ok(Self {})
    }

    /// Waits for the next signal and returns its name (`SIGINT` or `SIGTERM`).
    pub async fn recv(&mut self) -> &'static str {
        #[cfg(unix)]
        {
            tokio::select! {
                _ = self.interrupt.recv() => "SIGINT",
                _ = self.terminate.recv() => "SIGTERM",
            }
        }
        #[cfg(not(unix))]
        {
            match tokio::signal::ctrl_c().await {
                Ok(()) => "Ctrl-C",
                Err(_) => std::future::pending().await,
            }
        }
    }
}

/// A flag that turns true on SIGINT or SIGTERM (a background thread waits for them), for
/// blocking loops such as [`crate::cli::play::play_bag_until`].
pub fn stop_flag_on_signals() -> Result<Arc<AtomicBool>, NodeError> {
    let rt = runtime()?;
    let mut signals = {
        let _guard = rt.enter();
        ShutdownSignals::install()?
    };
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    std::thread::Builder::new()
        .name("mode360-signals".into())
        .spawn(move || {
            let name = rt.block_on(signals.recv());
            tracing::info!("{name}: stopping");
            flag.store(true, Ordering::SeqCst);
        })
        .map_err(|e| NodeError::Runtime {
            what: "starting the signal thread".into(),
            problem: e.to_string(),
        })?;
    Ok(stop)
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

/// The DDS topic `topic` carrying `T`.
fn create_topic<T: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<ros2_client::dds::rustdds::Topic, NodeError> {
    node.create_topic(&ros_name(topic)?, message_type_name::<T>(), qos)
        .map_err(|e| NodeError::Dds {
            what: format!("creating topic '{topic}'"),
            problem: e.to_string(),
        })
}

/// Creates a publisher of `T` on `topic`.
pub fn create_publisher<T: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<Publisher<T>, NodeError> {
    let t = create_topic::<T>(node, topic, &qos)?;
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
    let t = create_topic::<T>(node, topic, &qos)?;
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
        let rt = runtime()?;
        let handle = std::thread::Builder::new()
            .name("mode360-spinner".into())
            .spawn(move || {
                if let Err(e) = rt.block_on(spinner.spin()) {
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

    /// Stops the spinner and waits for it. Dropping the node is what signals the spinner:
    /// ros2-client signals it again on drop, which after `stop_spinner` would log an error
    /// because the stopped spinner no longer listens.
    pub fn stop(self) -> Result<(), NodeError> {
        let Self { node, spinner } = self;
        drop(node);
        if let Some(h) = spinner {
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
    stop: watch::Sender<bool>,
    /// Closed (its sender dropped) when the DDS thread ends.
    done: watch::Receiver<()>,
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
pub fn spawn_node(params: NodeParams, dds: DdsOptions) -> Result<NodeHandle, NodeError> {
    let rig = Rig::from_file(&params.rig_file)?;
    let estimator = params.estimator.build()?;
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
    let (stop_tx, stop_rx) = watch::channel(false);
    let (done_tx, done_rx) = watch::channel(());
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), NodeError>>();
    let thread = {
        let shared = shared.clone();
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
    /// Node-clock time of the newest good message.
    last_receipt_ns: Option<u64>,
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

/// Everything the DDS thread sets up before it reports ready.
struct DdsSetup {
    context: Context,
    spun: SpunNode,
    publishers: OutputPublishers,
    tf_static: Publisher<TFMessage>,
    diagnostics: Publisher<DiagnosticArray>,
    raw_subs: Vec<(usize, ros2_client::Subscription<Image>)>,
    compressed_subs: Vec<(usize, ros2_client::Subscription<CompressedImage>)>,
    clock_sub: Option<ros2_client::Subscription<Clock>>,
}

fn dds_setup(params: &NodeParams, dds: &DdsOptions, rig: &Rig) -> Result<DdsSetup, NodeError> {
    let context = dds_context(dds)?;
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
    let tf_static: Publisher<TFMessage> = create_publisher(node, TF_STATIC_TOPIC, latched_qos())?;
    let diagnostics: Publisher<DiagnosticArray> =
        create_publisher(node, DIAGNOSTICS_TOPIC, output_qos())?;
    let mut raw_subs = Vec::new();
    let mut compressed_subs = Vec::new();
    for (i, cam) in rig.cameras.iter().enumerate() {
        let t = camera_topic(params, &cam.name, &cam.topic);
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
    let clock_sub = if params.use_sim_time {
        Some(create_subscription::<Clock>(
            node,
            CLOCK_TOPIC,
            clock_qos(),
        )?)
    } else {
        None
    };
    tf_static
        .publish(rig_tf_static(rig))
        .map_err(|e| format!("{e:?}"))
        .map_err(dds_err("publishing /tf_static"))?;
    Ok(DdsSetup {
        context,
        spun,
        publishers,
        tf_static,
        diagnostics,
        raw_subs,
        compressed_subs,
        clock_sub,
    })
}

/// `/clock` subscription QoS (rclcpp's ClockQoS): best effort, keep last 1; matches
/// reliable and best-effort publishers.
pub fn clock_qos() -> QosProfile {
    QosProfile::subscription_default().history(ros2_client::qos::History::KeepLast { depth: 1 })
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
}

impl Receiver {
    fn on_camera(&mut self, i: usize, result: Result<CameraMsg, String>) {
        let now_ns = self.clock.now_ns();
        if let Some(now) = now_ns {
            self.started_ns.get_or_insert(now);
        }
        let sync = &mut self.sync;
        let outcome = result
            .and_then(|msg| decode_camera(&msg))
            .and_then(|(stamp_ns, img)| sync.push(i, stamp_ns, img).map_err(|e| e.to_string()));
        let mut groups = Vec::new();
        {
            let mut h = lock(&self.shared.health);
            match outcome {
                Ok(g) => {
                    groups = g;
                    if now_ns.is_some() {
                        self.cams[i].last_receipt_ns = now_ns;
                    }
                    self.cams[i].received_in_period += 1;
                    h.cameras[i].received += 1;
                    if !self.sync.is_active(i) {
                        h.cameras[i].active = true;
                        groups.extend(self.sync.set_active(i, true));
                    }
                }
                Err(reason) => {
                    h.cameras[i].bad_messages += 1;
                    h.cameras[i].last_bad_reason = Some(reason);
                }
            }
            h.sync = self.sync.stats();
        }
        post_groups(&self.shared, groups);
    }

    fn on_tick(&mut self, diagnostics: &Publisher<DiagnosticArray>) {
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
                    h.cameras[i].age_secs = match (c.last_receipt_ns, now_ns) {
                        (Some(t), Some(now)) => Some(secs_between(t, now)),
                        _ => None,
                    };
                    c.received_in_period = 0;
                }
                h.sync = self.sync.stats();
                // Stamp 0 with simulated time before the first /clock, as in ROS 2.
                diagnostic_array(now_ns.unwrap_or(0), &self.hardware_id, &h)
            };
            if let Err(e) = diagnostics.publish(report) {
                tracing::warn!("publishing /diagnostics: {e:?}");
            }
            self.last_diag = Instant::now();
        }
    }
}

fn dds_main(
    params: NodeParams,
    dds: DdsOptions,
    rig: Rig,
    pipeline: Pipeline,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
    ready: std::sync::mpsc::Sender<Result<(), NodeError>>,
) -> Result<(), NodeError> {
    let setup = runtime().and_then(|rt| Ok((rt, dds_setup(&params, &dds, &rig)?)));
    let (rt, setup) = match setup {
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
    let DdsSetup {
        context,
        spun,
        publishers,
        tf_static,
        diagnostics,
        raw_subs,
        compressed_subs,
        clock_sub,
    } = setup;
    let worker = {
        let shared = shared.clone();
        std::thread::Builder::new()
            .name("mode360-inference".into())
            .spawn(move || worker_main(pipeline, publishers, shared))
            .map_err(|e| e.to_string())
            .map_err(dds_err("starting the inference thread"))?
    };
    let _ = ready.send(Ok(()));

    let n = rig.cameras.len();
    let mut rx = Receiver {
        sync: ApproxTimeSync::new(
            n,
            SyncConfig {
                tolerance_ns: (params.sync_tolerance_secs * 1e9).round() as u64,
                queue_size: params.sync_queue_size,
            },
        ),
        clock: NodeClock::new(params.use_sim_time),
        cams: (0..n)
            .map(|_| CameraState {
                last_receipt_ns: None,
                received_in_period: 0,
            })
            .collect(),
        started_ns: None,
        timeout_ns: (params.camera_timeout_secs * 1e9).round() as u64,
        shared: shared.clone(),
        hardware_id: params.fully_qualified_name(),
        last_diag: Instant::now(),
    };

    rt.block_on(async {
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
        let mut incoming = futures::stream::select(raw, compressed);
        let mut clock_msgs = match &clock_sub {
            Some(s) => s.async_stream().boxed(),
            None => futures::stream::pending().boxed(),
        };
        let mut ticker = tokio::time::interval(TICK);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                // A stop request, or the handle dropped.
                _ = stop.changed() => break,
                Some((i, result)) = incoming.next() => {
                    rx.on_camera(i, result.map_err(|e| format!("cannot deserialize: {e:?}")));
                }
                Some(result) = clock_msgs.next() => match result {
                    Ok((clock, _)) => rx.clock.on_clock(clock.clock.to_nanos()),
                    Err(e) => tracing::warn!("/clock: cannot deserialize: {e:?}"),
                },
                _ = ticker.tick() => rx.on_tick(&diagnostics),
            }
        }
    });

    {
        let mut mb = lock(&shared.mailbox);
        mb.shutdown = true;
        // A group still waiting for inference is not processed any more: dropped.
        if mb.slot.take().is_some() {
            lock(&shared.health).groups_dropped += 1;
        }
    }
    shared.wake.notify_all();
    let worker_result = worker.join();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sync::SyncStats;

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
