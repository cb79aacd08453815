//! CDR golden bytes (written out by hand from the CDR rules), round trips, damaged input, and
//! the `ros2msg` schema text.

use mode360_io::msgs::schema::{self, DEFINITIONS};
use mode360_io::msgs::*;

/// Encapsulation header: CDR little endian, no options.
const HDR: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

fn with_header(body: &[u8]) -> Vec<u8> {
    [&HDR[..], body].concat()
}

#[test]
fn time_golden_bytes() {
    let time = Time { sec: 1, nanosec: 2 };
    let expected = with_header(&[1, 0, 0, 0, 2, 0, 0, 0]);
    assert_eq!(encode_cdr(&time), expected);
    assert_eq!(decode_cdr::<Time>(&expected).ok(), Some(time));
}

#[test]
fn time_nanos_conversion() {
    let t = Time::from_nanos(1_700_000_123_456_789_012);
    assert_eq!((t.sec, t.nanosec), (1_700_000_123, 456_789_012));
    assert_eq!(t.to_nanos(), 1_700_000_123_456_789_012);
    let h = Header::new(2_500_000_000, "base_link");
    assert_eq!((h.stamp.sec, h.stamp.nanosec), (2, 500_000_000));
    assert_eq!(h.frame_id, "base_link");
}

#[test]
fn header_golden_bytes() {
    let header = Header {
        stamp: Time {
            sec: 1,
            nanosec: 500,
        },
        frame_id: "ab".into(),
    };
    // sec | nanosec (500 = 0x1f4) | string length 3 (incl. NUL) | 'a' 'b' NUL
    let expected = with_header(&[1, 0, 0, 0, 0xf4, 0x01, 0, 0, 3, 0, 0, 0, b'a', b'b', 0]);
    assert_eq!(encode_cdr(&header), expected);
    assert_eq!(decode_cdr::<Header>(&expected).ok(), Some(header));
}

#[test]
fn tiny_image_golden_bytes_with_padding() {
    let image = Image {
        header: Header {
            stamp: Time { sec: 0, nanosec: 7 },
            frame_id: "c".into(),
        },
        height: 1,
        width: 2,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 6,
        data: vec![10, 20, 30, 40, 50, 60],
    };
    #[rustfmt::skip]
    let body: &[u8] = &[
        0, 0, 0, 0,             // 0: stamp.sec
        7, 0, 0, 0,             // 4: stamp.nanosec
        2, 0, 0, 0, b'c', 0,    // 8: frame_id "c" (length 2 with NUL)
        0, 0,                   // 14: padding to 4
        1, 0, 0, 0,             // 16: height
        2, 0, 0, 0,             // 20: width
        5, 0, 0, 0, b'r', b'g', b'b', b'8', 0, // 24: encoding "rgb8"
        0,                      // 33: is_bigendian
        0, 0,                   // 34: padding to 4
        6, 0, 0, 0,             // 36: step
        6, 0, 0, 0,             // 40: data length
        10, 20, 30, 40, 50, 60, // 44: data
    ];
    let expected = with_header(body);
    assert_eq!(encode_cdr(&image), expected);
    assert_eq!(decode_cdr::<Image>(&expected).ok(), Some(image));
}

#[test]
fn point_field_golden_bytes_with_padding() {
    let field = PointField::new("x", 4, PointField::FLOAT32, 1);
    #[rustfmt::skip]
    let body: &[u8] = &[
        2, 0, 0, 0, b'x', 0, // 0: name
        0, 0,                // 6: padding to 4
        4, 0, 0, 0,          // 8: offset
        7,                   // 12: datatype FLOAT32
        0, 0, 0,             // 13: padding to 4
        1, 0, 0, 0,          // 16: count
    ];
    let expected = with_header(body);
    assert_eq!(encode_cdr(&field), expected);
    assert_eq!(decode_cdr::<PointField>(&expected).ok(), Some(field));
}

