//! Third-party decoders read our bags: writes a bag with every message kind the node
//! publishes plus an expected-values JSON, then runs `tests/interop/check_bag.py` (mcap_ros2
//! and rosbags) and `tests/interop/check_bag.mjs` (Foxglove's rosmsg2-serialization over
//! @mcap/core), which must exit 0.
//!
//! Needs `MODE360_PYTHON` (a Python with `mcap mcap-ros2-support rosbags`) and
//! `MODE360_NODE_DIR` (a folder holding `node_modules` with the packages of
//! `tests/interop/package.json`); `tests/interop/setup.sh DIR` makes both. Without them the
//! test is skipped, unless `CI` is set, where it fails. The Python readers also check a
//! zstd-compressed copy of the bag.
//!
//! Checks are `[path, value]` pairs: `a.b[2].c` walks fields and indices, `#len` is a length,
//! `@f32le[i]` / `@u32le[i]` read a little-endian float32 / uint32 element of a byte array,
//! and the string `"NaN"` matches a NaN.

use crate::common::{NODE_DIR_ENV, PYTHON_ENV};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use mode360::bag::{BagCompression, BagWriteOptions, BagWriter};
use mode360::frame::{FloatImage, RgbImage};
use mode360::msgs::*;
use serde_json::{json, Value};

const T0_NS: u64 = 1_700_000_000_000_000_000;
const FRAME_PERIOD_NS: u64 = 100_000_000;
const METADATA_NAME: &str = "mode360.interop";

/// One message written and what the checkers must find in it.
struct Expected {
    topic: &'static str,
    schema: &'static str,
    log_time_ns: u64,
    checks: Vec<(String, Value)>,
}

impl Expected {
    fn to_json(&self) -> Value {
        json!({
            "topic": self.topic,
            "schema": self.schema,
            "log_time_ns": self.log_time_ns.to_string(),
            "checks": self.checks.iter().map(|(p, v)| json!([p, v])).collect::<Vec<_>>(),
        })
    }
}

fn check(path: &str, value: impl Into<Value>) -> (String, Value) {
    (path.to_string(), value.into())
}

fn header_checks(header: &Header) -> Vec<(String, Value)> {
    vec![
        check("header.stamp.sec", header.stamp.sec),
        check("header.stamp.nanosec", header.stamp.nanosec),
        check("header.frame_id", header.frame_id.clone()),
    ]
}

/// Writes `msg` and records the checks.
fn put<T: RosMessage>(
    bag: &mut BagWriter,
    expected: &mut Vec<Expected>,
    topic: &'static str,
    log_time_ns: u64,
    msg: &T,
    checks: Vec<(String, Value)>,
) {
    if let Err(err) = bag.write(topic, log_time_ns, msg) {
        panic!("writing {topic}: {err}");
    }
    expected.push(Expected {
        topic,
        schema: T::TYPE_NAME,
        log_time_ns,
        checks,
    });
}

fn test_image(frame: u32) -> RgbImage {
    RgbImage::from_fn(4, 2, |u, v| {
        ::image::Rgb([
            (10 * u + 50 * v + frame) as u8,
            (200 - 7 * u) as u8,
            (3 * v + 40 * frame) as u8,
        ])
    })
}

fn image_checks(msg: &Image, rgb: &RgbImage) -> Vec<(String, Value)> {
    let mut checks = header_checks(&msg.header);
    checks.extend([
        check("width", rgb.width()),
        check("height", rgb.height()),
        check("encoding", "rgb8"),
        check("is_bigendian", 0),
        check("step", rgb.width() * 3),
        check("data#len", rgb.as_raw().len()),
    ]);
    // Pixel (u=3, v=1) and (u=0, v=0), channel by channel.
    for (u, v) in [(3u32, 1u32), (0, 0)] {
        let px = rgb.get_pixel(u, v).0;
        for (c, value) in px.iter().enumerate() {
            let index = (v * msg.step + u * 3) as usize + c;
            checks.push(check(&format!("data[{index}]"), *value));
        }
    }
    checks
}

