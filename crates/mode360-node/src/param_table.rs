//! The node's parameters, declared once: [`PARAMETERS`] gives each one's name, type, whether
//! it may change while the node runs, how to read it from [`NodeParams`] and how to set it
//! from text. Everything else is derived from the table: [`NodeParams::set`], the ROS 2
//! declarations and run-time updates ([`super::ros_params`]), the descriptors
//! ([`super::param_docs`], whose tests check the README's parameter table against it), and the
//! test that checks the shipped params file against it.
//!
//! Parameter families that are not single names (`image_transport.CAMERA`,
//! `qos_overrides./TOPIC.ENDPOINT.POLICY`) are parsed by [`NodeParams::set`] itself.

use super::params::{ExtrinsicsSource, ImageTransport, NodeParams};
use super::pipeline::FarValue;
use mode360_estimator::psmode::{PairChoice, DEFAULT_PAIR_WIDTH};
use mode360_estimator::EstimatorError;
use mode360_model::model::DeviceError;
use std::net::IpAddr;
use std::path::PathBuf;

/// The ROS 2 type of a parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParamType {
    String,
    Double,
    Integer,
    Bool,
}

impl ParamType {
    /// Its name in the README's parameter table.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::String => "string",
            Self::Double => "double",
            Self::Integer => "int",
            Self::Bool => "bool",
        }
    }
}

/// A parameter's current value.
#[derive(Clone, Debug, PartialEq)]
pub enum ParamValue {
    String(String),
    Double(f64),
    Integer(i64),
    Bool(bool),
}

impl ParamValue {
    /// The value as a params file or `-p name:=value` writes it (doubles keep a decimal point).
    pub fn to_text(&self) -> String {
        match self {
            Self::String(s) => s.clone(),
            Self::Double(d) if d.fract() == 0.0 && d.abs() < 1e15 => format!("{d:.1}"),
            Self::Double(d) => d.to_string(),
            Self::Integer(i) => i.to_string(),
            Self::Bool(b) => b.to_string(),
        }
    }

    pub fn param_type(&self) -> ParamType {
        match self {
            Self::String(_) => ParamType::String,
            Self::Double(_) => ParamType::Double,
            Self::Integer(_) => ParamType::Integer,
            Self::Bool(_) => ParamType::Bool,
        }
    }
}

/// The values a parameter takes beyond its type, as its setter checks them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Constraint {
    /// Any value of its type (a string's own rules are in its description).
    None,
    /// Greater than zero.
    Positive,
    /// From 0 to 1.
    UnitInterval,
    /// A TCP port, 0 to 65535.
    Port,
}

/// One parameter: name, whether it changes at run time, and its accessors.
pub struct ParamSpec {
    /// Dotted name (`sync.tolerance_s`), as in a params file's nesting.
    pub name: &'static str,
    /// Takes effect at once when set while the node runs; otherwise a change is refused
    /// (restart the node with the new value).
    pub runtime: bool,
    /// What values it takes beyond its type (what `ros2 param describe` shows as its range
    /// and constraints).
    pub constraint: Constraint,
    /// The current value.
    pub get: fn(&NodeParams) -> ParamValue,
    /// Sets it from text; the error says what was expected.
    pub set: fn(&mut NodeParams, &str) -> Result<(), String>,
}

impl ParamSpec {
    /// The parameter's type (that of its value).
    pub fn param_type(&self) -> ParamType {
        (self.get)(&NodeParams::default()).param_type()
    }
}

fn positive_f64(value: &str) -> Result<f64, String> {
    value
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0)
        .ok_or_else(|| "expected a positive number".into())
}

fn positive_usize(value: &str) -> Result<usize, String> {
    value
        .parse::<usize>()
        .ok()
        .filter(|v| *v > 0)
        .ok_or_else(|| "expected a positive integer".into())
}

fn unit_interval(value: &str) -> Result<f64, String> {
    value
        .parse::<f64>()
        .ok()
        .filter(|v| (0.0..=1.0).contains(v))
        .ok_or_else(|| "expected a number from 0 to 1".into())
}

fn boolean(value: &str) -> Result<bool, String> {
    match value {
        "true" | "True" => Ok(true),
        "false" | "False" => Ok(false),
        _ => Err("expected true or false".into()),
    }
}

/// An image transport name.
pub(super) fn image_transport(value: &str) -> Result<ImageTransport, String> {
    ImageTransport::parse(value).ok_or_else(|| "expected raw or compressed".into())
}