#[test]
fn float64_fields_align_to_eight() {
    // Transform: 7 float64 starting at offset 0; a leading string shifts them to 8.
    let stamped = TransformStamped {
        header: Header::new(0, ""),
        child_frame_id: String::new(),
        transform: Transform::default(),
    };
    let bytes = encode_cdr(&stamped);
    // sec(4) nanosec(4) frame_id len(4)+NUL(1) -> 13, child len at 16 (+4) + NUL -> 21,
    // float64 aligned to 24, 7 of them -> 80.
    assert_eq!(bytes.len(), 4 + 24 + 7 * 8);
    let w_offset = 4 + 24 + 6 * 8;
    assert_eq!(&bytes[w_offset..w_offset + 8], &1.0f64.to_le_bytes());
}

fn sample_header() -> Header {
    Header::new(1_234_567_890_123_456_789, "frame_a")
}

fn round_trip<T: RosMessage + PartialEq + std::fmt::Debug>(msg: T) {
    let bytes = encode_cdr(&msg);
    assert_eq!(&bytes[..4], &HDR);
    let back: T = match decode_cdr(&bytes) {
        Ok(back) => back,
        Err(err) => panic!("{}: {err}", T::TYPE_NAME),
    };
    assert_eq!(back, msg, "{}", T::TYPE_NAME);
    // Every strict prefix is an error, never a panic.
    for cut in 0..bytes.len() {
        assert!(
            decode_cdr::<T>(&bytes[..cut]).is_err(),
            "{} decoded from {cut} of {} bytes",
            T::TYPE_NAME,
            bytes.len()
        );
    }
}

fn sample_transform() -> TransformStamped {
    TransformStamped {
        header: sample_header(),
        child_frame_id: "cam1_link".into(),
        transform: Transform {
            translation: Vector3 {
                x: 0.5,
                y: -0.25,
                z: 1.8,
            },
            rotation: Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.382_683_432_365_089_8,
                w: 0.923_879_532_511_286_7,
            },
        },
    }
}

#[test]
fn every_type_round_trips() {
    round_trip(Time {
        sec: -3,
        nanosec: 999_999_999,
    });
    round_trip(sample_header());
    round_trip(Image {
        header: sample_header(),
        height: 2,
        width: 3,
        encoding: "bgr8".into(),
        is_bigendian: 0,
        step: 10,
        data: (0..20).collect(),
    });
    round_trip(CompressedImage {
        header: sample_header(),
        format: "rgb8; jpeg compressed bgr8".into(),
        data: vec![0xff, 0xd8, 0xff, 0xd9],
    });
    round_trip(PointField::new("rgb", 12, PointField::FLOAT32, 1));
    round_trip(PointCloud2 {
        header: sample_header(),
        height: 1,
        width: 2,
        fields: vec![
            PointField::new("x", 0, PointField::FLOAT32, 1),
            PointField::new("y", 4, PointField::FLOAT32, 1),
        ],
        is_bigendian: false,
        point_step: 8,
        row_step: 16,
        data: (0..16).collect(),
        is_dense: true,
    });
    round_trip(Vector3 {
        x: 1.0,
        y: -2.0,
        z: 3.5,
    });
    round_trip(Quaternion::default());
    round_trip(sample_transform().transform);
    round_trip(sample_transform());
    round_trip(TFMessage {
        transforms: vec![sample_transform(), sample_transform()],
    });
    round_trip(KeyValue {
        key: "fps".into(),
        value: "30".into(),
    });
    let status = DiagnosticStatus {
        level: DiagnosticStatus::WARN,
        name: "mode360: depth".into(),
        message: "slow".into(),
        hardware_id: "cpu".into(),
        values: vec![KeyValue {
            key: "latency_ms".into(),
            value: "250".into(),
        }],
    };
    round_trip(status.clone());
    round_trip(DiagnosticArray {
        header: sample_header(),
        status: vec![status],
    });
    round_trip(Clock {
        clock: Time {
            sec: 42,
            nanosec: 7,
        },
    });
}

