//! What the node is configured with ([`NodeParams`]) and its defaults. The parameters are
//! declared in [`super::param_table`], read from `--ros-args` by [`super::ros_args`] and from
//! params files by `params_file.rs`.

use super::diagnostics::{DEFAULT_CALIBRATION_WARN_DEG, DEFAULT_LENS_WARN_FRACTION};
use super::live_view::{LiveViewAddress, FOXGLOVE_OFF};
use super::pipeline::{FarValue, PipelineParams};
use super::qos_overrides::QosOverrides;
use mode360_io::msgs::compressed_depth::DEFAULT_DEPTH_QUANTIZATION;
use std::collections::BTreeMap;
use std::net::{IpAddr, Ipv4Addr};
use std::path::PathBuf;

use mode360_estimator::EstimatorSpec;

/// Default node name.
pub const DEFAULT_NODE_NAME: &str = "mode360";
/// Default rig calibration.
pub const DEFAULT_RIG_FILE: &str = "launch_configs/rig_deep360.yaml";
/// Key under a node name holding its parameters.
pub const ROS_PARAMETERS_KEY: &str = "ros__parameters";
/// Wildcard node key matching every node.
pub const WILDCARD_NODE_KEY: &str = "/**";
/// Prefix of the per-camera transport parameters (`image_transport.cam2: compressed`).
pub const IMAGE_TRANSPORT_PREFIX: &str = "image_transport.";
/// Default interface of the Foxglove live view: loopback only.
pub const DEFAULT_FOXGLOVE_IP: Ipv4Addr = Ipv4Addr::LOCALHOST;

/// How a camera's images arrive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageTransport {
    /// `sensor_msgs/Image` on the camera's topic.
    Raw,
    /// `sensor_msgs/CompressedImage` on `<topic>/compressed`.
    Compressed,
}

impl ImageTransport {
    /// Its parameter spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Raw => "raw",
            Self::Compressed => "compressed",
        }
    }

    pub(super) fn parse(value: &str) -> Option<Self> {
        match value {
            "raw" => Some(Self::Raw),
            "compressed" => Some(Self::Compressed),
            _ => None,
        }
    }
}

/// Where the rig's extrinsics come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExtrinsicsSource {
    /// The rig YAML (`rig_file`).
    #[default]
    Yaml,
    /// `/tf_static` and `/tf` (the robot's URDF); the YAML still gives cameras and topics.
    Tf,
}

impl ExtrinsicsSource {
    /// Its parameter spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Yaml => "yaml",
            Self::Tf => "tf",
        }
    }
}

/// Bad arguments or parameters.
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    #[error("argument '{arg}': {problem}")]
    Argument { arg: String, problem: String },
    #[error("params file '{file}': {problem}")]
    File { file: String, problem: String },
    #[error("parameter '{name}' = '{value}': {problem}")]
    Value {
        name: String,
        value: String,
        problem: String,
    },
}

/// Everything the node is configured with.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeParams {
    pub node_name: String,
    /// Namespace, `/` or `/a/b`.
    pub namespace: String,
    pub rig_file: PathBuf,
    /// Parameters `estimator` and `weights` (SSMODE weights file, PSMODE's stage 1; empty: the
    /// shipped weights of the estimator).
    pub estimator: EstimatorSpec,
    pub output_width: usize,
    pub sync_tolerance_s: f64,
    pub sync_queue_size: usize,
    /// A camera silent for longer is no longer waited for.
    pub camera_timeout_s: f64,
    pub max_depth_m: f64,
    /// What `depth` holds beyond `max_depth_m` (REP 117: +Inf).
    pub far_value: FarValue,
    /// Pixels with a lower confidence are NaN in `depth` and have no point.
    pub min_confidence: f64,
    /// Quantization `Q` of `depth/compressedDepth` (image_transport's `depth_quantization`).
    pub depth_quantization: f64,
    pub use_sim_time: bool,
    /// Publish the rig's extrinsics on `/tf_static` (off where the robot's URDF does).
    pub publish_tf: bool,
    /// Output toggles (`points`, `confidence`, `depth/compressedDepth`); `depth` is always on.
    pub publish_points: bool,
    pub publish_confidence: bool,
    pub publish_compressed_depth: bool,
    /// Where `rig_from_cam` comes from.
    pub extrinsics_source: ExtrinsicsSource,
    /// How long to wait at start for the cameras' transforms with `extrinsics_source: tf`.
    pub tf_timeout_s: f64,
    /// `qos_overrides./<topic>.<publisher|subscription>.<policy>` parameters.
    pub qos_overrides: QosOverrides,
    /// Transport for cameras not named in `image_transport_per_camera`.
    pub image_transport_default: ImageTransport,
    /// Per camera name.
    pub image_transport_per_camera: BTreeMap<String, ImageTransport>,
    /// Topic remappings `from -> to` (names as written on the command line).
    pub remaps: BTreeMap<String, String>,
    /// Port of the Foxglove live view ([`FOXGLOVE_OFF`]: no server).
    pub foxglove_port: u16,
    /// Interface the Foxglove live view listens on.
    pub foxglove_address: IpAddr,
    /// A camera whose lens check finds more of its view blocked is WARN on `/diagnostics`.
    pub lens_warn_fraction: f64,
    /// The camera the calibration drift check suspects is WARN when turning it by more than
    /// this many degrees would make the cameras agree better.
    pub calibration_warn_deg: f64,
    /// Run the lens and calibration drift checks (off: no lens masks, their figures n/a).
    pub rig_health_checks: bool,
}

