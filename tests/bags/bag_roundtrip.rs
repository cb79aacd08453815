//! Rig bags: write synthetic frames, read them back byte for byte; damaged and incomplete bags
//! give errors naming the file and topic.

use std::collections::BTreeMap;
use std::path::Path;

use mode360::bag::*;
use mode360::frame::{FloatImage, RgbImage, RigFrame};
use mode360::geometry::rig::Rig;
use mode360::msgs::{Header, Image, TFMessage};

const RIG_YAML: &str = "
rig_frame: base_link
reference_camera: front
output:
  frame_id: depth_link
  rig_from_output: {translation: [0.1, 0.0, 1.5], rotation_xyzw: [0.0, 0.0, 0.0, 1.0]}
cameras:
  - name: front
    topic: /front/image_raw
    frame_id: front_link
    projection: equirectangular
    rig_from_cam: {translation: [0.5, 0.0, 1.5], rotation_xyzw: [0.0, 0.0, 0.0, 1.0]}
  - name: left
    topic: /left/image_raw
    frame_id: left_link
    projection: equirectangular
    rig_from_cam: {translation: [0.0, 0.5, 1.5], rotation_xyzw: [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]}
  - name: back
    topic: /back/image_raw
    frame_id: back_link
    projection: equirectangular
    rig_from_cam: {translation: [-0.5, 0.0, 1.5], rotation_xyzw: [0.0, 0.0, 0.0, 1.0]}
";

const WIDTH: u32 = 16;
const HEIGHT: u32 = 8;
const STAMPS_NS: [u64; 2] = [1_700_000_000_000_000_000, 1_700_000_000_100_000_000];

fn rig() -> Rig {
    match Rig::from_yaml_str(RIG_YAML, "test rig") {
        Ok(rig) => rig,
        Err(err) => panic!("{err}"),
    }
}

/// A deterministic image whose every byte depends on frame, camera, pixel and channel.
fn image(frame: usize, camera: usize) -> RgbImage {
    RgbImage::from_fn(WIDTH, HEIGHT, |u, v| {
        let base = (frame * 97 + camera * 31) as u32 + u * 7 + v * 13;
        image::Rgb([base as u8, (base * 3 + 1) as u8, (base * 5 + 2) as u8])
    })
}

fn ground_truth(frame: usize) -> FloatImage {
    let mut gt = FloatImage::filled(WIDTH as usize, HEIGHT as usize, 0.0);
    for (i, value) in gt.data.iter_mut().enumerate() {
        *value = 0.5 + i as f32 * 0.25 + frame as f32 * 100.0;
    }
    gt.data[3] = f32::NAN;
    gt
}

fn frames() -> Vec<RigFrame> {
    (0..STAMPS_NS.len())
        .map(|f| RigFrame {
            stamp_ns: STAMPS_NS[f],
            images: (0..3).map(|c| image(f, c)).collect(),
            ground_truth: Some(ground_truth(f)),
            labels: None,
        })
        .collect()
}

fn info() -> BTreeMap<String, String> {
    BTreeMap::from([
        ("scene".to_string(), "unit-test".to_string()),
        ("seed".to_string(), "7".to_string()),
    ])
}

fn write_bag(path: &Path, options: BagWriteOptions) -> Result<(), BagError> {
    let mut writer = RigBagWriter::create_with(path, &rig(), &info(), options)?;
    for frame in frames() {
        writer.write_frame(&frame)?;
    }
    writer.finish()
}

fn temp_dir() -> tempfile::TempDir {
    match tempfile::tempdir() {
        Ok(dir) => dir,
        Err(err) => panic!("temp dir: {err}"),
    }
}

fn same_floats(a: &FloatImage, b: &FloatImage) -> bool {
    a.width == b.width
        && a.height == b.height
        && a.data.len() == b.data.len()
        && a.data
            .iter()
            .zip(&b.data)
            .all(|(x, y)| x.to_bits() == y.to_bits())
}

