//! ROS 2 type hashes (REP 2011, version `RIHS01`) of the message and service types mode360's
//! endpoints carry, computed from the `.msg` and `.srv` definitions under `msg/` as rosidl
//! does, so that the node can announce them in discovery (`typehash=RIHS01_<hex>;` in each
//! endpoint's USER_DATA) and `ros2 topic info -v` shows them instead of INVALID.
//!
//! The hash of a type is the SHA-256 of its hashable description,
//! ```text
//! {"type_description": {"type_name": T, "fields": [F, ...]},
//!  "referenced_type_descriptions": [{"type_name": R, "fields": [F, ...]}, ...]}
//! ```
//! written as Python's `json.dumps(..., separators=(", ", ": "))` does, on one line, keys in
//! that order, the referenced types (every type used, transitively) sorted by name, and each
//! field `F` as `{"name": N, "type": {"type_id": I, "capacity": C, "string_capacity": S,
//! "nested_type_name": M}}` (rosidl's `default_value` is left out of the hash). Constants are
//! not fields. A service `pkg/srv/S` has the message types `pkg/srv/S_Request` and
//! `pkg/srv/S_Response` (the parts before and after `---`); their hashes are the ones
//! rmw_fastrtps announces on the service's request and reply endpoints.

use std::collections::BTreeMap;
use std::fmt;

use sha2::{Digest, Sha256};

use super::schema::{definition, service_definition, DEFINITIONS, SERVICE_DEFINITIONS};
use super::MsgError;

/// The prefix of a version-1 type hash string.
pub const TYPE_HASH_PREFIX: &str = "RIHS01_";
/// What an endpoint's USER_DATA holds before the hash string.
pub const USER_DATA_KEY: &str = "typehash=";

/// `type_description_interfaces/msg/FieldType` ids of the scalar types.
const FIELD_TYPE_NESTED: u8 = 1;
const FIELD_TYPE_STRING: u8 = 17;
const FIELD_TYPE_WSTRING: u8 = 18;
const FIELD_TYPE_BOUNDED_STRING: u8 = 21;
const FIELD_TYPE_BOUNDED_WSTRING: u8 = 22;
/// Added to a scalar id for a fixed-size array `T[N]`.
const FIELD_TYPE_ARRAY_OFFSET: u8 = 48;
/// Added for a bounded sequence `T[<=N]`.
const FIELD_TYPE_BOUNDED_SEQUENCE_OFFSET: u8 = 96;
/// Added for an unbounded sequence `T[]`.
const FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET: u8 = 144;

/// The `.msg` primitive types and their field type ids (`char` is `uint8` and `byte` is
/// `octet` in ROS 2's IDL mapping).
const PRIMITIVE_TYPE_IDS: &[(&str, u8)] = &[
    ("int8", 2),
    ("uint8", 3),
    ("char", 3),
    ("int16", 4),
    ("uint16", 5),
    ("int32", 6),
    ("uint32", 7),
    ("int64", 8),
    ("uint64", 9),
    ("float32", 10),
    ("float64", 11),
    ("bool", 15),
    ("byte", 16),
];

/// The member rosidl gives a structure without fields.
const EMPTY_STRUCTURE_MEMBER: &str = "structure_needs_at_least_one_member";
/// Its field type id (`uint8`).
const EMPTY_STRUCTURE_MEMBER_TYPE: u8 = 3;

/// A version-1 type hash: SHA-256 of a type's hashable description.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TypeHash(pub [u8; 32]);

impl TypeHash {
    /// The USER_DATA an endpoint of this type announces: `typehash=RIHS01_<hex>;`.
    pub fn user_data(&self) -> String {
        format!("{USER_DATA_KEY}{self};")
    }
}

impl fmt::Display for TypeHash {
    /// `RIHS01_` and 64 lowercase hex digits.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(TYPE_HASH_PREFIX)?;
        self.0.iter().try_for_each(|b| write!(f, "{b:02x}"))
    }
}

/// The type of one field, as `type_description_interfaces/msg/FieldType` holds it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FieldType {
    /// Scalar id plus the array or sequence offset.
    pub type_id: u8,
    /// Array size or sequence bound (0: unbounded or not an array).
    pub capacity: u64,
    /// Bound of a bounded string (0: none).
    pub string_capacity: u64,
    /// `pkg/msg/Type` of a nested message, else empty.
    pub nested_type_name: String,
}

/// One field of a type description.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Field {
    pub name: String,
    pub field_type: FieldType,
}

/// A type's name and fields in definition order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TypeDescription {
    /// `pkg/msg/Type` or `pkg/srv/Service_Request`.
    pub type_name: String,
    pub fields: Vec<Field>,
}

