//! The ROS 2 node: synchronized camera streams in, depth, points and confidence out.
//!
//! [`pipeline`] is the DDS-free core shared with offline replay ([`crate::cli::replay`]),
//! [`params`] parses `--ros-args` and params files, [`diagnostics`] builds `/diagnostics`,
//! [`clock`] is the node's system or simulated clock.

pub mod clock;
pub mod diagnostics;
pub mod params;
pub mod pipeline;

pub use clock::{ClockSource, NodeClock};
pub use diagnostics::{diagnostic_array, CameraHealth, NodeHealth};
pub use params::{ImageTransport, NodeParams, ParamsError};
pub use pipeline::{Pipeline, PipelineError, PipelineOutput, PipelineParams};

/// Relative topic of the range image.
pub const DEPTH_TOPIC: &str = "depth";
/// Relative topic of the point cloud.
pub const POINTS_TOPIC: &str = "points";
/// Relative topic of the confidence image.
pub const CONFIDENCE_TOPIC: &str = "confidence";
/// Absolute topic of the static transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
/// Absolute topic of the diagnostics.
pub const DIAGNOSTICS_TOPIC: &str = "/diagnostics";
/// Absolute topic of the simulated clock.
pub const CLOCK_TOPIC: &str = "/clock";

/// `name` resolved in `namespace` (`/` or `/a/b`): absolute names stay, relative ones are
/// prefixed.
pub fn resolve_topic(namespace: &str, name: &str) -> String {
    if name.starts_with('/') {
        name.to_string()
    } else {
        format!("{}/{}", namespace.trim_end_matches('/'), name)
    }
}

pub mod ros;
pub use ros::{
    create_publisher, create_subscription, dds_context, latched_qos, output_qos, run_node, runtime,
    sensor_qos, spawn_node, stop_flag_on_signals, DdsOptions, NodeError, NodeHandle, NodeRun,
    ShutdownSignals, SpunNode,
};