/// Writes the bag and returns what each message must decode to.
fn write_bag(path: &Path, options: BagWriteOptions) -> Vec<Expected> {
    let mut bag = match BagWriter::create_with(path, options) {
        Ok(bag) => bag,
        Err(err) => panic!("{err}"),
    };
    let mut expected = Vec::new();
    let meta = BTreeMap::from([("purpose".to_string(), "interop".to_string())]);
    if let Err(err) = bag.write_metadata(METADATA_NAME, meta) {
        panic!("{err}");
    }

    // /tf_static: two cameras, one turned 90 degrees left.
    let half_sqrt2 = std::f64::consts::FRAC_1_SQRT_2;
    let tf = TFMessage {
        transforms: vec![
            TransformStamped {
                header: Header::new(T0_NS, "base_link"),
                child_frame_id: "cam1_link".into(),
                transform: Transform {
                    translation: Vector3 {
                        x: 0.5,
                        y: 0.5,
                        z: 1.8,
                    },
                    rotation: Quaternion::default(),
                },
            },
            TransformStamped {
                header: Header::new(T0_NS, "base_link"),
                child_frame_id: "cam2_link".into(),
                transform: Transform {
                    translation: Vector3 {
                        x: 0.5,
                        y: -0.5,
                        z: 1.8,
                    },
                    rotation: Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: half_sqrt2,
                        w: half_sqrt2,
                    },
                },
            },
        ],
    };
    let mut checks = vec![check("transforms#len", 2)];
    for (i, t) in tf.transforms.iter().enumerate() {
        let p = format!("transforms[{i}]");
        let tr = &t.transform;
        checks.extend([
            check(&format!("{p}.header.frame_id"), t.header.frame_id.clone()),
            check(&format!("{p}.header.stamp.sec"), t.header.stamp.sec),
            check(&format!("{p}.child_frame_id"), t.child_frame_id.clone()),
            check(&format!("{p}.transform.translation.x"), tr.translation.x),
            check(&format!("{p}.transform.translation.y"), tr.translation.y),
            check(&format!("{p}.transform.translation.z"), tr.translation.z),
            check(&format!("{p}.transform.rotation.z"), tr.rotation.z),
            check(&format!("{p}.transform.rotation.w"), tr.rotation.w),
        ]);
    }
    put(&mut bag, &mut expected, "/tf_static", T0_NS, &tf, checks);

    for frame in 0..2u32 {
        let stamp = T0_NS + u64::from(frame) * FRAME_PERIOD_NS;
        let clock = Clock {
            clock: Time::from_nanos(stamp),
        };
        let checks = vec![
            check("clock.sec", clock.clock.sec),
            check("clock.nanosec", clock.clock.nanosec),
        ];
        put(&mut bag, &mut expected, "/clock", stamp, &clock, checks);

        let rgb = test_image(frame);
        let msg = image_msg_from_rgb(Header::new(stamp, "cam1_link"), &rgb);
        let checks = image_checks(&msg, &rgb);
        put(
            &mut bag,
            &mut expected,
            "/cam1/image_raw",
            stamp,
            &msg,
            checks,
        );

        // Ground truth 32FC1 with a NaN.
        let mut gt = FloatImage::filled(4, 2, 0.0);
        for (i, v) in gt.data.iter_mut().enumerate() {
            *v = 0.5 + 1.25 * i as f32 + frame as f32;
        }
        gt.data[5] = f32::NAN;
        let msg = image_msg_from_float(Header::new(stamp, "cam1_link"), &gt);
        let mut checks = header_checks(&msg.header);
        checks.extend([
            check("encoding", "32FC1"),
            check("width", 4),
            check("height", 2),
            check("step", 16),
            check("data#len", 32),
            check("data@f32le[0]", f64::from(gt.data[0])),
            check("data@f32le[7]", f64::from(gt.data[7])),
            check("data@f32le[5]", "NaN"),
        ]);
        put(
            &mut bag,
            &mut expected,
            "/ground_truth/depth",
            stamp,
            &msg,
            checks,
        );

        // Labels (docs/ground_truth.md): classes 8UC1 (0 sky, 1 ground, 2 structure,
        // 3 object), instances 16UC1 little endian, 0 off objects. The checks are the
        // documented bytes, written out by hand.
        let mut labels = mode360::frame::SceneLabels::sky(4, 2);
        labels.class = [0u8, 1, 2, 3, 3, 1, 1, 0]
            .iter()
            .map(|&c| mode360::frame::SurfaceClass::from_u8(c).unwrap_or_default())
            .collect();
        labels.instance = vec![0, 0, 0, 7 + frame as u16, 300, 0, 0, 0];
        let (classes, instances) = label_image_msgs(&Header::new(stamp, "cam1_link"), &labels);
        let mut checks = header_checks(&classes.header);
        checks.extend([
            check("encoding", "8UC1"),
            check("width", 4),
            check("height", 2),
            check("step", 4),
            check("data#len", 8),
            check("data[2]", 2),
            check("data[3]", 3),
            check("data[5]", 1),
        ]);
        put(
            &mut bag,
            &mut expected,
            "/ground_truth/classes",
            stamp,
            &classes,
            checks,
        );
        let mut checks = header_checks(&instances.header);
        checks.extend([
            check("encoding", "16UC1"),
            check("is_bigendian", 0),
            check("step", 8),
            check("data#len", 16),
            check("data[6]", 7 + frame),
            check("data[7]", 0),
            check("data[8]", 0x2c),
            check("data[9]", 0x01),
        ]);
        put(
            &mut bag,
            &mut expected,
            "/ground_truth/instances",
            stamp,
            &instances,
            checks,
        );
    }

    // Coloured point cloud: x y z float32 and packed float32 rgb (0x00RRGGBB bits).
    let points: [([f32; 3], [u8; 3]); 3] = [
        ([1.0, 2.0, 3.0], [255, 0, 0]),
        ([-4.5, 0.25, 10.0], [0, 128, 255]),
        ([0.0, -1.0, 0.5], [12, 34, 56]),
    ];
    const POINT_STEP: u32 = 16;
    let mut data = Vec::new();
    for (xyz, rgb) in &points {
        for c in xyz {
            data.extend_from_slice(&c.to_le_bytes());
        }
        let packed = u32::from(rgb[0]) << 16 | u32::from(rgb[1]) << 8 | u32::from(rgb[2]);
        data.extend_from_slice(&f32::from_bits(packed).to_le_bytes());
    }
    let cloud = PointCloud2 {
        header: Header::new(T0_NS + 5, "cam1_link"),
        height: 1,
        width: points.len() as u32,
        fields: ["x", "y", "z", "rgb"]
            .iter()
            .enumerate()
            .map(|(i, name)| PointField::new(*name, 4 * i as u32, PointField::FLOAT32, 1))
            .collect(),
        is_bigendian: false,
        point_step: POINT_STEP,
        row_step: POINT_STEP * points.len() as u32,
        data,
        is_dense: true,
    };
    let mut checks = header_checks(&cloud.header);
    checks.extend([
        check("width", 3),
        check("height", 1),
        check("point_step", POINT_STEP),
        check("row_step", 48),
        check("is_bigendian", false),
        check("is_dense", true),
        check("fields#len", 4),
        check("fields[3].name", "rgb"),
        check("fields[3].offset", 12),
        check("fields[3].datatype", PointField::FLOAT32),
        check("fields[3].count", 1),
        check("fields[1].name", "y"),
        check("data#len", 48),
    ]);
    for (i, (xyz, rgb)) in points.iter().enumerate() {
        for (c, value) in xyz.iter().enumerate() {
            checks.push(check(
                &format!("data@f32le[{}]", 4 * i + c),
                f64::from(*value),
            ));
        }
        let packed = u32::from(rgb[0]) << 16 | u32::from(rgb[1]) << 8 | u32::from(rgb[2]);
        checks.push(check(&format!("data@u32le[{}]", 4 * i + 3), packed));
    }
    put(
        &mut bag,
        &mut expected,
        "/points",
        T0_NS + 5,
        &cloud,
        checks,
    );

    let diagnostics = DiagnosticArray {
        header: Header::new(T0_NS + 7, ""),
        status: vec![DiagnosticStatus {
            level: DiagnosticStatus::WARN,
            name: "mode360: depth".into(),
            message: "latency above budget".into(),
            hardware_id: "cpu0".into(),
            values: vec![
                KeyValue {
                    key: "latency_ms".into(),
                    value: "250.5".into(),
                },
                KeyValue {
                    key: "frames".into(),
                    value: "2".into(),
                },
            ],
        }],
    };
    let mut checks = header_checks(&diagnostics.header);
    checks.extend([
        check("status#len", 1),
        check("status[0].level", DiagnosticStatus::WARN),
        check("status[0].name", "mode360: depth"),
        check("status[0].message", "latency above budget"),
        check("status[0].hardware_id", "cpu0"),
        check("status[0].values#len", 2),
        check("status[0].values[0].key", "latency_ms"),
        check("status[0].values[0].value", "250.5"),
        check("status[0].values[1].key", "frames"),
    ]);
    put(
        &mut bag,
        &mut expected,
        "/diagnostics",
        T0_NS + 7,
        &diagnostics,
        checks,
    );

    // PNG CompressedImage of the first test image.
    let rgb = test_image(0);
    let mut png = Vec::new();
    let encoded = ::image::DynamicImage::ImageRgb8(rgb.clone()).write_to(
        &mut std::io::Cursor::new(&mut png),
        ::image::ImageFormat::Png,
    );
    assert!(encoded.is_ok());
    let compressed = CompressedImage {
        header: Header::new(T0_NS + 9, "cam1_link"),
        format: "rgb8; png compressed rgb8".into(),
        data: png.clone(),
    };
    // Our own decoder must give back the pixels.
    let decoded = rgb_from_compressed(&compressed).map(|i| i.into_raw());
    assert_eq!(decoded.ok().as_ref(), Some(rgb.as_raw()));
    let mut checks = header_checks(&compressed.header);
    checks.push(check("format", "rgb8; png compressed rgb8"));
    checks.push(check("data#len", png.len()));
    for (i, byte) in png.iter().take(8).enumerate() {
        checks.push(check(&format!("data[{i}]"), *byte));
    }
    let last = png.len() - 1;
    checks.push(check(&format!("data[{last}]"), png[last]));
    put(
        &mut bag,
        &mut expected,
        "/cam1/image_raw/compressed",
        T0_NS + 9,
        &compressed,
        checks,
    );

    if let Err(err) = bag.finish() {
        panic!("{err}");
    }
    expected
}