/// `pkg/msg/Type` (or `pkg/srv/S_Request`) as a DDS type name, the form on the wire:
/// `pkg::msg::dds_::Type_`.
pub fn dds_type_name(type_name: &str) -> String {
    match type_name.rsplit_once('/') {
        Some((namespace, name)) => format!("{}::dds_::{name}_", namespace.replace('/', "::")),
        None => format!("{type_name}_"),
    }
}

/// Every type an endpoint of the node may carry: each shipped message, and the request and
/// reply of each shipped service, as `pkg/msg/Type` or `pkg/srv/S_Request`.
pub fn endpoint_type_names() -> Vec<String> {
    let messages = DEFINITIONS.iter().map(|d| d.full_name());
    let services = SERVICE_DEFINITIONS.iter().flat_map(|d| {
        let name = format!("{}/srv/{}", d.package, d.name);
        [format!("{name}_Request"), format!("{name}_Response")]
    });
    messages.chain(services).collect()
}

/// The description of `type_name` (`pkg/msg/Type`, `pkg/srv/S_Request` or
/// `pkg/srv/S_Response`) from its shipped definition.
pub fn type_description(type_name: &str) -> Result<TypeDescription, MsgError> {
    let (package, text) = if let Some((service, part)) = type_name
        .strip_suffix("_Request")
        .map(|s| (s, ServicePart::Request))
        .or_else(|| {
            type_name
                .strip_suffix("_Response")
                .map(|s| (s, ServicePart::Response))
        })
        .filter(|_| type_name.contains("/srv/"))
    {
        let def = service_definition(service)?;
        (def.package, part.text(def.text))
    } else {
        let def = definition(type_name)?;
        (def.package, def.text)
    };
    let fields = parse_fields(type_name, package, text)?;
    Ok(TypeDescription {
        type_name: type_name.to_string(),
        fields,
    })
}

/// The type hash of `type_name` (see the module docs).
pub fn type_hash(type_name: &str) -> Result<TypeHash, MsgError> {
    let json = hashable_description(type_name)?;
    Ok(TypeHash(Sha256::digest(json.as_bytes()).into()))
}

/// The JSON text that [`type_hash`] hashes.
pub fn hashable_description(type_name: &str) -> Result<String, MsgError> {
    let main = type_description(type_name)?;
    let mut referenced: BTreeMap<String, TypeDescription> = BTreeMap::new();
    let mut pending: Vec<String> = nested_names(&main);
    while let Some(name) = pending.pop() {
        if referenced.contains_key(&name) {
            continue;
        }
        let description = type_description(&name).map_err(|_| MsgError::MissingDependency {
            type_name: type_name.to_string(),
            dependency: name.clone(),
        })?;
        pending.extend(nested_names(&description));
        referenced.insert(name, description);
    }
    let referenced: Vec<String> = referenced.values().map(description_json).collect();
    Ok(format!(
        "{{\"type_description\": {}, \"referenced_type_descriptions\": [{}]}}",
        description_json(&main),
        referenced.join(", ")
    ))
}

/// Which half of a `.srv` file.
#[derive(Clone, Copy)]
enum ServicePart {
    Request,
    Response,
}

impl ServicePart {
    /// Lines before the `---` separator (request) or after it (response).
    fn text(self, srv: &str) -> &str {
        let separator = srv
            .match_indices("---")
            .find(|(i, _)| *i == 0 || srv.as_bytes()[i - 1] == b'\n');
        match (self, separator) {
            (ServicePart::Request, Some((i, _))) => &srv[..i],
            (ServicePart::Response, Some((i, sep))) => &srv[i + sep.len()..],
            (ServicePart::Request, None) => srv,
            (ServicePart::Response, None) => "",
        }
    }
}

fn nested_names(description: &TypeDescription) -> Vec<String> {
    description
        .fields
        .iter()
        .map(|f| f.field_type.nested_type_name.clone())
        .filter(|n| !n.is_empty())
        .collect()
}

fn description_json(description: &TypeDescription) -> String {
    let fields: Vec<String> = description
        .fields
        .iter()
        .map(|f| {
            let t = &f.field_type;
            format!(
                "{{\"name\": \"{}\", \"type\": {{\"type_id\": {}, \"capacity\": {}, \
                 \"string_capacity\": {}, \"nested_type_name\": \"{}\"}}}}",
                f.name, t.type_id, t.capacity, t.string_capacity, t.nested_type_name
            )
        })
        .collect();
    format!(
        "{{\"type_name\": \"{}\", \"fields\": [{}]}}",
        description.type_name,
        fields.join(", ")
    )
}

