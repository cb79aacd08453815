//! MCAP `ros2msg` schema text, built from the `.msg` files under `msg/` (embedded at compile
//! time, so they are the one source of truth).
//!
//! Layout (rosbag2 style): the type's own `.msg` text, then for each dependency, depth first
//! in order of first use, each once:
//! ```text
//! ================================================================================
//! MSG: pkg/Type
//! <that type's .msg text>
//! ```
//! Every text block ends with exactly one newline.

use std::collections::BTreeSet;

use super::MsgError;

/// The line that separates definitions: exactly 80 `=`.
pub const SCHEMA_SEPARATOR: &str =
    "================================================================================";

/// One embedded `.msg` definition.
#[derive(Clone, Copy, Debug)]
pub struct MsgDefinition {
    /// Package name, e.g. `sensor_msgs`.
    pub package: &'static str,
    /// Type name inside the package, e.g. `Image`.
    pub name: &'static str,
    /// The `.msg` file text.
    pub text: &'static str,
}

impl MsgDefinition {
    /// `pkg/msg/Type`, the MCAP schema name.
    pub fn full_name(&self) -> String {
        format!("{}/msg/{}", self.package, self.name)
    }

    /// `pkg/Type`, the form used after `MSG:`.
    pub fn short_name(&self) -> String {
        format!("{}/{}", self.package, self.name)
    }
}

macro_rules! definitions {
    ($ext:literal: $($pkg:literal / $name:literal),* $(,)?) => {
        &[$(MsgDefinition {
            package: $pkg,
            name: $name,
            text: include_str!(concat!("../../../../msg/", $pkg, "/", $name, $ext)),
        }),*]
    };
}

/// Every message definition mode360 ships.
pub const DEFINITIONS: &[MsgDefinition] = definitions![".msg":
    "builtin_interfaces" / "Time",
    "std_msgs" / "Header",
    "sensor_msgs" / "Image",
    "sensor_msgs" / "CompressedImage",
    "sensor_msgs" / "PointCloud2",
    "sensor_msgs" / "PointField",
    "geometry_msgs" / "TransformStamped",
    "geometry_msgs" / "Transform",
    "geometry_msgs" / "Vector3",
    "geometry_msgs" / "Quaternion",
    "tf2_msgs" / "TFMessage",
    "diagnostic_msgs" / "DiagnosticArray",
    "diagnostic_msgs" / "DiagnosticStatus",
    "diagnostic_msgs" / "KeyValue",
    "rosgraph_msgs" / "Clock",
    // The types of the endpoints ros2-client makes for the node (`/rosout`,
    // `/parameter_events`, `ros_discovery_info`, the parameter services), for their hashes.
    "rcl_interfaces" / "Log",
    "rcl_interfaces" / "ParameterEvent",
    "rcl_interfaces" / "Parameter",
    "rcl_interfaces" / "ParameterValue",
    "rcl_interfaces" / "ParameterDescriptor",
    "rcl_interfaces" / "FloatingPointRange",
    "rcl_interfaces" / "IntegerRange",
    "rcl_interfaces" / "SetParametersResult",
    "rcl_interfaces" / "ListParametersResult",
    "rmw_dds_common" / "Gid",
    "rmw_dds_common" / "NodeEntitiesInfo",
    "rmw_dds_common" / "ParticipantEntitiesInfo",
];

/// Every service definition mode360 ships (`.srv` files under `msg/<pkg>/`): the parameter
/// services ros2-client serves for the node.
pub const SERVICE_DEFINITIONS: &[MsgDefinition] = definitions![".srv":
    "rcl_interfaces" / "GetParameters",
    "rcl_interfaces" / "GetParameterTypes",
    "rcl_interfaces" / "SetParameters",
    "rcl_interfaces" / "SetParametersAtomically",
    "rcl_interfaces" / "ListParameters",
    "rcl_interfaces" / "DescribeParameters",
];