impl Default for NodeParams {
    fn default() -> Self {
        Self {
            node_name: DEFAULT_NODE_NAME.into(),
            namespace: "/".into(),
            rig_file: DEFAULT_RIG_FILE.into(),
            estimator: EstimatorSpec::default(),
            output_width: 512,
            sync_tolerance_s: 0.01,
            sync_queue_size: 5,
            camera_timeout_s: 1.0,
            max_depth_m: mode360_core::geometry::DEFAULT_MAX_DEPTH_M,
            far_value: FarValue::Inf,
            min_confidence: 0.0,
            depth_quantization: f64::from(DEFAULT_DEPTH_QUANTIZATION),
            use_sim_time: false,
            publish_tf: true,
            publish_points: true,
            publish_confidence: true,
            publish_compressed_depth: true,
            extrinsics_source: ExtrinsicsSource::Yaml,
            tf_timeout_s: 5.0,
            qos_overrides: QosOverrides::default(),
            image_transport_default: ImageTransport::Raw,
            image_transport_per_camera: BTreeMap::new(),
            remaps: BTreeMap::new(),
            foxglove_port: FOXGLOVE_OFF,
            foxglove_address: IpAddr::from(DEFAULT_FOXGLOVE_IP),
            lens_warn_fraction: DEFAULT_LENS_WARN_FRACTION,
            calibration_warn_deg: DEFAULT_CALIBRATION_WARN_DEG,
            rig_health_checks: true,
        }
    }
}

impl NodeParams {
    /// The pipeline's settings among these parameters.
    pub fn pipeline_params(&self) -> PipelineParams {
        PipelineParams {
            output_width: self.output_width,
            max_depth_m: self.max_depth_m as f32,
            far_value: self.far_value,
            min_confidence: self.min_confidence as f32,
            depth_quantization: self.depth_quantization as f32,
            rig_health_checks: self.rig_health_checks,
        }
    }

    /// Fully qualified node name, `/ns/name`.
    pub fn fully_qualified_name(&self) -> String {
        format!(
            "{}/{}",
            self.namespace.trim_end_matches('/'),
            self.node_name
        )
    }

    /// Transport used for `camera`.
    pub fn image_transport(&self, camera: &str) -> ImageTransport {
        self.image_transport_per_camera
            .get(camera)
            .copied()
            .unwrap_or(self.image_transport_default)
    }

    /// Where the Foxglove live view listens (`None`: `foxglove_port` is 0, no live view).
    pub fn live_view_address(&self) -> Option<LiveViewAddress> {
        (self.foxglove_port != FOXGLOVE_OFF).then_some(LiveViewAddress {
            address: self.foxglove_address,
            port: self.foxglove_port,
        })
    }

    /// `topic` after remapping (exact match of the name as written).
    pub fn remap(&self, topic: &str) -> String {
        self.remaps
            .get(topic)
            .cloned()
            .unwrap_or_else(|| topic.to_string())
    }
}
