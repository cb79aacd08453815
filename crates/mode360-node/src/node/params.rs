//! Node parameters from ROS 2 command-line arguments and params files.
//!
//! Accepted `--ros-args` forms (as `ros2 run` passes them): `--params-file FILE`,
//! `-p name:=value` / `--param name:=value`, `-r from:=to` / `--remap from:=to`,
//! `-r __ns:=/x`, `-r __node:=name`, and `--` (or a later `--ros-args`) closing a section.
//! Params files use the ROS 2 layout: `node_name: {ros__parameters: {...}}` where the key may
//! be the node name, `/node_name`, `/ns/node_name` or the wildcard `/**`. Nested maps become
//! dotted names (`sync: {tolerance_s: 0.01}` is `sync.tolerance_s`). Later sources win.

use super::live_view::{LiveViewAddress, FOXGLOVE_OFF};
use super::pipeline::FarValue;
use super::qos_overrides::{QosOverrides, QOS_OVERRIDES_PREFIX};
use mode360_io::msgs::compressed_depth::DEFAULT_DEPTH_QUANTIZATION;
use std::collections::BTreeMap;
use std::net::{IpAddr, Ipv4Addr};
use std::path::PathBuf;

use mode360_estimator::estimator::{EstimatorError, EstimatorSpec};

/// Default node name.
pub const DEFAULT_NODE_NAME: &str = "mode360";
/// Default rig calibration.
pub const DEFAULT_RIG_FILE: &str = "launch_configs/rig_deep360.yaml";
/// Key under a node name holding its parameters.
pub const ROS_PARAMETERS_KEY: &str = "ros__parameters";
/// Wildcard node key matching every node.
pub const WILDCARD_NODE_KEY: &str = "/**";
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

    fn parse(value: &str) -> Option<Self> {
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
    /// Parameters `estimator` and `weights` (SSMODE weights file; empty: the shipped weights).
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
            max_depth_m: 1000.0,
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
        }
    }
}

/// A parameter source in command-line order.
enum Source {
    File(PathBuf),
    Param { name: String, value: String },
}

impl NodeParams {
    /// Parses everything after `mode360 node` (ROS arguments must follow `--ros-args`).
    pub fn from_args(args: &[String]) -> Result<Self, ParamsError> {
        let mut params = Self::default();
        let mut sources = Vec::new();
        let mut in_ros_args = false;
        let mut it = args.iter();
        while let Some(arg) = it.next() {
            let mut value_of = |flag: &str| {
                it.next().cloned().ok_or_else(|| ParamsError::Argument {
                    arg: flag.to_string(),
                    problem: "needs a value".into(),
                })
            };
            match arg.as_str() {
                "--ros-args" => in_ros_args = true,
                "--" if in_ros_args => in_ros_args = false,
                _ if !in_ros_args => {
                    return Err(ParamsError::Argument {
                        arg: arg.clone(),
                        problem: "unexpected; node settings go after --ros-args".into(),
                    })
                }
                "--params-file" => sources.push(Source::File(value_of(arg)?.into())),
                "-p" | "--param" => {
                    let (name, value) = split_assignment(arg, &value_of(arg)?)?;
                    sources.push(Source::Param { name, value });
                }
                "-r" | "--remap" => {
                    let (from, to) = split_assignment(arg, &value_of(arg)?)?;
                    match from.as_str() {
                        "__ns" => params.namespace = normalize_namespace(&to),
                        "__node" | "__name" => params.node_name = to,
                        _ => {
                            params.remaps.insert(from, to);
                        }
                    }
                }
                "--log-level" | "--enclave" => {
                    value_of(arg)?;
                }
                "--disable-rosout-logs" | "--disable-stdout-logs" | "--enable-rosout-logs" => {}
                other => {
                    return Err(ParamsError::Argument {
                        arg: other.into(),
                        problem: "unknown ROS argument".into(),
                    })
                }
            }
        }
        for source in sources {
            match source {
                Source::File(path) => {
                    let file = path.display().to_string();
                    let text = std::fs::read_to_string(&path).map_err(|e| ParamsError::File {
                        file: file.clone(),
                        problem: e.to_string(),
                    })?;
                    for (name, value) in params.file_parameters(&text, &file)? {
                        // A bad value names the file as well as the parameter.
                        params.set(&name, &value).map_err(|e| ParamsError::File {
                            file: file.clone(),
                            problem: e.to_string(),
                        })?;
                    }
                }
                Source::Param { name, value } => params.set(&name, &value)?,
            }
        }
        Ok(params)
    }

