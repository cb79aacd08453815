//! mode360's ROS 2 node: subscriptions, camera sync, the depth pipeline shared with offline
//! replay, publishers, diagnostics and the Foxglove live view.
//!
//! The ROS 2 node: synchronized camera streams in, depth, points and confidence out.
//!
//! [`pipeline`] is the DDS-free core shared with offline replay (`mode360 replay`). The
//! parameters: [`params`] (what the node is configured with), [`param_table`] (each
//! parameter declared once), [`param_docs`] (their descriptors: the README's text, ranges,
//! read-only), [`ros_args`] (`--ros-args`), `params_file.rs` (ROS 2 params files),
//! [`ros_params`] (ROS 2 parameter services); [`diagnostics`] builds `/diagnostics`,
//! [`clock`] is the node's system or simulated clock, [`topics`] names every topic.
//!
//! The live node over ros2-client (RustDDS, no ROS install needed), one concern per file:
//! - [`dds`] (`dds.rs`): DDS plumbing, the node's small public API: [`DdsOptions`],
//!   [`dds_context`], the QoS profiles, [`create_publisher`], [`create_subscription`],
//!   [`SpunNode`] (a node plus its spinner thread) and the tokio [`runtime`];
//! - `shutdown.rs`: [`ShutdownSignals`] (SIGINT, SIGTERM) and [`stop_flag_on_signals`];
//! - `endpoints.rs`: the node's publishers and subscriptions, created once;
//! - `decode.rs`: camera messages validated and decoded into images;
//! - `receive.rs`: the DDS thread's receive loop: the synchronizer, camera timeouts, `/clock`
//!   and `/diagnostics`;
//! - `worker.rs`: the 1-slot mailbox (a newer group replaces an unprocessed one, counted as
//!   dropped) and the inference worker that runs the [`Pipeline`] and publishes `depth`,
//!   `points` and `confidence`;
//! - `run.rs`: the lifecycle: [`spawn_node`], [`NodeHandle`], [`run_node`] and [`NodeRun`];
//! - `error.rs`: [`NodeError`];
//! - [`live_view`]: the Foxglove WebSocket server (`foxglove_port`), fed by the receive loop
//!   (camera inputs, `/diagnostics`, `/tf_static`) and the worker (outputs);
//! - [`player`]: a bag played on DDS with its recorded timing (`play`, `demo`, `bench-node`).
//!
//! Threads: the DDS thread (receive loop), the inference worker and the ros2-client spinner
//! (discovery), each on its own; [`NodeHandle::shutdown`] stops them all and waits for them.
//! Module dependencies go one way: `run` → `receive` → `endpoints`, `decode`, `worker`; all of
//! them → `topics`, `params`, `dds`, `error`.

pub mod clock;
pub mod diagnostics;
pub mod discovery_range;
pub mod live_view;
pub mod outputs;
pub mod page_release;
pub mod param_docs;
pub mod param_table;
pub mod params;
mod params_file;
pub mod pipeline;
pub mod player;
pub mod qos_overrides;
pub mod ros_args;
pub mod ros_distro;
pub mod ros_params;
pub mod rosout;
pub mod tf_extrinsics;

pub use clock::{ClockSource, NodeClock};
pub use diagnostics::{diagnostic_array, CameraHealth, NodeHealth};
pub use params::{ImageTransport, NodeParams, ParamsError};
pub use pipeline::{Pipeline, PipelineError, PipelineOutput, PipelineParams};

/// Environment variable holding the DDS domain ([`DdsOptions::from_env`]).
pub const ROS_DOMAIN_ID_ENV: &str = "ROS_DOMAIN_ID";

pub mod topics;
pub use topics::{
    resolve_topic, CLOCK_TOPIC, COMPRESSED_DEPTH_TOPIC, CONFIDENCE_TOPIC, DEPTH_TOPIC,
    DIAGNOSTICS_TOPIC, POINTS_TOPIC, TF_STATIC_TOPIC,
};

pub mod dds;
mod decode;
mod endpoints;
mod error;
mod receive;
mod run;
mod shutdown;
mod worker;
pub use dds::{
    create_publisher, create_subscription, dds_context, latched_qos, output_qos, runtime,
    sensor_qos, DdsOptions, SpunNode,
};
pub use error::NodeError;
pub use run::{run_node, spawn_node, NodeHandle, NodeRun};
pub use shutdown::{stop_flag_on_signals, ShutdownSignals};