#[test]
fn rig_bag_round_trip() {
    let dir = temp_dir();
    let path = dir.path().join("frames.mcap");
    let written = write_bag(&path, BagWriteOptions::default());
    assert!(written.is_ok(), "{written:?}");

    let reader = match RigBagReader::open(&path) {
        Ok(reader) => reader,
        Err(err) => panic!("{err}"),
    };
    assert_eq!(reader.rig(), &rig());
    assert_eq!(reader.info(), info());
    assert_eq!(reader.bag().profile(), "ros2");
    assert!(reader.bag().check_complete().is_ok());

    let read: Vec<RigFrame> = match reader.frames().collect::<Result<_, _>>() {
        Ok(read) => read,
        Err(err) => panic!("{err}"),
    };
    let expected = frames();
    assert_eq!(read.len(), expected.len());
    for (got, want) in read.iter().zip(&expected) {
        assert_eq!(got.stamp_ns, want.stamp_ns);
        assert_eq!(got.images.len(), 3);
        for (g, w) in got.images.iter().zip(&want.images) {
            assert_eq!(g.dimensions(), (WIDTH, HEIGHT));
            assert_eq!(g.as_raw(), w.as_raw());
        }
        match (&got.ground_truth, &want.ground_truth) {
            (Some(g), Some(w)) => assert!(same_floats(g, w)),
            other => panic!("ground truth mismatch: {other:?}"),
        }
    }

    // Raw bag view: topics, schemas, headers, tf.
    let bag = reader.bag();
    let topics: BTreeMap<String, (String, usize)> = bag
        .topics()
        .into_iter()
        .map(|t| (t.topic, (t.type_name, t.message_count)))
        .collect();
    let image_type = ("sensor_msgs/msg/Image".to_string(), 2);
    assert_eq!(topics.get("/front/image_raw"), Some(&image_type));
    assert_eq!(topics.get("/back/image_raw"), Some(&image_type));
    assert_eq!(topics.get(GROUND_TRUTH_TOPIC), Some(&image_type));
    assert_eq!(
        topics.get("/tf_static"),
        Some(&("tf2_msgs/msg/TFMessage".to_string(), 1))
    );
    let log_times: Vec<u64> = bag
        .messages()
        .filter_map(Result::ok)
        .map(|m| m.log_time_ns)
        .collect();
    assert!(log_times.windows(2).all(|w| w[0] <= w[1]));
    assert_eq!(log_times.len(), 1 + 2 * 4);

    let left: Vec<Image> = bag.decode_topic("/left/image_raw").unwrap_or_default();
    assert_eq!(left.len(), 2);
    assert_eq!(left[1].header, Header::new(STAMPS_NS[1], "left_link"));
    assert_eq!(
        (left[1].encoding.as_str(), left[1].step),
        ("rgb8", WIDTH * 3)
    );
    let gt: Vec<Image> = bag.decode_topic(GROUND_TRUTH_TOPIC).unwrap_or_default();
    assert_eq!(gt[0].header.frame_id, "depth_link");
    assert_eq!(gt[0].encoding, "32FC1");
    assert_eq!(&gt[0].data[4..8], &0.75f32.to_le_bytes());

    let tf: Vec<TFMessage> = bag.decode_topic("/tf_static").unwrap_or_default();
    assert_eq!(tf.len(), 1);
    let children: Vec<&str> = tf[0]
        .transforms
        .iter()
        .map(|t| t.child_frame_id.as_str())
        .collect();
    assert_eq!(
        children,
        ["front_link", "left_link", "back_link", "depth_link"]
    );
    assert!(tf[0]
        .transforms
        .iter()
        .all(|t| t.header.frame_id == "base_link"));
    let left_tf = tf[0].transforms[1].transform;
    assert_eq!(
        (
            left_tf.translation.x,
            left_tf.translation.y,
            left_tf.translation.z
        ),
        (0.0, 0.5, 1.5)
    );
    assert!((left_tf.rotation.z - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    assert!((left_tf.rotation.w - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    let depth_tf = tf[0].transforms[3].transform.translation;
    assert_eq!((depth_tf.x, depth_tf.y, depth_tf.z), (0.1, 0.0, 1.5));

    // Decoding with the wrong type is an error naming the topic.
    let wrong = bag.decode_topic::<TFMessage>("/left/image_raw");
    let msg = wrong.err().map(|e| e.to_string()).unwrap_or_default();
    assert!(msg.contains("/left/image_raw") && msg.contains("sensor_msgs/msg/Image"));
}

#[test]
fn zstd_and_lz4_bags_read_back() {
    for compression in [BagCompression::Zstd, BagCompression::Lz4] {
        let dir = temp_dir();
        let path = dir.path().join("compressed.mcap");
        let options = BagWriteOptions {
            compression,
            chunk_size_bytes: None,
        };
        assert!(write_bag(&path, options).is_ok());
        let reader = RigBagReader::open(&path);
        let read: Result<Vec<RigFrame>, _> = match &reader {
            Ok(r) => r.frames().collect(),
            Err(err) => panic!("{err}"),
        };
        let read = read.unwrap_or_default();
        assert_eq!(read.len(), 2, "{compression:?}");
        assert_eq!(read[1].images[2].as_raw(), image(1, 2).as_raw());
    }
}

#[test]
fn truncated_bag_is_an_error_naming_the_file() {
    let dir = temp_dir();
    let path = dir.path().join("full.mcap");
    // Small chunks, so a cut loses little.
    let options = BagWriteOptions {
        compression: BagCompression::None,
        chunk_size_bytes: Some(256),
    };
    assert!(write_bag(&path, options).is_ok());
    let bytes = std::fs::read(&path).unwrap_or_default();
    let len = bytes.len();
    assert!(len > 4000, "bag of {len} bytes");

    // Where the data section ends: the last image message is complete before it.
    let cuts = [
        0,
        5,
        8,
        40,
        len / 4,
        len / 2,
        3 * len / 4,
        len - 200,
        len - 9,
        len - 1,
    ];
    let mut recovered_some = false;
    for cut in cuts {
        let cut_path = dir.path().join(format!("cut_{cut}.mcap"));
        assert!(std::fs::write(&cut_path, &bytes[..cut]).is_ok());
        let cut_name = cut_path.display().to_string();
        let errors: Vec<String> = match RigBagReader::open(&cut_path) {
            Err(err) => vec![err.to_string()],
            Ok(reader) => {
                let items: Vec<Result<RigFrame, BagError>> = reader.frames().collect();
                let good: Vec<&RigFrame> = items.iter().filter_map(|r| r.as_ref().ok()).collect();
                // Frames recovered before the damage are exactly the written ones.
                for frame in &good {
                    let index = STAMPS_NS.iter().position(|&s| s == frame.stamp_ns);
                    let index = index.unwrap_or(usize::MAX);
                    assert!(index < 2, "unexpected stamp {}", frame.stamp_ns);
                    assert_eq!(frame.images[0].as_raw(), image(index, 0).as_raw());
                    recovered_some = true;
                }
                println!(
                    "cut at {cut} of {len} bytes: {} frames recovered",
                    good.len()
                );
                items
                    .into_iter()
                    .filter_map(Result::err)
                    .map(|e| e.to_string())
                    .collect()
            }
        };
        println!(
            "cut at {cut} of {len} bytes: first error: {:?}",
            errors.first()
        );
        assert!(!errors.is_empty(), "cut at {cut} of {len}: no error");
        assert!(
            errors.iter().any(|e| e.contains(&cut_name)),
            "cut at {cut}: {errors:?}"
        );
    }
    assert!(recovered_some, "no frame recovered from any cut");

    // The raw reader keeps every message before the damage and then reports it.
    let cut_path = dir.path().join("cut_late.mcap");
    assert!(std::fs::write(&cut_path, &bytes[..len - 200]).is_ok());
    let bag = BagReader::open(&cut_path);
    let bag = match bag {
        Ok(bag) => bag,
        Err(err) => panic!("{err}"),
    };
    let items: Vec<_> = bag.messages().collect();
    assert!(items.last().is_some_and(|r| r.is_err()));
    assert!(items.iter().filter(|r| r.is_ok()).count() >= 5);
}

#[test]
fn missing_camera_topic_and_missing_camera_image_are_named() {
    let dir = temp_dir();
    // A bag written for a 2-camera rig, read with the 3-camera rig: /back/image_raw is absent.
    let path = dir.path().join("two_cams.mcap");
    let two = rig().subset(&[0, 1]);
    let two = match two {
        Ok(two) => two,
        Err(err) => panic!("{err}"),
    };
    let mut writer = match RigBagWriter::create(&path, &two, &info()) {
        Ok(w) => w,
        Err(err) => panic!("{err}"),
    };
    let frame = RigFrame {
        stamp_ns: STAMPS_NS[0],
        images: vec![image(0, 0), image(0, 1)],
        ground_truth: None,
        labels: None,
    };
    assert!(writer.write_frame(&frame).is_ok());
    assert!(writer.finish().is_ok());
    let reader = RigBagReader::open_with_rig(&path, rig());
    let first = reader.ok().and_then(|r| r.frames().next());
    let msg = match first {
        Some(Err(err)) => err.to_string(),
        other => panic!("expected an error, got {other:?}"),
    };
    assert!(msg.contains("/back/image_raw"), "{msg}");
    assert!(msg.contains(&path.display().to_string()), "{msg}");

    // A stamp where one camera has no image.
    let path = dir.path().join("gap.mcap");
    let mut bag = match BagWriter::create(&path) {
        Ok(bag) => bag,
        Err(err) => panic!("{err}"),
    };
    let the_rig = rig();
    let yaml = BTreeMap::from([("yaml".to_string(), the_rig.to_yaml())]);
    assert!(bag.write_metadata(RIG_METADATA, yaml).is_ok());
    for (stamp_index, stamp) in STAMPS_NS.iter().enumerate() {
        for (c, camera) in the_rig.cameras.iter().enumerate() {
            if stamp_index == 1 && c == 2 {
                continue;
            }
            let msg = mode360::msgs::image_msg_from_rgb(
                Header::new(*stamp, &camera.frame_id),
                &image(stamp_index, c),
            );
            assert!(bag.write(&camera.topic, *stamp, &msg).is_ok());
        }
    }
    assert!(bag.finish().is_ok());
    let reader = RigBagReader::open(&path);
    let items: Vec<Result<RigFrame, BagError>> = match &reader {
        Ok(r) => r.frames().collect(),
        Err(err) => panic!("{err}"),
    };
    assert_eq!(items.len(), 2);
    assert!(items[0].is_ok());
    let msg = items[1]
        .as_ref()
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        msg.contains("/back/image_raw") && msg.contains("back"),
        "{msg}"
    );

    // Wrong encoding on a camera topic.
    let path = dir.path().join("wrong_encoding.mcap");
    let mut bag = match BagWriter::create(&path) {
        Ok(bag) => bag,
        Err(err) => panic!("{err}"),
    };
    for camera in &the_rig.cameras {
        let msg = mode360::msgs::image_msg_from_float(
            Header::new(STAMPS_NS[0], &camera.frame_id),
            &ground_truth(0),
        );
        assert!(bag.write(&camera.topic, STAMPS_NS[0], &msg).is_ok());
    }
    assert!(bag.finish().is_ok());
    let reader = RigBagReader::open_with_rig(&path, rig());
    let first = reader.ok().and_then(|r| r.frames().next());
    let msg = match first {
        Some(Err(err)) => err.to_string(),
        other => panic!("expected an error, got {other:?}"),
    };
    assert!(
        msg.contains("/front/image_raw") && msg.contains("32FC1"),
        "{msg}"
    );

    // A bag without rig metadata names the record.
    let err = RigBagReader::open(&path).err().map(|e| e.to_string());
    assert!(err.is_some_and(|e| e.contains(RIG_METADATA)));
}

#[test]
fn flipped_byte_is_detected_by_chunk_crc() {
    let dir = temp_dir();
    let path = dir.path().join("flip.mcap");
    let options = BagWriteOptions {
        compression: BagCompression::None,
        chunk_size_bytes: Some(256),
    };
    assert!(write_bag(&path, options).is_ok());
    let mut bytes = std::fs::read(&path).unwrap_or_default();
    // Find the second frame's first pixel bytes (unique pattern) and flip one.
    let needle = image(1, 0).as_raw()[..12].to_vec();
    let at = bytes
        .windows(needle.len())
        .position(|w| w == needle.as_slice());
    let at = match at {
        Some(at) => at,
        None => panic!("pixel pattern not found"),
    };
    bytes[at + 5] ^= 0x40;
    let bad_path = dir.path().join("flipped.mcap");
    assert!(std::fs::write(&bad_path, &bytes).is_ok());
    let reader = match RigBagReader::open(&bad_path) {
        Ok(reader) => reader,
        Err(err) => panic!("{err}"),
    };
    let items: Vec<Result<RigFrame, BagError>> = reader.frames().collect();
    let good: Vec<&RigFrame> = items.iter().filter_map(|r| r.as_ref().ok()).collect();
    // No frame with the flipped byte is returned as good data.
    for frame in &good {
        let index = STAMPS_NS
            .iter()
            .position(|&s| s == frame.stamp_ns)
            .unwrap_or(usize::MAX);
        assert!(index < 2);
        assert_eq!(frame.images[0].as_raw(), image(index, 0).as_raw());
    }
    let errors: Vec<String> = items
        .iter()
        .filter_map(|r| r.as_ref().err())
        .map(|e| e.to_string())
        .collect();
    println!(
        "flipped byte: {} good frames, errors: {errors:?}",
        good.len()
    );
    // The corrupt chunk is dropped whole; chunks after it are kept (small chunks: the
    // second frame survives).
    assert_eq!(good.len(), 1);
    assert!(errors
        .iter()
        .any(|e| e.contains(&bad_path.display().to_string()) && e.to_lowercase().contains("crc")));
}

#[test]
fn compressed_camera_images_are_decoded() {
    let dir = temp_dir();
    let path = dir.path().join("compressed_cams.mcap");
    let the_rig = rig();
    let mut bag = match BagWriter::create(&path) {
        Ok(bag) => bag,
        Err(err) => panic!("{err}"),
    };
    let yaml = BTreeMap::from([("yaml".to_string(), the_rig.to_yaml())]);
    assert!(bag.write_metadata(RIG_METADATA, yaml).is_ok());
    for (c, camera) in the_rig.cameras.iter().enumerate() {
        let mut png = Vec::new();
        let encoded = ::image::DynamicImage::ImageRgb8(image(0, c)).write_to(
            &mut std::io::Cursor::new(&mut png),
            ::image::ImageFormat::Png,
        );
        assert!(encoded.is_ok());
        let msg = mode360::msgs::CompressedImage {
            header: Header::new(STAMPS_NS[0], &camera.frame_id),
            format: "png".into(),
            data: png,
        };
        assert!(bag.write(&camera.topic, STAMPS_NS[0], &msg).is_ok());
    }
    assert!(bag.finish().is_ok());
    let frames: Vec<RigFrame> = match RigBagReader::open(&path) {
        Ok(reader) => reader
            .frames()
            .collect::<Result<_, _>>()
            .unwrap_or_default(),
        Err(err) => panic!("{err}"),
    };
    assert_eq!(frames.len(), 1);
    for (c, img) in frames[0].images.iter().enumerate() {
        assert_eq!(img.as_raw(), image(0, c).as_raw());
    }
    assert!(frames[0].ground_truth.is_none());
}

#[test]
fn full_size_frames_round_trip_with_timing() {
    // Four 1024x512 panoramas and a 1024x512 ground truth per frame, as the node sees them.
    const FULL_WIDTH: u32 = 1024;
    const FULL_HEIGHT: u32 = 512;
    const FRAMES: u64 = 3;
    let yaml = match std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/launch_configs/rig_deep360.yaml"
    )) {
        Ok(yaml) => yaml,
        Err(err) => panic!("{err}"),
    };
    let deep360 = match Rig::from_yaml_str(&yaml, "rig_deep360.yaml") {
        Ok(rig) => rig,
        Err(err) => panic!("{err}"),
    };
    let make_frame = |f: u64| RigFrame {
        stamp_ns: STAMPS_NS[0] + f * 50_000_000,
        images: (0..deep360.cameras.len() as u32)
            .map(|c| {
                RgbImage::from_fn(FULL_WIDTH, FULL_HEIGHT, |u, v| {
                    let x = u ^ (v * 3) ^ (c * 77) ^ (f as u32 * 5);
                    ::image::Rgb([x as u8, (x >> 3) as u8, (u + v) as u8])
                })
            })
            .collect(),
        ground_truth: Some(FloatImage {
            width: FULL_WIDTH as usize,
            height: FULL_HEIGHT as usize,
            data: (0..FULL_WIDTH * FULL_HEIGHT)
                .map(|i| 0.5 + (i % 997) as f32 * 0.125 + f as f32)
                .collect(),
        }),
        labels: None,
    };
    let frames: Vec<RigFrame> = (0..FRAMES).map(make_frame).collect();
    let dir = temp_dir();
    let path = dir.path().join("full.mcap");
    let started = std::time::Instant::now();
    let mut writer = match RigBagWriter::create(&path, &deep360, &info()) {
        Ok(w) => w,
        Err(err) => panic!("{err}"),
    };
    for frame in &frames {
        assert!(writer.write_frame(frame).is_ok());
    }
    assert!(writer.finish().is_ok());
    let write_s = started.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);

    let started = std::time::Instant::now();
    let reader = match RigBagReader::open(&path) {
        Ok(reader) => reader,
        Err(err) => panic!("{err}"),
    };
    let read: Vec<RigFrame> = reader
        .frames()
        .collect::<Result<_, _>>()
        .unwrap_or_default();
    let read_s = started.elapsed().as_secs_f64();
    assert_eq!(read.len(), frames.len());
    for (got, want) in read.iter().zip(&frames) {
        assert_eq!(got.stamp_ns, want.stamp_ns);
        for (g, w) in got.images.iter().zip(&want.images) {
            assert!(g.as_raw() == w.as_raw());
        }
        match (&got.ground_truth, &want.ground_truth) {
            (Some(g), Some(w)) => assert!(same_floats(g, w)),
            other => panic!("ground truth mismatch: {other:?}"),
        }
    }
    let mb = bytes as f64 / 1e6;
    println!(
        "{FRAMES} frames, {mb:.1} MB: write {write_s:.3} s ({:.0} MB/s), read+decode {read_s:.3} s ({:.0} MB/s)",
        mb / write_s,
        mb / read_s
    );
}