/// The fields of one `.msg` body (or half of a `.srv`) of `package`: comments, blank lines
/// and constants (`TYPE NAME=VALUE`) skipped, default values ignored. A body without fields
/// gets rosidl's placeholder member.
fn parse_fields(type_name: &str, package: &str, text: &str) -> Result<Vec<Field>, MsgError> {
    let mut fields = Vec::new();
    for (index, line) in text.lines().enumerate() {
        let code = line.split('#').next().unwrap_or("").trim();
        let Some((type_token, rest)) = code.split_once(char::is_whitespace) else {
            if code.is_empty() {
                continue;
            }
            return Err(bad_line(
                type_name,
                index,
                line,
                "a type without a field name",
            ));
        };
        let rest = rest.trim_start();
        let name_len = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        let (name, after_name) = rest.split_at(name_len);
        if after_name.trim_start().starts_with('=') {
            continue; // a constant
        }
        if name.is_empty() {
            return Err(bad_line(type_name, index, line, "no field name"));
        }
        let field_type = parse_field_type(package, type_token)
            .map_err(|problem| bad_line(type_name, index, line, &problem))?;
        fields.push(Field {
            name: name.to_string(),
            field_type,
        });
    }
    if fields.is_empty() {
        fields.push(Field {
            name: EMPTY_STRUCTURE_MEMBER.to_string(),
            field_type: FieldType {
                type_id: EMPTY_STRUCTURE_MEMBER_TYPE,
                capacity: 0,
                string_capacity: 0,
                nested_type_name: String::new(),
            },
        });
    }
    Ok(fields)
}

fn bad_line(type_name: &str, index: usize, line: &str, problem: &str) -> MsgError {
    MsgError::BadDefinition {
        type_name: type_name.to_string(),
        problem: format!("line {} '{}': {problem}", index + 1, line.trim()),
    }
}

/// A field type token such as `uint8`, `string<=256`, `Gid[]`, `char[16]`,
/// `FloatingPointRange[<=1]` or `builtin_interfaces/Time`, in `package`.
fn parse_field_type(package: &str, token: &str) -> Result<FieldType, String> {
    let (base, offset, capacity) = match token.split_once('[') {
        None => (token, 0, 0),
        Some((base, array)) => {
            let inner = array
                .strip_suffix(']')
                .ok_or_else(|| format!("'{token}': an array suffix without ']'"))?;
            let number = |s: &str| {
                s.parse::<u64>()
                    .map_err(|_| format!("'{token}': array bound '{s}' is not a number"))
            };
            if inner.is_empty() {
                (base, FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET, 0)
            } else if let Some(bound) = inner.strip_prefix("<=") {
                (base, FIELD_TYPE_BOUNDED_SEQUENCE_OFFSET, number(bound)?)
            } else {
                (base, FIELD_TYPE_ARRAY_OFFSET, number(inner)?)
            }
        }
    };
    let (scalar, string_capacity, nested_type_name) = scalar_type(package, base)?;
    Ok(FieldType {
        type_id: scalar + offset,
        capacity,
        string_capacity,
        nested_type_name,
    })
}