#[test]
fn garbage_is_rejected() {
    let good = encode_cdr(&sample_transform());
    // Unknown encapsulation kind.
    let mut bad = good.clone();
    bad[1] = 0x07;
    assert!(matches!(
        decode_cdr::<TransformStamped>(&bad),
        Err(MsgError::BadEncapsulation { .. })
    ));
    // Extra bytes beyond padding: the bytes are not this type.
    let mut long = good.clone();
    long.extend_from_slice(&[0; 8]);
    assert!(matches!(
        decode_cdr::<TransformStamped>(&long),
        Err(MsgError::TrailingBytes { extra: 8, .. })
    ));
    // Up to 3 bytes of padding are fine.
    let mut padded = encode_cdr(&Header::new(0, "ab"));
    padded.push(0);
    assert!(decode_cdr::<Header>(&padded).is_ok());
    // A Time is not an Image.
    assert!(decode_cdr::<Image>(&encode_cdr(&Time::default())).is_err());
    // A huge sequence length fails instead of allocating.
    let huge = with_header(&[0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff, 0xff, 0xff]);
    assert!(decode_cdr::<Header>(&huge).is_err());
    // Bool must be 0 or 1.
    let cloud = PointCloud2::default();
    let mut bytes = encode_cdr(&cloud);
    let last = bytes.len() - 1;
    bytes[last] = 2;
    assert!(decode_cdr::<PointCloud2>(&bytes).is_err());
    // Pseudo-random bytes never panic.
    let mut state: u32 = 0x1234_5678;
    for len in 0..200 {
        let noise: Vec<u8> = (0..len)
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 24) as u8
            })
            .collect();
        let _ = decode_cdr::<DiagnosticArray>(&noise);
        let _ = decode_cdr::<PointCloud2>(&noise);
    }
}

const SEP: &str =
    "================================================================================";

#[test]
fn image_schema_text_golden() {
    let expected = String::new()
        + include_str!("../../../../msg/sensor_msgs/Image.msg")
        + SEP
        + "\nMSG: std_msgs/Header\n"
        + include_str!("../../../../msg/std_msgs/Header.msg")
        + SEP
        + "\nMSG: builtin_interfaces/Time\n"
        + include_str!("../../../../msg/builtin_interfaces/Time.msg");
    let text = schema_text("sensor_msgs/msg/Image").map_err(|e| e.to_string());
    assert_eq!(text.as_deref(), Ok(expected.as_str()));
    // The start, spelled out.
    let text = text.unwrap_or_default();
    assert!(text.starts_with("# This message contains an uncompressed image\n"));
    assert!(text.contains(
        "uint8[] data          # actual matrix data, size is (step * rows)\n\
         ================================================================================\n\
         MSG: std_msgs/Header\n"
    ));
    assert!(text.ends_with(
        "int32 sec\n\n# The nanoseconds component, valid in the range [0, 1e9).\nuint32 nanosec\n"
    ));
    assert_eq!(SEP.len(), 80);
    assert_eq!(SCHEMA_SEPARATOR, SEP);
}