/// The env var, or `None` after printing why the check is skipped (panics under CI).
fn tool_from_env(var: &str, what: &str) -> Option<String> {
    crate::common::tool_from_env(
        var,
        what,
        &format!(
            "set {PYTHON_ENV}=<python with mcap mcap-ros2-support rosbags> and \
             {NODE_DIR_ENV}=<folder with node_modules> (tests/interop/setup.sh DIR makes both)"
        ),
    )
}

/// Runs a checker on `json_path`; returns (success, stdout).
fn run_checker(
    program: &str,
    script: &Path,
    json_path: &Path,
    node_dir: Option<&str>,
) -> (bool, String) {
    let mut cmd = Command::new(program);
    cmd.arg(script).arg(json_path);
    if let Some(node_dir) = node_dir {
        cmd.env(NODE_DIR_ENV, node_dir);
    }
    let output = match cmd.output() {
        Ok(output) => output,
        Err(err) => panic!("cannot run {program} {}: {err}", script.display()),
    };
    let stdout = String::from_utf8_lossy(&output.stdout).to_string();
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!(
        "--- {} stdout ---\n{stdout}--- stderr ---\n{stderr}",
        script.display()
    );
    (output.status.success(), stdout)
}

/// The checker passes on the true expectations and fails, naming the field, on tampered ones.
fn check_both_ways(
    program: &str,
    script: &Path,
    good: &Path,
    tampered: &Path,
    node_dir: Option<&str>,
) {
    let (ok, stdout) = run_checker(program, script, good, node_dir);
    assert!(
        ok && stdout.contains("OK"),
        "{} failed: {stdout}",
        script.display()
    );
    let (ok, stdout) = run_checker(program, script, tampered, node_dir);
    assert!(!ok, "{} accepted tampered expectations", script.display());
    for path in TAMPERED_PATHS {
        assert!(
            stdout.contains(path),
            "{} did not report {path}",
            script.display()
        );
    }
}

