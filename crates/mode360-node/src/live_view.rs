//! A live view without ROS: a Foxglove WebSocket server (the `foxglove` crate) that streams
//! the node's inputs and outputs, so the Foxglove app can look at a running node on a machine
//! with no ROS install and no DDS route to the robot.
//!
//! Every topic is a channel with `cdr` messages and a `ros2msg` schema, the same bytes and the
//! same schema text as on DDS and in the node's bags, so Foxglove decodes them as ROS 2
//! messages (its Image panel colour-maps the 32FC1 `depth`, its 3D panel draws `points` in
//! the frames of `/tf_static`). Channel names are the node's resolved DDS topics.
//!
//! A message is serialized only while a client subscribes to its channel
//! ([`LiveTopic::wanted`]); the worker also builds the point cloud and the compressed depth
//! for a live-view subscriber alone. `/tf_static` is latched on DDS but the WebSocket protocol
//! has no latching, so the receive loop sends it again once a second while subscribed.
//!
//! The server runs on its own small tokio runtime, so starting it works from any thread, also
//! inside another runtime. Each view has its own [`foxglove::Context`]: two nodes in one
//! process do not share channels.
//!
//! When a client leaves, the memory its queue held goes back to the kernel
//! ([`release_freed_pages`], [`RELEASE_DELAY`] later, through the allocator's release the
//! binary registered): the binary's jemalloc otherwise keeps freed pages for the next frame
//! (`muzzy_decay_ms:-1`, `src/main.rs`), and a node that once served stalled clients would keep
//! their backlog's size for good.

use super::outputs::{Output, OutputMessage, OutputType, PerOutput};
use super::page_release::release_freed_pages;
use foxglove::websocket::ServerListener;
use foxglove::{Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use mode360_io::bag::{MESSAGE_ENCODING, SCHEMA_ENCODING};
use mode360_io::msgs::{
    encode_cdr, CompressedImage, DiagnosticArray, Image, PointCloud2, RosMessage, TFMessage,
};
use std::marker::PhantomData;
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Port of Foxglove's WebSocket connection by default (what the app suggests).
pub const DEFAULT_FOXGLOVE_PORT: u16 = 8765;
/// `foxglove_port` value that switches the live view off (the node's default).
pub const FOXGLOVE_OFF: u16 = 0;
/// Name the server announces to clients.
pub const SERVER_NAME: &str = "mode360";
/// Worker threads of the server's runtime (it only moves bytes).
const SERVER_THREADS: usize = 1;
/// Messages queued per client before the oldest are dropped. The SDK's default (1024) lets a
/// client that subscribes to everything and never reads hold about a gigabyte of images and
/// clouds (a group's messages are up to 1.5 MiB at 512 wide); 16 is about three groups.
pub const CLIENT_BACKLOG_MESSAGES: usize = 16;
/// How long after a client disconnects its freed memory is handed back to the kernel: the
/// server drops the client's queue once its connection task ends, shortly after the
/// disconnect is reported. Disconnects within this time share one release.
pub const RELEASE_DELAY: Duration = Duration::from_secs(1);
/// Releases freed pages [`RELEASE_DELAY`] after a client disconnects (one release pending at
/// a time), on the server's runtime.
struct ReleaseOnDisconnect {
    runtime: tokio::runtime::Handle,
    pending: Arc<AtomicBool>,
    /// Releases done so far.
    releases: Arc<AtomicUsize>,
}

impl ServerListener for ReleaseOnDisconnect {
    fn on_client_disconnect(&self) {
        if self.pending.swap(true, Ordering::AcqRel) {
            return;
        }
        let (pending, releases) = (self.pending.clone(), self.releases.clone());
        self.runtime.spawn(async move {
            tokio::time::sleep(RELEASE_DELAY).await;
            pending.store(false, Ordering::Release);
            let before = mode360_core::memory::resident_mib();
            let released = tokio::task::spawn_blocking(release_freed_pages)
                .await
                .unwrap_or(false);
            let after = mode360_core::memory::resident_mib();
            releases.fetch_add(1, Ordering::AcqRel);
            if let (true, Some(before), Some(after)) = (released, before, after) {
                tracing::debug!(
                    "live view: a client left; resident memory {before:.0} -> {after:.0} MiB"
                );
            }
        });
    }
}

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveViewError {
    #[error("Foxglove live view on {address}:{port}: {problem}")]
    Server {
        address: String,
        port: u16,
        problem: String,
    },
    #[error("Foxglove live view: channel '{topic}': {problem}")]
    Channel { topic: String, problem: String },
}

/// Where the live view listens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LiveViewAddress {
    pub address: IpAddr,
    /// 1..=65535 (0 is [`FOXGLOVE_OFF`] in the parameters, never a bind request).
    pub port: u16,
}

