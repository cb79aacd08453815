//! The node's topic names: the outputs (relative to the namespace), the absolute ones, and
//! how remapping, the namespace and the image transport resolve them.

use super::live_view::LiveViewTopics;
use super::outputs::PerOutput;
use super::params::{ImageTransport, NodeParams};
use mode360_core::geometry::Rig;

pub use super::outputs::{COMPRESSED_DEPTH_TOPIC, CONFIDENCE_TOPIC, DEPTH_TOPIC, POINTS_TOPIC};
/// Absolute topic of the static transforms (the bags' topic too).
pub use mode360_io::bag::TF_STATIC_TOPIC;
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

/// Suffix of image_transport's compressed topic.
pub const COMPRESSED_SUFFIX: &str = "compressed";

/// The topic camera `name` is received on (after remapping and transport suffix).
pub fn camera_topic(params: &NodeParams, name: &str, topic: &str) -> String {
    let base = params.remap(topic);
    match params.image_transport(name) {
        ImageTransport::Raw => base,
        ImageTransport::Compressed => format!("{base}/{COMPRESSED_SUFFIX}"),
    }
}

/// The topic output `name` (relative or absolute) is published on, after namespace and
/// remapping.
pub fn output_topic(params: &NodeParams, name: &str) -> String {
    match params.remaps.get(name) {
        // `-r depth:=range` remaps the relative name; the result resolves in the namespace.
        Some(to) => resolve_topic(&params.namespace, to),
        None => params.remap(&resolve_topic(&params.namespace, name)),
    }
}

/// The live view's topics: the node's, as on DDS.
pub fn live_view_topics(params: &NodeParams, rig: &Rig) -> LiveViewTopics {
    LiveViewTopics {
        cameras: rig
            .cameras
            .iter()
            .map(|c| {
                let compressed = params.image_transport(&c.name) == ImageTransport::Compressed;
                (camera_topic(params, &c.name, &c.topic), compressed)
            })
            .collect(),
        outputs: PerOutput::new(|o| output_topic(params, o.topic())),
        tf_static: TF_STATIC_TOPIC.to_string(),
        diagnostics: DIAGNOSTICS_TOPIC.to_string(),
    }
}