    /// Fully qualified node name, `/ns/name`.
    pub fn fully_qualified_name(&self) -> String {
        format!(
            "{}/{}",
            self.namespace.trim_end_matches('/'),
            self.node_name
        )
    }

    /// The parameters in `text` (a params file) that apply to this node, as dotted names
    /// and YAML scalar text, wildcard entries first so that named entries override them.
    fn file_parameters(
        &self,
        text: &str,
        file: &str,
    ) -> Result<Vec<(String, String)>, ParamsError> {
        let err = |problem: String| ParamsError::File {
            file: file.to_string(),
            problem,
        };
        let doc: serde_yaml::Value =
            serde_yaml::from_str(text).map_err(|e| err(format!("not YAML: {e}")))?;
        let map = doc
            .as_mapping()
            .ok_or_else(|| err("top level must map node names to ros__parameters".into()))?;
        let fq = self.fully_qualified_name();
        let matches = |key: &str| -> Option<u8> {
            if key == WILDCARD_NODE_KEY {
                Some(0)
            } else if key == self.node_name
                || key.trim_start_matches('/') == self.node_name
                || key == fq
                || key == format!("{}/**", self.namespace.trim_end_matches('/'))
            {
                Some(1)
            } else {
                None
            }
        };
        let mut entries: Vec<(u8, &serde_yaml::Value)> = Vec::new();
        for (key, value) in map {
            let key = key
                .as_str()
                .ok_or_else(|| err("node keys must be strings".into()))?;
            if let Some(rank) = matches(key) {
                entries.push((rank, value));
            }
        }
        entries.sort_by_key(|(rank, _)| *rank);
        let mut out = Vec::new();
        for (_, node_value) in entries {
            let params = node_value
                .get(ROS_PARAMETERS_KEY)
                .ok_or_else(|| err(format!("node entry has no '{ROS_PARAMETERS_KEY}' key")))?;
            flatten("", params, &mut out).map_err(err)?;
        }
        Ok(out)
    }

