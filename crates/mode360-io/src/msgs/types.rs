//! Serde structs for the ROS 2 messages mode360 reads and writes.
//!
//! Every struct lists its fields in the order of its `.msg` file under `msg/` (CDR is
//! positional), and every `uint8[]` is a `serde_bytes` byte buffer so it is encoded as one
//! length-prefixed block rather than element by element.

use nalgebra::{Isometry3, Quaternion as NaQuaternion, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::RosMessage;

/// Nanoseconds in one second.
pub const NANOS_PER_SEC: u64 = 1_000_000_000;

/// `builtin_interfaces/msg/Time`: seconds and nanoseconds since the epoch.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// `sec = ns / 1e9`, `nanosec = ns mod 1e9`. ROS 2 stores seconds as int32, so stamps
    /// past 2038-01-19 saturate to `i32::MAX` seconds (and 999 999 999 ns).
    pub fn from_nanos(stamp_ns: u64) -> Self {
        let sec = stamp_ns / NANOS_PER_SEC;
        match i32::try_from(sec) {
            Ok(sec) => Self {
                sec,
                nanosec: (stamp_ns % NANOS_PER_SEC) as u32,
            },
            Err(_) => Self {
                sec: i32::MAX,
                nanosec: (NANOS_PER_SEC - 1) as u32,
            },
        }
    }

    /// `sec * 1e9 + nanosec`; times before the epoch (negative `sec`) saturate to 0.
    pub fn to_nanos(&self) -> u64 {
        match u64::try_from(self.sec) {
            Ok(sec) => sec * NANOS_PER_SEC + u64::from(self.nanosec),
            Err(_) => 0,
        }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    /// A header stamped `stamp_ns` (nanoseconds since the epoch) in frame `frame_id`.
    pub fn new(stamp_ns: u64, frame_id: impl Into<String>) -> Self {
        Self {
            stamp: Time::from_nanos(stamp_ns),
            frame_id: frame_id.into(),
        }
    }
}

/// `sensor_msgs/msg/Image`: `data` holds `height` rows of `step` bytes.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/CompressedImage`: `format` is e.g. `jpeg`, `png` or
/// `rgb8; jpeg compressed bgr8` (image_transport's form).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/PointField`: one named entry of a point's binary layout.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    pub datatype: u8,
    pub count: u32,
}

impl PointField {
    pub const INT8: u8 = 1;
    pub const UINT8: u8 = 2;
    pub const INT16: u8 = 3;
    pub const UINT16: u8 = 4;
    pub const INT32: u8 = 5;
    pub const UINT32: u8 = 6;
    pub const FLOAT32: u8 = 7;
    pub const FLOAT64: u8 = 8;

    /// A field of `count` values of `datatype` at byte `offset` of each point.
    pub fn new(name: impl Into<String>, offset: u32, datatype: u8, count: u32) -> Self {
        Self {
            name: name.into(),
            offset,
            datatype,
            count,
        }
    }
}

/// `sensor_msgs/msg/PointCloud2`: `data` holds `height` rows of `row_step` bytes, each point
/// `point_step` bytes laid out as `fields` says.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointCloud2 {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    pub is_dense: bool,
}

/// `geometry_msgs/msg/Vector3`, metres for translations.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion` (x, y, z, w); the default is the identity, as in the .msg.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/msg/Transform`: maps child-frame points into the parent frame,
/// `p_parent = rotation * p_child + translation`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

impl Transform {
    /// The message form of `parent_from_child`.
    pub fn from_isometry(parent_from_child: &Isometry3<f64>) -> Self {
        let t = &parent_from_child.translation.vector;
        let q = parent_from_child.rotation.quaternion();
        Self {
            translation: Vector3 {
                x: t.x,
                y: t.y,
                z: t.z,
            },
            rotation: Quaternion {
                x: q.i,
                y: q.j,
                z: q.k,
                w: q.w,
            },
        }
    }

    /// `parent_from_child` as an isometry (the quaternion is normalized).
    pub fn to_isometry(&self) -> Isometry3<f64> {
        let q = self.rotation;
        let t = self.translation;
        Isometry3::from_parts(
            Translation3::new(t.x, t.y, t.z),
            UnitQuaternion::from_quaternion(NaQuaternion::new(q.w, q.x, q.y, q.z)),
        )
    }
}

/// `geometry_msgs/msg/TransformStamped`: `transform` is `header.frame_id <- child_frame_id`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`, published on `/tf` and `/tf_static`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`; `level` is one of the associated constants.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticArray`, published on `/diagnostics`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

/// `rosgraph_msgs/msg/Clock`, published on `/clock` for simulated time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}

macro_rules! ros_message {
    ($($ty:ty => $name:literal),* $(,)?) => {
        $(impl RosMessage for $ty {
            const TYPE_NAME: &'static str = $name;
        })*
    };
}

ros_message! {
    Time => "builtin_interfaces/msg/Time",
    Header => "std_msgs/msg/Header",
    Image => "sensor_msgs/msg/Image",
    CompressedImage => "sensor_msgs/msg/CompressedImage",
    PointField => "sensor_msgs/msg/PointField",
    PointCloud2 => "sensor_msgs/msg/PointCloud2",
    Vector3 => "geometry_msgs/msg/Vector3",
    Quaternion => "geometry_msgs/msg/Quaternion",
    Transform => "geometry_msgs/msg/Transform",
    TransformStamped => "geometry_msgs/msg/TransformStamped",
    TFMessage => "tf2_msgs/msg/TFMessage",
    KeyValue => "diagnostic_msgs/msg/KeyValue",
    DiagnosticStatus => "diagnostic_msgs/msg/DiagnosticStatus",
    DiagnosticArray => "diagnostic_msgs/msg/DiagnosticArray",
    Clock => "rosgraph_msgs/msg/Clock",
}