/// One topic of the live view, typed by its ROS message.
pub struct LiveTopic<T> {
    channel: Arc<RawChannel>,
    _msg: PhantomData<fn(&T)>,
}

impl<T: RosMessage> LiveTopic<T> {
    fn new(context: &Arc<Context>, topic: &str) -> Result<Self, LiveViewError> {
        let problem = |problem: String| LiveViewError::Channel {
            topic: topic.to_string(),
            problem,
        };
        let schema_text = T::schema_text().map_err(|e| problem(e.to_string()))?;
        let channel = context
            .channel_builder(topic)
            .message_encoding(MESSAGE_ENCODING)
            .schema(Schema::new(
                T::TYPE_NAME,
                SCHEMA_ENCODING,
                schema_text.into_bytes(),
            ))
            .build_raw()
            .map_err(|e| problem(e.to_string()))?;
        Ok(Self {
            channel,
            _msg: PhantomData,
        })
    }

    /// Whether a client subscribes to this topic now.
    pub fn wanted(&self) -> bool {
        self.channel.has_sinks()
    }

    /// Sends `msg` to the subscribed clients (serialized only when there is one).
    pub fn log(&self, msg: &T) {
        if self.wanted() {
            self.channel.log(&encode_cdr(msg));
        }
    }

    /// The channel's topic.
    pub fn topic(&self) -> &str {
        self.channel.topic()
    }
}

/// A camera's input channel, as the camera sends it.
pub enum CameraTopic {
    Raw(LiveTopic<Image>),
    Compressed(LiveTopic<CompressedImage>),
}

/// An output's channel, of the output's message type ([`Output::message_type`]).
pub enum OutputChannel {
    Image(LiveTopic<Image>),
    CompressedImage(LiveTopic<CompressedImage>),
    PointCloud(LiveTopic<PointCloud2>),
}

impl OutputChannel {
    fn new(context: &Arc<Context>, topic: &str, ty: OutputType) -> Result<Self, LiveViewError> {
        Ok(match ty {
            OutputType::Image => Self::Image(LiveTopic::new(context, topic)?),
            OutputType::CompressedImage => Self::CompressedImage(LiveTopic::new(context, topic)?),
            OutputType::PointCloud => Self::PointCloud(LiveTopic::new(context, topic)?),
        })
    }

    /// Whether a client subscribes.
    pub fn wanted(&self) -> bool {
        match self {
            Self::Image(t) => t.wanted(),
            Self::CompressedImage(t) => t.wanted(),
            Self::PointCloud(t) => t.wanted(),
        }
    }

    /// The channel's topic.
    pub fn topic(&self) -> &str {
        match self {
            Self::Image(t) => t.topic(),
            Self::CompressedImage(t) => t.topic(),
            Self::PointCloud(t) => t.topic(),
        }
    }

    /// Sends `msg` to the subscribed clients; a message of another type than the channel's is
    /// not sent (the output table gives both, so it cannot happen).
    pub fn log(&self, msg: OutputMessage<'_>) {
        match (self, msg) {
            (Self::Image(t), OutputMessage::Image(m)) => t.log(m),
            (Self::CompressedImage(t), OutputMessage::CompressedImage(m)) => t.log(m),
            (Self::PointCloud(t), OutputMessage::PointCloud(m)) => t.log(m),
            _ => tracing::debug!("live view: a message not of {}'s type", self.topic()),
        }
    }
}

/// The topics of one node, with their resolved names.
#[derive(Clone, Debug)]
pub struct LiveViewTopics {
    /// Per rig camera: its topic and whether it is compressed.
    pub cameras: Vec<(String, bool)>,
    /// Each output's topic.
    pub outputs: PerOutput<String>,
    pub tf_static: String,
    pub diagnostics: String,
}