    /// Sets one parameter from its text value.
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), ParamsError> {
        let bad = |problem: &str| ParamsError::Value {
            name: name.to_string(),
            value: value.to_string(),
            problem: problem.to_string(),
        };
        let positive_f64 = || -> Result<f64, ParamsError> {
            value
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| bad("expected a positive number"))
        };
        let boolean = || -> Result<bool, ParamsError> {
            match value {
                "true" | "True" => Ok(true),
                "false" | "False" => Ok(false),
                _ => Err(bad("expected true or false")),
            }
        };
        let positive_usize = || -> Result<usize, ParamsError> {
            value
                .parse::<usize>()
                .ok()
                .filter(|v| *v > 0)
                .ok_or_else(|| bad("expected a positive integer"))
        };
        match name {
            "rig_file" => self.rig_file = value.into(),
            "estimator" => {
                self.estimator.kind = value
                    .parse()
                    .map_err(|e: EstimatorError| bad(&e.to_string()))?
            }
            "weights" => self.estimator.weights = (!value.is_empty()).then(|| PathBuf::from(value)),
            "output_width" => {
                let w = positive_usize()?;
                if w % 2 != 0 {
                    return Err(bad("output width must be even"));
                }
                self.output_width = w;
            }
            "sync.tolerance_s" => self.sync_tolerance_s = positive_f64()?,
            "sync.queue_size" => self.sync_queue_size = positive_usize()?,
            "camera_timeout_s" => self.camera_timeout_s = positive_f64()?,
            // Names before the units were unified (seconds are `_s` everywhere).
            "sync.tolerance_secs" | "camera_timeout_secs" => {
                let current = name.replace("_secs", "_s");
                tracing::warn!("parameter '{name}' is deprecated: use '{current}'");
                return self.set(&current, value);
            }
            "max_depth_m" => self.max_depth_m = positive_f64()?,
            "depth_far_value" => {
                self.far_value = FarValue::parse(value).ok_or_else(|| {
                    bad(&format!("expected one of: {}", FarValue::NAMES.join(", ")))
                })?
            }
            "depth_quantization" => self.depth_quantization = positive_f64()?,
            "min_confidence" => {
                self.min_confidence = value
                    .parse::<f64>()
                    .ok()
                    .filter(|c| (0.0..=1.0).contains(c))
                    .ok_or_else(|| bad("expected a number from 0 to 1"))?
            }
            "publish_tf" => self.publish_tf = boolean()?,
            "publish_points" => self.publish_points = boolean()?,
            "publish_confidence" => self.publish_confidence = boolean()?,
            "publish_compressed_depth" => self.publish_compressed_depth = boolean()?,
            "extrinsics_source" => {
                self.extrinsics_source = match value {
                    "yaml" => ExtrinsicsSource::Yaml,
                    "tf" => ExtrinsicsSource::Tf,
                    _ => return Err(bad("expected one of: yaml, tf")),
                }
            }
            "tf_timeout_s" => self.tf_timeout_s = positive_f64()?,
            "use_sim_time" => self.use_sim_time = boolean()?,
            "foxglove_port" => {
                self.foxglove_port = value
                    .parse::<u16>()
                    .map_err(|_| bad("expected a TCP port from 1 to 65535, or 0 for no live view"))?
            }
            "foxglove_address" => {
                self.foxglove_address = value.parse::<IpAddr>().map_err(|_| {
                    bad("expected an IP address (127.0.0.1: this machine only; 0.0.0.0: every interface)")
                })?
            }
            "image_transport" => {
                self.image_transport_default =
                    ImageTransport::parse(value).ok_or_else(|| bad("expected raw or compressed"))?
            }
            _ => {
                if let Some(rest) = name.strip_prefix(QOS_OVERRIDES_PREFIX) {
                    self.qos_overrides.set(rest, value).map_err(|p| bad(&p))?;
                } else if let Some(camera) = name.strip_prefix("image_transport.") {
                    let t = ImageTransport::parse(value)
                        .ok_or_else(|| bad("expected raw or compressed"))?;
                    self.image_transport_per_camera
                        .insert(camera.to_string(), t);
                } else {
                    return Err(bad("unknown parameter"));
                }
            }
        }
        Ok(())
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

/// Splits `name:=value`.
fn split_assignment(flag: &str, text: &str) -> Result<(String, String), ParamsError> {
    text.split_once(":=")
        .map(|(a, b)| (a.trim().to_string(), b.trim().to_string()))
        .filter(|(a, _)| !a.is_empty())
        .ok_or_else(|| ParamsError::Argument {
            arg: format!("{flag} {text}"),
            problem: "expected name:=value".into(),
        })
}

/// `/`-prefixed namespace without a trailing slash (except the root `/`).
fn normalize_namespace(ns: &str) -> String {
    let trimmed = ns.trim_matches('/');
    format!("/{trimmed}")
}