/// Field types that are not messages.
const PRIMITIVE_TYPES: &[&str] = &[
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
    "uint32", "int64", "uint64", "string", "wstring",
];

/// The `(package, type)` of `type_name`, which may be `pkg/msg/Type` or `pkg/Type`.
fn split_type_name(type_name: &str) -> Option<(&str, &str)> {
    let mut parts = type_name.split('/');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some(pkg), Some("msg"), Some(name), None) | (Some(pkg), Some(name), None, None)
            if !pkg.is_empty() && !name.is_empty() =>
        {
            Some((pkg, name))
        }
        _ => None,
    }
}

/// The embedded definition of `type_name` (`pkg/msg/Type` or `pkg/Type`).
pub fn definition(type_name: &str) -> Result<&'static MsgDefinition, MsgError> {
    split_type_name(type_name)
        .and_then(|(pkg, name)| {
            DEFINITIONS
                .iter()
                .find(|d| d.package == pkg && d.name == name)
        })
        .ok_or_else(|| MsgError::UnknownType {
            type_name: type_name.to_string(),
        })
}

/// The embedded definition of service `pkg/srv/Service`.
pub fn service_definition(service_name: &str) -> Result<&'static MsgDefinition, MsgError> {
    let mut parts = service_name.split('/');
    let found = match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some(pkg), Some("srv"), Some(name), None) => SERVICE_DEFINITIONS
            .iter()
            .find(|d| d.package == pkg && d.name == name),
        _ => None,
    };
    found.ok_or_else(|| MsgError::UnknownType {
        type_name: service_name.to_string(),
    })
}

/// The message types a definition's fields use, as `pkg/Type`, in order of first use
/// (a type without a package is in the definition's own package; array suffixes, string
/// bounds, comments and constants are stripped).
pub fn field_dependencies(def: &MsgDefinition) -> Vec<String> {
    let mut deps: Vec<String> = Vec::new();
    for line in def.text.lines() {
        let code = line.split('#').next().unwrap_or("").trim();
        let Some(field_type) = code.split_whitespace().next() else {
            continue;
        };
        let base = field_type
            .split('[')
            .next()
            .unwrap_or(field_type)
            .split("<=")
            .next()
            .unwrap_or(field_type);
        if PRIMITIVE_TYPES.contains(&base) {
            continue;
        }
        let dep = match split_type_name(base) {
            Some((pkg, name)) => format!("{pkg}/{name}"),
            None => format!("{}/{}", def.package, base),
        };
        if !deps.contains(&dep) {
            deps.push(dep);
        }
    }
    deps
}

/// `text` with trailing newlines replaced by exactly one.
fn with_single_newline(text: &str) -> String {
    let mut out = text.trim_end_matches(['\n', '\r']).to_string();
    out.push('\n');
    out
}

fn append_dependencies(
    def: &MsgDefinition,
    root_type: &str,
    seen: &mut BTreeSet<String>,
    out: &mut String,
) -> Result<(), MsgError> {
    for dep in field_dependencies(def) {
        if !seen.insert(dep.clone()) {
            continue;
        }
        let dep_def = definition(&dep).map_err(|_| MsgError::MissingDependency {
            type_name: root_type.to_string(),
            dependency: dep.clone(),
        })?;
        out.push_str(SCHEMA_SEPARATOR);
        out.push('\n');
        out.push_str("MSG: ");
        out.push_str(&dep);
        out.push('\n');
        out.push_str(&with_single_newline(dep_def.text));
        append_dependencies(dep_def, root_type, seen, out)?;
    }
    Ok(())
}

/// The complete `ros2msg` schema text of `type_name` (`pkg/msg/Type` or `pkg/Type`):
/// see the module docs for the layout.
pub fn schema_text(type_name: &str) -> Result<String, MsgError> {
    let def = definition(type_name)?;
    let mut out = with_single_newline(def.text);
    let mut seen = BTreeSet::new();
    seen.insert(def.short_name());
    append_dependencies(def, type_name, &mut seen, &mut out)?;
    Ok(out)
}