/// `(scalar type id, string bound, nested type name)` of a type without array suffix.
fn scalar_type(package: &str, base: &str) -> Result<(u8, u64, String), String> {
    if let Some(&(_, id)) = PRIMITIVE_TYPE_IDS.iter().find(|(name, _)| *name == base) {
        return Ok((id, 0, String::new()));
    }
    for (prefix, unbounded, bounded) in [
        ("wstring", FIELD_TYPE_WSTRING, FIELD_TYPE_BOUNDED_WSTRING),
        ("string", FIELD_TYPE_STRING, FIELD_TYPE_BOUNDED_STRING),
    ] {
        if base == prefix {
            return Ok((unbounded, 0, String::new()));
        }
        if let Some(bound) = base.strip_prefix(prefix).and_then(|r| r.strip_prefix("<=")) {
            let bound = bound
                .parse::<u64>()
                .map_err(|_| format!("'{base}': string bound '{bound}' is not a number"))?;
            return Ok((bounded, bound, String::new()));
        }
    }
    let valid = |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    let nested = match base.split('/').collect::<Vec<_>>()[..] {
        [name] if valid(name) => format!("{package}/msg/{name}"),
        [pkg, name] | [pkg, "msg", name] if valid(pkg) && valid(name) => {
            format!("{pkg}/msg/{name}")
        }
        _ => return Err(format!("'{base}' is not a field type")),
    };
    Ok((FIELD_TYPE_NESTED, 0, nested))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_types_follow_the_field_type_ids() {
        let t = |token: &str| parse_field_type("pkg", token).unwrap();
        assert_eq!((t("uint32").type_id, t("uint32").capacity), (7, 0));
        assert_eq!(
            (t("char[16]").type_id, t("char[16]").capacity),
            (3 + 48, 16)
        );
        assert_eq!(t("byte[]").type_id, 16 + 144);
        let bounded = t("FloatingPointRange[<=1]");
        assert_eq!((bounded.type_id, bounded.capacity), (1 + 96, 1));
        assert_eq!(bounded.nested_type_name, "pkg/msg/FloatingPointRange");
        let s = t("string<=256");
        assert_eq!((s.type_id, s.string_capacity), (21, 256));
        assert_eq!(t("string[]").type_id, 17 + 144);
        assert_eq!(
            t("builtin_interfaces/Time").nested_type_name,
            "builtin_interfaces/msg/Time"
        );
        assert!(parse_field_type("pkg", "uint8[x]").is_err());
        assert!(parse_field_type("pkg", "a/b/c/d").is_err());
    }

    #[test]
    fn constants_comments_and_defaults_are_not_fields() {
        let fields = parse_fields(
            "pkg/msg/T",
            "pkg",
            "uint8 DEBUG=10 # a constant\nuint8 X = 3\n# comment\n\nbool read_only false\nint32 a",
        )
        .unwrap();
        let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["read_only", "a"]);
        let empty = parse_fields("pkg/srv/S_Request", "pkg", "# nothing\n").unwrap();
        assert_eq!(empty[0].name, EMPTY_STRUCTURE_MEMBER);
    }

    #[test]
    fn a_malformed_line_names_the_type_and_line() {
        let err = parse_fields("pkg/msg/T", "pkg", "int32 a\nfloat64[ b\n").unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("pkg/msg/T") && text.contains("line 2"),
            "{text}"
        );
    }

    #[test]
    fn services_split_at_the_separator() {
        let req = type_description("rcl_interfaces/srv/ListParameters_Request").unwrap();
        let names: Vec<&str> = req.fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["prefixes", "depth"]);
        let resp = type_description("rcl_interfaces/srv/ListParameters_Response").unwrap();
        assert_eq!(resp.fields.len(), 1);
        assert_eq!(
            resp.fields[0].field_type.nested_type_name,
            "rcl_interfaces/msg/ListParametersResult"
        );
    }

    #[test]
    fn dds_type_names_are_the_wire_form() {
        assert_eq!(
            dds_type_name("sensor_msgs/msg/Image"),
            "sensor_msgs::msg::dds_::Image_"
        );
        assert_eq!(
            dds_type_name("rcl_interfaces/srv/GetParameters_Request"),
            "rcl_interfaces::srv::dds_::GetParameters_Request_"
        );
    }

    /// The hashes rosidl generated for these types: rclpy's Jazzy and Kilted wheels
    /// (`share/<pkg>/msg/<Type>.json`, `type_hashes`; the same in both) and, for TFMessage
    /// (no tf2_msgs wheel), rosidl's generated C (`tf2_msgs__msg__TFMessage__EXPECTED_HASH`).
    #[test]
    fn hashes_equal_the_ones_rosidl_generates() {
        let expected = [
            (
                "builtin_interfaces/msg/Time",
                "b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
            ),
            (
                "std_msgs/msg/Header",
                "f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
            ),
            (
                "sensor_msgs/msg/Image",
                "d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
            ),
            (
                "tf2_msgs/msg/TFMessage",
                "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
            ),
            (
                "rcl_interfaces/srv/GetParameters_Request",
                "135a9e1c3d7cebef792f6687d7ddf99949b21a0bd9a320d863a9110a3f5cf4d6",
            ),
            (
                "rcl_interfaces/srv/GetParameters_Response",
                "9fa773b46e39cc5d02db6224d8fd520bb9caeeffc2b27c96c1e59431baba9f2a",
            ),
        ];
        for (type_name, hex) in expected {
            let hash = type_hash(type_name).unwrap();
            assert_eq!(hash.to_string(), format!("RIHS01_{hex}"), "{type_name}");
        }
    }

    #[test]
    fn every_endpoint_type_has_a_hash() {
        let names = endpoint_type_names();
        assert!(names.len() >= 30, "{names:?}");
        for name in names {
            let hash = type_hash(&name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(hash.user_data().len(), USER_DATA_KEY.len() + 7 + 64 + 1);
        }
    }
}