/// Dotted names and scalar text of a nested YAML map.
fn flatten(
    prefix: &str,
    value: &serde_yaml::Value,
    out: &mut Vec<(String, String)>,
) -> Result<(), String> {
    use serde_yaml::Value;
    let scalar = match value {
        Value::Mapping(map) => {
            for (k, v) in map {
                let key = k
                    .as_str()
                    .ok_or_else(|| format!("parameter names must be strings (under '{prefix}')"))?;
                let name = if prefix.is_empty() {
                    key.to_string()
                } else {
                    format!("{prefix}.{key}")
                };
                flatten(&name, v, out)?;
            }
            return Ok(());
        }
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => n.to_string(),
        Value::String(s) => s.clone(),
        Value::Null => return Err(format!("parameter '{prefix}' has no value")),
        Value::Sequence(_) | Value::Tagged(_) => {
            return Err(format!("parameter '{prefix}': lists are not supported"))
        }
    };
    out.push((prefix.to_string(), scalar));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(list: &[&str]) -> Vec<String> {
        list.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn command_line_params_and_remaps() {
        let p = NodeParams::from_args(&args(&[
            "--ros-args",
            "-p",
            "output_width:=256",
            "-p",
            "sync.tolerance_s:=0.02",
            "--param",
            "use_sim_time:=true",
            "-r",
            "__ns:=/robot1/",
            "-r",
            "__node:=depth360",
            "-r",
            "/cam1/image_raw:=/front/image",
            "-p",
            "image_transport.cam2:=compressed",
            "-p",
            "weights:=runs/x/ssmode_compact.safetensors",
        ]))
        .unwrap();
        assert_eq!(
            p.estimator.weights.as_deref(),
            Some(std::path::Path::new("runs/x/ssmode_compact.safetensors"))
        );
        assert_eq!(p.output_width, 256);
        assert_eq!(p.sync_tolerance_s, 0.02);
        assert!(p.use_sim_time);
        assert_eq!(p.namespace, "/robot1");
        assert_eq!(p.node_name, "depth360");
        assert_eq!(p.fully_qualified_name(), "/robot1/depth360");
        assert_eq!(p.remap("/cam1/image_raw"), "/front/image");
        assert_eq!(p.remap("/cam3/image_raw"), "/cam3/image_raw");
        assert_eq!(p.image_transport("cam2"), ImageTransport::Compressed);
        assert_eq!(p.image_transport("cam1"), ImageTransport::Raw);
    }

    #[test]
    fn a_bad_value_in_a_params_file_names_the_file_parameter_and_allowed_values() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("bad.yaml");
        std::fs::write(
            &file,
            "mode360:\n  ros__parameters:\n    depth_far_value: zero\n",
        )
        .unwrap();
        let f = file.display().to_string();
        let err = NodeParams::from_args(&args(&["--ros-args", "--params-file", &f]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("bad.yaml")
                && err.contains("depth_far_value")
                && err.contains("inf, max_depth"),
            "{err}"
        );
    }

    #[test]
    fn rep117_parameters_are_validated() {
        let p = NodeParams::from_args(&args(&[
            "--ros-args",
            "-p",
            "depth_far_value:=max_depth",
            "-p",
            "min_confidence:=0.25",
        ]))
        .unwrap();
        assert_eq!(p.far_value, FarValue::MaxDepth);
        assert_eq!(p.min_confidence, 0.25);
        assert_eq!(NodeParams::default().far_value, FarValue::Inf);
        let err = NodeParams::from_args(&args(&["--ros-args", "-p", "depth_far_value:=zero"]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("depth_far_value") && err.contains("inf, max_depth"),
            "{err}"
        );
        let err = NodeParams::from_args(&args(&["--ros-args", "-p", "min_confidence:=1.5"]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("min_confidence") && err.contains("0 to 1"),
            "{err}"
        );
    }

    #[test]
    fn deprecated_secs_names_still_set_the_seconds() {
        let p = NodeParams::from_args(&args(&[
            "--ros-args",
            "-p",
            "sync.tolerance_secs:=0.03",
            "-p",
            "camera_timeout_secs:=2.5",
        ]))
        .unwrap();
        assert_eq!(p.sync_tolerance_s, 0.03);
        assert_eq!(p.camera_timeout_s, 2.5);
        assert!(
            NodeParams::from_args(&args(&["--ros-args", "-p", "camera_timeout_secs:=-1"])).is_err()
        );
    }

    #[test]
    fn params_file_layout_with_wildcard_and_named_node() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("p.yaml");
        std::fs::write(
            &file,
            "/**:\n  ros__parameters:\n    use_sim_time: true\n    max_depth_m: 50.0\n\
             mode360:\n  ros__parameters:\n    estimator: photometric\n    max_depth_m: 80\n\
             \x20   sync:\n      tolerance_s: 0.005\n      queue_size: 3\n\
             \x20   image_transport:\n      cam4: compressed\n\
             other_node:\n  ros__parameters:\n    output_width: 64\n",
        )
        .unwrap();
        let f = file.display().to_string();
        let p = NodeParams::from_args(&args(&[
            "--ros-args",
            "--params-file",
            &f,
            "-p",
            "sync.queue_size:=7",
        ]))
        .unwrap();
        assert!(p.use_sim_time);
        assert_eq!(p.max_depth_m, 80.0);
        assert_eq!(p.sync_tolerance_s, 0.005);
        assert_eq!(p.sync_queue_size, 7);
        assert_eq!(p.output_width, NodeParams::default().output_width);
        assert_eq!(p.image_transport("cam4"), ImageTransport::Compressed);
    }

    #[test]
    fn shipped_params_file_parses_to_defaults() {
        let p = NodeParams::from_args(&args(&[
            "--ros-args",
            "--params-file",
            "launch_configs/mode360.params.yaml",
        ]))
        .unwrap();
        assert_eq!(p, NodeParams::default());
    }

    #[test]
    fn bad_input_names_the_culprit() {
        let e = NodeParams::from_args(&args(&["--ros-args", "-p", "output_width:=33"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("output_width") && e.contains("even"), "{e}");
        let e = NodeParams::from_args(&args(&["--ros-args", "-p", "nonsense:=1"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("nonsense"), "{e}");
        let e = NodeParams::from_args(&args(&["--ros-args", "--params-file", "/no/such.yaml"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/no/such.yaml"), "{e}");
        let e = NodeParams::from_args(&args(&["--ros-args", "-p", "estimator:=sgbm"]))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("estimator") && e.contains("sgbm") && e.contains("photometric, ssmode"),
            "{e}"
        );
        let p = NodeParams::from_args(&args(&["--ros-args", "-p", "estimator:=ssmode"])).unwrap();
        assert_eq!(
            p.estimator.kind,
            mode360_estimator::estimator::EstimatorKind::Ssmode
        );
        assert!(NodeParams::from_args(&args(&["--frobnicate"])).is_err());
        assert!(NodeParams::from_args(&args(&["--ros-args", "-p"])).is_err());
        assert!(NodeParams::from_args(&args(&["--ros-args", "-p", "x=1"])).is_err());
    }

    #[test]
    fn the_live_view_is_off_by_default_and_validated() {
        assert_eq!(NodeParams::default().live_view_address(), None);
        let p = NodeParams::from_args(&args(&[
            "--ros-args",
            "-p",
            "foxglove_port:=8765",
            "-p",
            "foxglove_address:=0.0.0.0",
        ]))
        .unwrap();
        let at = p.live_view_address().unwrap();
        assert_eq!(
            (at.address.to_string().as_str(), at.port),
            ("0.0.0.0", 8765)
        );
        for (name, value) in [
            ("foxglove_port", "70000"),
            ("foxglove_port", "-1"),
            ("foxglove_address", "robot.local:1"),
        ] {
            let e =
                NodeParams::from_args(&args(&["--ros-args", "-p", &format!("{name}:={value}")]))
                    .unwrap_err()
                    .to_string();
            assert!(
                e.contains(name) && e.contains(value) && e.contains("expected"),
                "{e}"
            );
        }
    }
}