/// Every single-valued parameter of the node, in the order of the README's table.
pub const PARAMETERS: &[ParamSpec] = &[
    ParamSpec {
        name: "rig_file",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.rig_file.display().to_string()),
        set: |p, v| {
            p.rig_file = v.into();
            Ok(())
        },
    },
    ParamSpec {
        name: "estimator",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.estimator.kind.to_string()),
        set: |p, v| {
            p.estimator.kind = v.parse().map_err(|e: EstimatorError| e.to_string())?;
            Ok(())
        },
    },
    ParamSpec {
        name: "weights",
        runtime: false,
        constraint: Constraint::None,
        get: |p| {
            let w = p.estimator.weights.as_ref();
            ParamValue::String(w.map(|w| w.display().to_string()).unwrap_or_default())
        },
        set: |p, v| {
            p.estimator.weights = (!v.is_empty()).then(|| PathBuf::from(v));
            Ok(())
        },
    },
    ParamSpec {
        name: "fusion_weights",
        runtime: false,
        constraint: Constraint::None,
        get: |p| {
            let w = p.estimator.fusion_weights.as_ref();
            ParamValue::String(w.map(|w| w.display().to_string()).unwrap_or_default())
        },
        set: |p, v| {
            p.estimator.fusion_weights = (!v.is_empty()).then(|| PathBuf::from(v));
            Ok(())
        },
    },
    ParamSpec {
        name: "pairs",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.estimator.pairs.to_string()),
        set: |p, v| {
            p.estimator.pairs = PairChoice::parse(v).map_err(|e| e.to_string())?;
            Ok(())
        },
    },
    ParamSpec {
        name: "pair_width",
        runtime: false,
        constraint: Constraint::None,
        get: |p| {
            let w = p.estimator.pair_width.unwrap_or(DEFAULT_PAIR_WIDTH);
            ParamValue::Integer(w as i64)
        },
        set: |p, v| {
            // the default is kept unset, so that a params file listing it still loads the
            // other estimators (which refuse a pair width)
            let width = v
                .trim()
                .parse::<usize>()
                .map_err(|_| "expected a width in pixels, or 0 for the trained width")?;
            p.estimator.pair_width = (width != DEFAULT_PAIR_WIDTH).then_some(width);
            Ok(())
        },
    },
    ParamSpec {
        name: "near_pass_width",
        runtime: false,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Integer(p.estimator.near_pass_width.unwrap_or(0) as i64),
        set: |p, v| {
            // 0: off
            p.estimator.near_pass_width = match v.trim().parse::<usize>() {
                Ok(0) => None,
                _ => Some(positive_usize(v)?),
            };
            Ok(())
        },
    },
    ParamSpec {
        name: "near_pass_source",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.estimator.near_pass_source.to_string()),
        set: |p, v| {
            p.estimator.near_pass_source = v.parse().map_err(|e: EstimatorError| e.to_string())?;
            Ok(())
        },
    },
    ParamSpec {
        name: "device",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.estimator.device.to_string()),
        set: |p, v| {
            p.estimator.device = v.parse().map_err(|e: DeviceError| e.to_string())?;
            Ok(())
        },
    },
    ParamSpec {
        name: "output_width",
        runtime: false,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Integer(p.output_width as i64),
        set: |p, v| {
            let w = positive_usize(v)?;
            if w % 2 != 0 {
                return Err("output width must be even".into());
            }
            p.output_width = w;
            Ok(())
        },
    },
    ParamSpec {
        name: "sync.tolerance_s",
        runtime: false,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Double(p.sync_tolerance_s),
        set: |p, v| {
            p.sync_tolerance_s = positive_f64(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "sync.queue_size",
        runtime: false,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Integer(p.sync_queue_size as i64),
        set: |p, v| {
            p.sync_queue_size = positive_usize(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "camera_timeout_s",
        runtime: false,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Double(p.camera_timeout_s),
        set: |p, v| {
            p.camera_timeout_s = positive_f64(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "max_depth_m",
        runtime: true,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Double(p.max_depth_m),
        set: |p, v| {
            p.max_depth_m = positive_f64(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "depth_far_value",
        runtime: true,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.far_value.as_str().into()),
        set: |p, v| {
            p.far_value = FarValue::parse(v)
                .ok_or_else(|| format!("expected one of: {}", FarValue::NAMES.join(", ")))?;
            Ok(())
        },
    },
    ParamSpec {
        name: "depth_quantization",
        runtime: true,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Double(p.depth_quantization),
        set: |p, v| {
            p.depth_quantization = positive_f64(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "min_confidence",
        runtime: true,
        constraint: Constraint::UnitInterval,
        get: |p| ParamValue::Double(p.min_confidence),
        set: |p, v| {
            p.min_confidence = unit_interval(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "use_sim_time",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::Bool(p.use_sim_time),
        set: |p, v| {
            p.use_sim_time = boolean(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "image_transport",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.image_transport_default.as_str().into()),
        set: |p, v| {
            p.image_transport_default = image_transport(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "extrinsics_source",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.extrinsics_source.as_str().into()),
        set: |p, v| {
            p.extrinsics_source = match v {
                "yaml" => ExtrinsicsSource::Yaml,
                "tf" => ExtrinsicsSource::Tf,
                _ => return Err("expected one of: yaml, tf".into()),
            };
            Ok(())
        },
    },
    ParamSpec {
        name: "tf_timeout_s",
        runtime: false,
        constraint: Constraint::Positive,
        get: |p| ParamValue::Double(p.tf_timeout_s),
        set: |p, v| {
            p.tf_timeout_s = positive_f64(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "publish_points",
        runtime: true,
        constraint: Constraint::None,
        get: |p| ParamValue::Bool(p.publish_points),
        set: |p, v| {
            p.publish_points = boolean(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "publish_confidence",
        runtime: true,
        constraint: Constraint::None,
        get: |p| ParamValue::Bool(p.publish_confidence),
        set: |p, v| {
            p.publish_confidence = boolean(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "publish_compressed_depth",
        runtime: true,
        constraint: Constraint::None,
        get: |p| ParamValue::Bool(p.publish_compressed_depth),
        set: |p, v| {
            p.publish_compressed_depth = boolean(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "publish_tf",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::Bool(p.publish_tf),
        set: |p, v| {
            p.publish_tf = boolean(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "foxglove_port",
        runtime: false,
        constraint: Constraint::Port,
        get: |p| ParamValue::Integer(i64::from(p.foxglove_port)),
        set: |p, v| {
            p.foxglove_port = v
                .parse::<u16>()
                .map_err(|_| "expected a TCP port from 1 to 65535, or 0 for no live view")?;
            Ok(())
        },
    },
    ParamSpec {
        name: "foxglove_address",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::String(p.foxglove_address.to_string()),
        set: |p, v| {
            p.foxglove_address = v.parse::<IpAddr>().map_err(|_| {
                "expected an IP address (127.0.0.1: this machine only; 0.0.0.0: every interface)"
            })?;
            Ok(())
        },
    },
    ParamSpec {
        name: "lens_warn_fraction",
        runtime: false,
        constraint: Constraint::UnitInterval,
        get: |p| ParamValue::Double(p.lens_warn_fraction),
        set: |p, v| {
            p.lens_warn_fraction = unit_interval(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "rig_health_checks",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::Bool(p.rig_health_checks),
        set: |p, v| {
            p.rig_health_checks = boolean(v)?;
            Ok(())
        },
    },
    ParamSpec {
        name: "calibration_warn_deg",
        runtime: false,
        constraint: Constraint::None,
        get: |p| ParamValue::Double(p.calibration_warn_deg),
        set: |p, v| {
            p.calibration_warn_deg = v
                .parse::<f64>()
                .ok()
                .filter(|deg| *deg > 0.0 && *deg <= MAX_CALIBRATION_WARN_DEG)
                .ok_or_else(|| {
                    format!("expected degrees above 0 and at most {MAX_CALIBRATION_WARN_DEG}")
                })?;
            Ok(())
        },
    },
];

/// Largest `calibration_warn_deg`: the drift check searches corrections up to 3 degrees.
const MAX_CALIBRATION_WARN_DEG: f64 = 3.0;

/// The table entry called `name`.
pub fn parameter(name: &str) -> Option<&'static ParamSpec> {
    PARAMETERS.iter().find(|s| s.name == name)
}

/// The names of the parameters that may change while the node runs.
pub fn runtime_parameter_names() -> impl Iterator<Item = &'static str> {
    PARAMETERS.iter().filter(|s| s.runtime).map(|s| s.name)
}

/// Deprecated names and their replacements (seconds are `_s` everywhere).
pub const DEPRECATED_NAMES: [(&str, &str); 2] = [
    ("sync.tolerance_secs", "sync.tolerance_s"),
    ("camera_timeout_secs", "camera_timeout_s"),
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params_file::file_parameters;
    use std::collections::BTreeSet;

    fn repo_file(relative: &str) -> (String, String) {
        let path = format!("{}/../../{relative}", env!("CARGO_MANIFEST_DIR"));
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        (path, text)
    }

    fn table_names() -> BTreeSet<&'static str> {
        PARAMETERS.iter().map(|s| s.name).collect()
    }

    #[test]
    fn every_parameter_round_trips_through_its_text() {
        let defaults = NodeParams::default();
        for spec in PARAMETERS {
            let mut p = NodeParams::default();
            let text = (spec.get)(&defaults).to_text();
            (spec.set)(&mut p, &text).unwrap_or_else(|e| panic!("{}: {e}", spec.name));
            assert_eq!((spec.get)(&p), (spec.get)(&defaults), "{}", spec.name);
            assert!(p.set(spec.name, &text).is_ok(), "{} via set", spec.name);
        }
        assert_eq!(table_names().len(), PARAMETERS.len(), "duplicate names");
    }

    #[test]
    fn device_is_cpu_or_a_cuda_index() {
        let mut p = NodeParams::default();
        p.set("device", "cuda:1").unwrap();
        assert_eq!(p.estimator.device.to_string(), "cuda:1");
        let e = p.set("device", "gpu").unwrap_err().to_string();
        assert!(e.contains("device") && e.contains("cpu or cuda:N"), "{e}");
    }

    /// The shipped params file sets exactly the table's parameters, to their defaults.
    #[test]
    fn shipped_params_file_sets_every_parameter_to_its_default() {
        let (path, text) = repo_file("launch_configs/mode360.params.yaml");
        let defaults = NodeParams::default();
        let entries = file_parameters(&defaults, &text, &path).unwrap();
        let names: BTreeSet<&str> = entries.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, table_names(), "{path} against the parameter table");
        for (name, value) in &entries {
            let mut p = NodeParams::default();
            p.set(name, value).unwrap();
            assert_eq!(p, defaults, "{path}: {name} = {value} is not the default");
        }
    }
}