/// Checks altered in the tampered JSON (every occurrence).
const TAMPERED_PATHS: [&str; 3] = [
    "data@f32le[7]",
    "transforms[1].transform.rotation.z",
    "status[0].values[0].value",
];

/// `json` with every check named in [`TAMPERED_PATHS`] changed.
fn tamper(json: &Value) -> Value {
    let mut out = json.clone();
    if let Some(messages) = out.get_mut("messages").and_then(Value::as_array_mut) {
        for message in messages {
            let Some(checks) = message.get_mut("checks").and_then(Value::as_array_mut) else {
                continue;
            };
            for pair in checks {
                let is_target = pair
                    .get(0)
                    .and_then(Value::as_str)
                    .is_some_and(|p| TAMPERED_PATHS.contains(&p));
                if !is_target {
                    continue;
                }
                if let Some(value) = pair.get_mut(1) {
                    *value = match value {
                        Value::Number(n) => json!(n.as_f64().unwrap_or(0.0) * 1.0001 + 0.001),
                        _ => json!("tampered"),
                    };
                }
            }
        }
    }
    out
}

#[test]
fn third_party_decoders_read_our_bag() {
    let python = tool_from_env(PYTHON_ENV, "python interop check");
    let node_dir = tool_from_env(NODE_DIR_ENV, "node interop check");
    if python.is_none() && node_dir.is_none() {
        return;
    }
    let dir = match tempfile::tempdir() {
        Ok(dir) => dir,
        Err(err) => panic!("{err}"),
    };
    let bag_path = dir.path().join("interop.mcap");
    let expected = write_bag(&bag_path, BagWriteOptions::default());
    // The same content with zstd chunks (checked by the Python readers, which ship zstd).
    let zstd_path = dir.path().join("interop_zstd.mcap");
    let zstd = BagWriteOptions {
        compression: BagCompression::Zstd,
        chunk_size_bytes: None,
    };
    let zstd_expected = write_bag(&zstd_path, zstd);
    assert_eq!(zstd_expected.len(), expected.len());
    let json = json!({
        "bag": bag_path.display().to_string(),
        "profile": "ros2",
        "metadata": { METADATA_NAME: { "purpose": "interop" } },
        "messages": expected.iter().map(Expected::to_json).collect::<Vec<_>>(),
    });
    let json_path = dir.path().join("expected.json");
    assert!(std::fs::write(&json_path, json.to_string()).is_ok());
    let tampered_path = dir.path().join("tampered.json");
    assert!(std::fs::write(&tampered_path, tamper(&json).to_string()).is_ok());

    let interop_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/interop");
    if let Some(python) = python {
        let script = interop_dir.join("check_bag.py");
        check_both_ways(&python, &script, &json_path, &tampered_path, None);
        let mut zstd_json = json.clone();
        zstd_json["bag"] = json!(zstd_path.display().to_string());
        let zstd_json_path = dir.path().join("expected_zstd.json");
        assert!(std::fs::write(&zstd_json_path, zstd_json.to_string()).is_ok());
        let (ok, stdout) = run_checker(&python, &script, &zstd_json_path, None);
        assert!(ok && stdout.contains("OK"), "zstd bag: {stdout}");
    }
    if let Some(node_dir) = node_dir {
        let script = interop_dir.join("check_bag.mjs");
        check_both_ways("node", &script, &json_path, &tampered_path, Some(&node_dir));
    }
}