#[test]
fn every_schema_lists_each_dependency_once() {
    let expected: &[(&str, &[&str])] = &[
        ("builtin_interfaces/msg/Time", &[]),
        ("std_msgs/msg/Header", &["builtin_interfaces/Time"]),
        (
            "sensor_msgs/msg/Image",
            &["std_msgs/Header", "builtin_interfaces/Time"],
        ),
        (
            "sensor_msgs/msg/CompressedImage",
            &["std_msgs/Header", "builtin_interfaces/Time"],
        ),
        (
            "sensor_msgs/msg/PointCloud2",
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "sensor_msgs/PointField",
            ],
        ),
        ("sensor_msgs/msg/PointField", &[]),
        (
            "geometry_msgs/msg/TransformStamped",
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/Transform",
                "geometry_msgs/Vector3",
                "geometry_msgs/Quaternion",
            ],
        ),
        (
            "geometry_msgs/msg/Transform",
            &["geometry_msgs/Vector3", "geometry_msgs/Quaternion"],
        ),
        ("geometry_msgs/msg/Vector3", &[]),
        ("geometry_msgs/msg/Quaternion", &[]),
        (
            "tf2_msgs/msg/TFMessage",
            &[
                "geometry_msgs/TransformStamped",
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/Transform",
                "geometry_msgs/Vector3",
                "geometry_msgs/Quaternion",
            ],
        ),
        (
            "diagnostic_msgs/msg/DiagnosticArray",
            &[
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "diagnostic_msgs/DiagnosticStatus",
                "diagnostic_msgs/KeyValue",
            ],
        ),
        (
            "diagnostic_msgs/msg/DiagnosticStatus",
            &["diagnostic_msgs/KeyValue"],
        ),
        ("diagnostic_msgs/msg/KeyValue", &[]),
        ("rosgraph_msgs/msg/Clock", &["builtin_interfaces/Time"]),
        ("rcl_interfaces/msg/Log", &["builtin_interfaces/Time"]),
        (
            "rcl_interfaces/msg/ParameterEvent",
            &[
                "builtin_interfaces/Time",
                "rcl_interfaces/Parameter",
                "rcl_interfaces/ParameterValue",
            ],
        ),
        (
            "rcl_interfaces/msg/Parameter",
            &["rcl_interfaces/ParameterValue"],
        ),
        ("rcl_interfaces/msg/ParameterValue", &[]),
        (
            "rcl_interfaces/msg/ParameterDescriptor",
            &[
                "rcl_interfaces/FloatingPointRange",
                "rcl_interfaces/IntegerRange",
            ],
        ),
        ("rcl_interfaces/msg/FloatingPointRange", &[]),
        ("rcl_interfaces/msg/IntegerRange", &[]),
        ("rcl_interfaces/msg/SetParametersResult", &[]),
        ("rcl_interfaces/msg/ListParametersResult", &[]),
        ("rmw_dds_common/msg/Gid", &[]),
        (
            "rmw_dds_common/msg/NodeEntitiesInfo",
            &["rmw_dds_common/Gid"],
        ),
        (
            "rmw_dds_common/msg/ParticipantEntitiesInfo",
            &["rmw_dds_common/Gid", "rmw_dds_common/NodeEntitiesInfo"],
        ),
    ];
    assert_eq!(expected.len(), DEFINITIONS.len());
    for (type_name, deps) in expected {
        let text = match schema_text(type_name) {
            Ok(text) => text,
            Err(err) => panic!("{type_name}: {err}"),
        };
        let blocks: Vec<&str> = text.split(&format!("{SEP}\n")).collect();
        assert_eq!(blocks.len(), deps.len() + 1, "{type_name}");
        let own = schema::definition(type_name).map(|d| d.text);
        assert_eq!(own.ok(), Some(blocks[0]), "{type_name}: own text first");
        let mut named: Vec<&str> = Vec::new();
        for block in &blocks[1..] {
            let (first_line, body) = block.split_once('\n').unwrap_or((block, ""));
            let name = first_line.strip_prefix("MSG: ");
            assert!(name.is_some(), "{type_name}: block starts '{first_line}'");
            let name = name.unwrap_or_default();
            let def = schema::definition(name).map(|d| d.text);
            assert_eq!(def.ok(), Some(body), "{type_name}: text of {name}");
            named.push(name);
        }
        let mut sorted_named = named.clone();
        sorted_named.sort_unstable();
        sorted_named.dedup();
        assert_eq!(sorted_named.len(), named.len(), "{type_name}: duplicate");
        let mut sorted_expected = deps.to_vec();
        sorted_expected.sort_unstable();
        assert_eq!(sorted_named, sorted_expected, "{type_name}");
        // Trait method and free function agree; short names work too.
        let short = type_name.replace("/msg/", "/");
        assert_eq!(schema_text(&short).ok(), Some(text));
    }
    assert!(matches!(
        schema_text("sensor_msgs/msg/CameraInfo"),
        Err(MsgError::UnknownType { .. })
    ));
    assert!(Image::schema_text().is_ok_and(|t| t.contains("MSG: std_msgs/Header\n")));
}