#[test]
fn tf_static_carries_the_stamp_it_is_given() {
    let rig = mode360::geometry::Rig::from_file(crate::common::RIG_PATH).expect("rig");
    let stamp_ns = 1_764_000_000_123_456_789;
    let at = mode360::bag::rig_tf_static_at(&rig, stamp_ns);
    let plain = mode360::bag::rig_tf_static(&rig);
    assert_eq!(at.transforms.len(), rig.cameras.len());
    for (a, p) in at.transforms.iter().zip(&plain.transforms) {
        assert_eq!(a.header.stamp.to_nanos(), stamp_ns);
        assert_eq!(p.header.stamp.to_nanos(), 0);
        assert_eq!(
            (&a.child_frame_id, &a.transform),
            (&p.child_frame_id, &p.transform)
        );
    }
}

#[test]
fn max_depth_comes_from_the_metadata_and_a_bad_value_is_named() {
    let dir = temp_dir();
    let cases = [
        (None, Ok(DEFAULT_MAX_DEPTH_M)),
        (Some("250"), Ok(250.0)),
        (Some("far"), Err("'far'")),
        (Some("-5"), Err("'-5'")),
    ];
    for (k, (value, expected)) in cases.into_iter().enumerate() {
        let path = dir.path().join(format!("max_depth_{k}.mcap"));
        let mut meta = info();
        if let Some(v) = value {
            meta.insert(MAX_DEPTH_KEY.to_string(), v.to_string());
        }
        let writer = match RigBagWriter::create(&path, &rig(), &meta) {
            Ok(w) => w,
            Err(err) => panic!("{err}"),
        };
        assert!(writer.finish().is_ok());
        let reader = match RigBagReader::open(&path) {
            Ok(r) => r,
            Err(err) => panic!("{err}"),
        };
        match (reader.max_depth_m(), expected) {
            (Ok(m), Ok(want)) => assert_eq!(m, want, "{value:?}"),
            (Err(e), Err(named)) => {
                let text = e.to_string();
                assert!(
                    text.contains(named) && text.contains(MAX_DEPTH_KEY),
                    "{text}"
                );
            }
            (got, want) => panic!("{value:?}: got {got:?}, expected {want:?}"),
        }
    }
}