/// The running server and the node's channels.
pub struct LiveView {
    pub cameras: Vec<CameraTopic>,
    /// Each output's channel.
    pub outputs: PerOutput<OutputChannel>,
    pub tf_static: LiveTopic<TFMessage>,
    pub diagnostics: LiveTopic<DiagnosticArray>,
    port: u16,
    /// Times freed memory was released after clients left.
    releases: Arc<AtomicUsize>,
    server: Option<WebSocketServerHandle>,
    /// Dropped last: the server's tasks run on it.
    runtime: Option<tokio::runtime::Runtime>,
    _context: Arc<Context>,
}

impl LiveView {
    /// Starts a server on `at` advertising `topics`.
    pub fn start(at: &LiveViewAddress, topics: &LiveViewTopics) -> Result<Self, LiveViewError> {
        let server_err = |problem: String| LiveViewError::Server {
            address: at.address.to_string(),
            port: at.port,
            problem,
        };
        let context = Context::new();
        let cameras = topics
            .cameras
            .iter()
            .map(|(topic, compressed)| {
                Ok(if *compressed {
                    CameraTopic::Compressed(LiveTopic::new(&context, topic)?)
                } else {
                    CameraTopic::Raw(LiveTopic::new(&context, topic)?)
                })
            })
            .collect::<Result<Vec<_>, LiveViewError>>()?;
        let outputs = PerOutput::try_new(|o: Output| {
            OutputChannel::new(&context, &topics.outputs[o], o.message_type())
        })?;
        let tf_static = LiveTopic::new(&context, &topics.tf_static)?;
        let diagnostics = LiveTopic::new(&context, &topics.diagnostics)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(SERVER_THREADS)
            .thread_name("mode360-foxglove")
            .enable_all()
            .build()
            .map_err(|e| server_err(format!("cannot start its runtime: {e}")))?;
        let releases = Arc::new(AtomicUsize::new(0));
        let server = WebSocketServer::new()
            .name(SERVER_NAME)
            .bind(at.address.to_string(), at.port)
            .context(&context)
            .message_backlog_size(CLIENT_BACKLOG_MESSAGES)
            .listener(Arc::new(ReleaseOnDisconnect {
                runtime: runtime.handle().clone(),
                pending: Arc::new(AtomicBool::new(false)),
                releases: releases.clone(),
            }))
            .tokio_runtime(runtime.handle());
        // Started from a plain thread: `block_on` refuses to run inside another runtime.
        let handle = std::thread::scope(|s| {
            s.spawn(|| runtime.block_on(server.start()))
                .join()
                .map_err(|_| server_err("its start panicked".into()))
        })?
        .map_err(|e| server_err(e.to_string()))?;
        let port = handle.port();
        tracing::info!(
            "Foxglove live view on ws://{}:{port} ({} channels)",
            at.address,
            cameras.len() + Output::ALL.len() + 2
        );
        Ok(Self {
            cameras,
            outputs,
            tf_static,
            diagnostics,
            port,
            releases,
            server: Some(handle),
            runtime: Some(runtime),
            _context: context,
        })
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Clients connected now.
    pub fn client_count(&self) -> usize {
        self.server.as_ref().map_or(0, |s| s.client_count())
    }

    /// How many times memory freed by departed clients was handed back to the kernel.
    pub fn memory_releases(&self) -> usize {
        self.releases.load(Ordering::Acquire)
    }

    /// Sends camera `i`'s message (raw or compressed, as received).
    pub fn log_camera_raw(&self, i: usize, msg: &Image) {
        if let Some(CameraTopic::Raw(t)) = self.cameras.get(i) {
            t.log(msg);
        }
    }

    /// Sends camera `i`'s compressed message.
    pub fn log_camera_compressed(&self, i: usize, msg: &CompressedImage) {
        if let Some(CameraTopic::Compressed(t)) = self.cameras.get(i) {
            t.log(msg);
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        if let (Some(server), Some(runtime)) = (self.server.take(), self.runtime.take()) {
            // Closes the clients' connections and waits for the server's tasks, off any
            // async context (the node may be dropped from inside one).
            let shutdown = server.stop();
            let _ = std::thread::scope(|s| {
                s.spawn(move || {
                    runtime.block_on(shutdown.wait());
                    runtime.shutdown_background();
                })
                .join()
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::memory::resident_mib;
    use std::io::{Read, Write};
    use std::net::{Ipv4Addr, TcpListener, TcpStream};
    use std::time::Instant;

    /// The unit tests allocate as the binary does (`src/main.rs`): jemalloc, freed pages kept.
    #[global_allocator]
    static JEMALLOC: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;
    #[allow(non_upper_case_globals)]
    #[export_name = "_rjem_malloc_conf"]
    pub static malloc_conf: &[u8] = b"oversize_threshold:0,muzzy_decay_ms:-1\0";

    /// The release `src/main.rs` registers: jemalloc's purge of every arena.
    fn purge_jemalloc() -> bool {
        // SAFETY: `arena.<i>.purge` reads and writes nothing (all pointers null, length 0).
        let rc = unsafe {
            tikv_jemalloc_sys::mallctl(
                c"arena.4096.purge".as_ptr(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                0,
            )
        };
        rc == 0
    }

    fn topics() -> LiveViewTopics {
        LiveViewTopics {
            cameras: vec![
                ("/cam1/image_raw".into(), false),
                ("/cam2/image_raw".into(), true),
            ],
            outputs: PerOutput::new(|o| format!("/{}", o.topic())),
            tf_static: "/tf_static".into(),
            diagnostics: "/diagnostics".into(),
        }
    }

    #[test]
    fn a_port_in_use_is_an_error_naming_the_address() {
        let taken = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).unwrap();
        let port = taken.local_addr().unwrap().port();
        let at = LiveViewAddress {
            address: Ipv4Addr::LOCALHOST.into(),
            port,
        };
        let e = LiveView::start(&at, &topics()).err().unwrap().to_string();
        assert!(e.contains(&format!("127.0.0.1:{port}")), "{e}");
    }

    fn free_port() -> LiveViewAddress {
        let taken = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).unwrap();
        let port = taken.local_addr().unwrap().port();
        LiveViewAddress {
            address: Ipv4Addr::LOCALHOST.into(),
            port,
        }
    }

    #[test]
    fn freed_pages_go_back_to_the_kernel_only_when_released() {
        const BLOCKS: usize = 256;
        let blocks: Vec<Vec<u8>> = (0..BLOCKS).map(|i| vec![i as u8 | 1; 1 << 20]).collect();
        let held = resident_mib().unwrap();
        drop(blocks);
        let kept = resident_mib().unwrap();
        crate::page_release::set_page_release(purge_jemalloc);
        assert!(release_freed_pages());
        let released = resident_mib().unwrap();
        // Without a release jemalloc keeps the 256 MiB resident; with one, they are gone.
        assert!(held - kept < 64.0, "held {held:.0}, kept {kept:.0} MiB");
        assert!(
            held - released > 200.0,
            "held {held:.0}, after release {released:.0} MiB"
        );
    }

    #[test]
    fn a_client_leaving_releases_freed_memory() {
        let at = free_port();
        let view = LiveView::start(&at, &topics()).unwrap();
        let mut ws = TcpStream::connect((at.address, at.port)).unwrap();
        write!(
            ws,
            "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n\
             Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\
             Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
        )
        .unwrap();
        let mut reply = [0u8; 12];
        ws.read_exact(&mut reply).unwrap();
        assert_eq!(&reply, b"HTTP/1.1 101");
        let deadline = Instant::now() + Duration::from_secs(5);
        while view.client_count() != 1 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(view.client_count(), 1);
        assert_eq!(view.memory_releases(), 0);
        drop(ws);
        let left = Instant::now();
        while view.memory_releases() == 0 && left.elapsed() < RELEASE_DELAY * 5 {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(view.client_count(), 0);
        assert_eq!(view.memory_releases(), 1);
        assert!(left.elapsed() >= RELEASE_DELAY, "{:?}", left.elapsed());
    }

    #[test]
    fn nothing_is_wanted_without_a_client() {
        let taken = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).unwrap();
        let port = taken.local_addr().unwrap().port();
        drop(taken);
        let at = LiveViewAddress {
            address: Ipv4Addr::LOCALHOST.into(),
            port,
        };
        let view = LiveView::start(&at, &topics()).unwrap();
        assert_eq!(view.port(), port);
        assert_eq!(view.client_count(), 0);
        assert!(Output::ALL.iter().all(|&o| !view.outputs[o].wanted()));
        assert_eq!(view.outputs[Output::Points].topic(), "/points");
        assert_eq!(
            view.outputs[Output::CompressedDepth].topic(),
            "/depth/compressedDepth"
        );
        assert!(matches!(view.cameras[1], CameraTopic::Compressed(_)));
    }
}
