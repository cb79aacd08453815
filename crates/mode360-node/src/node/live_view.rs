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

use foxglove::{Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use mode360_io::bag::{MESSAGE_ENCODING, SCHEMA_ENCODING};
use mode360_io::msgs::{
    encode_cdr, CompressedImage, DiagnosticArray, Image, PointCloud2, RosMessage, TFMessage,
};
use std::marker::PhantomData;
use std::net::IpAddr;
use std::sync::Arc;

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

/// The topics of one node, with their resolved names.
#[derive(Clone, Debug)]
pub struct LiveViewTopics {
    /// Per rig camera: its topic and whether it is compressed.
    pub cameras: Vec<(String, bool)>,
    pub depth: String,
    pub compressed_depth: String,
    pub points: String,
    pub confidence: String,
    pub tf_static: String,
    pub diagnostics: String,
}

/// The running server and the node's channels.
pub struct LiveView {
    pub cameras: Vec<CameraTopic>,
    pub depth: LiveTopic<Image>,
    pub compressed_depth: LiveTopic<CompressedImage>,
    pub points: LiveTopic<PointCloud2>,
    pub confidence: LiveTopic<Image>,
    pub tf_static: LiveTopic<TFMessage>,
    pub diagnostics: LiveTopic<DiagnosticArray>,
    port: u16,
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
        let depth = LiveTopic::new(&context, &topics.depth)?;
        let compressed_depth = LiveTopic::new(&context, &topics.compressed_depth)?;
        let points = LiveTopic::new(&context, &topics.points)?;
        let confidence = LiveTopic::new(&context, &topics.confidence)?;
        let tf_static = LiveTopic::new(&context, &topics.tf_static)?;
        let diagnostics = LiveTopic::new(&context, &topics.diagnostics)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(SERVER_THREADS)
            .thread_name("mode360-foxglove")
            .enable_all()
            .build()
            .map_err(|e| server_err(format!("cannot start its runtime: {e}")))?;
        let server = WebSocketServer::new()
            .name(SERVER_NAME)
            .bind(at.address.to_string(), at.port)
            .context(&context)
            .message_backlog_size(CLIENT_BACKLOG_MESSAGES)
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
            cameras.len() + 6
        );
        Ok(Self {
            cameras,
            depth,
            compressed_depth,
            points,
            confidence,
            tf_static,
            diagnostics,
            port,
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
    use std::net::{Ipv4Addr, TcpListener};

    fn topics() -> LiveViewTopics {
        LiveViewTopics {
            cameras: vec![
                ("/cam1/image_raw".into(), false),
                ("/cam2/image_raw".into(), true),
            ],
            depth: "/depth".into(),
            compressed_depth: "/depth/compressedDepth".into(),
            points: "/points".into(),
            confidence: "/confidence".into(),
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
        assert!(!view.depth.wanted() && !view.points.wanted());
        assert_eq!(view.points.topic(), "/points");
        assert!(matches!(view.cameras[1], CameraTopic::Compressed(_)));
    }
}
