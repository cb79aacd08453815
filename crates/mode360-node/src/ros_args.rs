//! Node parameters from ROS 2 command-line arguments.
//!
//! Accepted `--ros-args` forms (as `ros2 run` passes them): `--params-file FILE`,
//! `-p name:=value` / `--param name:=value`, `-r from:=to` / `--remap from:=to`,
//! `-r __ns:=/x`, `-r __node:=name`, `--log-level LEVEL`, and `--` (or a later `--ros-args`)
//! closing a section. Params files (`params_file.rs`) and `-p` values are applied in
//! command-line order: later sources win.

use super::param_table::{image_transport, parameter, DEPRECATED_NAMES};
use super::params::{NodeParams, ParamsError, IMAGE_TRANSPORT_PREFIX};
use super::params_file::file_parameters;
use super::qos_overrides::QOS_OVERRIDES_PREFIX;
use mode360_core::shipped;
use std::path::PathBuf;

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
                "--log-level" => {
                    let level = value_of(arg)?;
                    if tracing_level(&level).is_none() {
                        return Err(ParamsError::Argument {
                            arg: format!("{arg} {level}"),
                            problem: format!("expected one of {}", ROS_LOG_LEVELS.join(", ")),
                        });
                    }
                }
                "--enclave" => {
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
                    let path = shipped::locate_path(&path, shipped::LAUNCH_CONFIGS);
                    let file = path.display().to_string();
                    let text = std::fs::read_to_string(&path).map_err(|e| ParamsError::File {
                        file: file.clone(),
                        problem: e.to_string(),
                    })?;
                    for (name, value) in file_parameters(&params, &text, &file)? {
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

    /// Sets one parameter from its text value: a name of [`PARAMETERS`](super::param_table::PARAMETERS), a deprecated name
    /// (warned), `image_transport.CAMERA` or `qos_overrides./TOPIC.ENDPOINT.POLICY`.
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), ParamsError> {
        let bad = |problem: String| ParamsError::Value {
            name: name.to_string(),
            value: value.to_string(),
            problem,
        };
        if let Some(spec) = parameter(name) {
            return (spec.set)(self, value).map_err(bad);
        }
        if let Some((_, current)) = DEPRECATED_NAMES.iter().find(|(old, _)| *old == name) {
            tracing::warn!("parameter '{name}' is deprecated: use '{current}'");
            return self.set(current, value);
        }
        if let Some(rest) = name.strip_prefix(QOS_OVERRIDES_PREFIX) {
            self.qos_overrides.set(rest, value).map_err(bad)
        } else if let Some(camera) = name.strip_prefix(IMAGE_TRANSPORT_PREFIX) {
            let transport = image_transport(value).map_err(bad)?;
            self.image_transport_per_camera
                .insert(camera.to_string(), transport);
            Ok(())
        } else {
            Err(bad("unknown parameter".into()))
        }
    }
}

/// The levels ROS 2's `--log-level` takes (any case; also as `logger:=level`).
pub const ROS_LOG_LEVELS: [&str; 5] = ["debug", "info", "warn", "error", "fatal"];

/// The `tracing` level of a ROS 2 `--log-level` value (`fatal` is `error`); `None` when it is
/// not a level.
pub fn tracing_level(value: &str) -> Option<&'static str> {
    let level = value.rsplit_once(":=").map_or(value, |(_, l)| l);
    match level.to_ascii_lowercase().as_str() {
        "debug" => Some("debug"),
        "info" => Some("info"),
        "warn" => Some("warn"),
        "error" | "fatal" => Some("error"),
        _ => None,
    }
}

/// The value of the last `--log-level` given after `--ros-args` in `args`, if any.
pub fn log_level_arg(args: &[String]) -> Option<&str> {
    let mut in_ros_args = false;
    let mut level = None;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--ros-args" => in_ros_args = true,
            "--" => in_ros_args = false,
            "--log-level" if in_ros_args => level = it.next().map(String::as_str),
            _ => {}
        }
    }
    level
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::ImageTransport;
    use crate::pipeline::FarValue;

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
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../launch_configs/mode360.params.yaml"
            ),
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
        assert_eq!(p.estimator.kind, mode360_estimator::EstimatorKind::Ssmode);
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

    #[test]
    fn log_level_is_read_and_validated() {
        let a = args(&[
            "--ros-args",
            "--log-level",
            "DEBUG",
            "-p",
            "output_width:=256",
        ]);
        assert_eq!(log_level_arg(&a), Some("DEBUG"));
        assert_eq!(log_level_arg(&a).and_then(tracing_level), Some("debug"));
        assert_eq!(tracing_level("mode360:=fatal"), Some("error"));
        assert!(NodeParams::from_args(&a).is_ok());
        assert_eq!(log_level_arg(&args(&["--log-level", "debug"])), None);
        let e = NodeParams::from_args(&args(&["--ros-args", "--log-level", "loud"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("loud") && e.contains("debug, info"), "{e}");
    }
}
