//! The live view without ROS (domain 53 for the cameras): the node with `foxglove_port` set
//! serves a Foxglove WebSocket; `tests/interop/foxglove_client.mjs`, Foxglove's own client
//! (`@foxglove/ws-protocol` over `ws`) and decoders (`@foxglove/rosmsg2-serialization`),
//! subscribes to `/depth`, `/points`, `/tf_static` and a camera and reports what it decoded.
//!
//! Checked: the depth it decoded is byte for byte the `depth` of the same stamp on DDS, and
//! scores against the ground truth like the DDS tests; its cloud has one point per point
//! range of that depth, each at range x ERP direction, built although nobody subscribes to
//! `points` on DDS (the lazy output follows the live view's subscribers too); the camera
//! image is the one we sent; the transforms are the rig's.
//!
//! Needs `MODE360_NODE_DIR` (`tests/interop/setup.sh DIR`); skipped without it, unless `CI`
//! is set, where it fails.

use super::harness::{fnv1a64, json_at, json_str, json_u64, loopback, render, Cameras};
use crate::common::{reliable_qos, tool_from_env, TestResult, NODE_DIR_ENV, RIG_PATH};
use mode360::bag::rig_tf_static;
use mode360::geometry::Rig;
use mode360::metrics::depth_metrics;
use mode360::msgs::image::float_from_image_msg;
use mode360::msgs::Image;
use mode360::node::pipeline::{POINT_FIELD_NAMES, POINT_STEP_BYTES};
use mode360::node::{
    create_subscription, dds_context, resolve_topic, spawn_node, NodeParams, SpunNode,
    CONFIDENCE_TOPIC, DEPTH_TOPIC, DIAGNOSTICS_TOPIC, POINTS_TOPIC, TF_STATIC_TOPIC,
};
use serde_json::Value;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::net::{Ipv4Addr, TcpListener};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 53;
const CLIENT_SCRIPT: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/interop/foxglove_client.mjs"
);
const WIDTH: usize = 64;
const MAX_DEPTH_M: f64 = 1000.0;
const SEED: u64 = 5;
const STAMP_STEP_NS: u64 = 100_000_000;
const SEND_PERIOD: Duration = Duration::from_millis(300);
const TEST_TIMEOUT: Duration = Duration::from_secs(60);
const CLIENT_TIMEOUT_S: u64 = 50;
/// Lowest acceptable delta1 (%) of the depth (as the other live-node tests).
const MIN_DELTA1_PCT: f64 = 55.0;
/// Largest difference between a decoded point and range x direction (float32 rounding).
const MAX_XYZ_ERROR_M: f64 = 1e-3;
/// PointCloud2's FLOAT32 datatype.
const FLOAT32: u64 = 7;

/// A free TCP port on loopback (bound, read, released).
fn free_port() -> std::io::Result<u16> {
    Ok(TcpListener::bind((Ipv4Addr::LOCALHOST, 0))?
        .local_addr()?
        .port())
}

#[test]
fn foxglove_client_decodes_depth_points_and_a_camera() -> TestResult {
    let Some(node_dir) = tool_from_env(
        NODE_DIR_ENV,
        "Foxglove live view check",
        &format!("set {NODE_DIR_ENV}=<folder with node_modules> (tests/interop/setup.sh DIR)"),
    ) else {
        return Ok(());
    };
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, SEED, WIDTH)?;
    let ground_truth = frame.ground_truth.clone().ok_or("no ground truth")?;
    let camera_image = frame.images[0].clone();
    let dds = loopback(DOMAIN_ID);
    let node = spawn_node(
        NodeParams {
            rig_file: RIG_PATH.into(),
            output_width: WIDTH,
            max_depth_m: MAX_DEPTH_M,
            foxglove_port: free_port()?,
            ..Default::default()
        },
        dds.clone(),
    )?;
    let port = node.foxglove_port().ok_or("the node has no live view")?;

    let mut client = Command::new("node")
        .arg(CLIENT_SCRIPT)
        .arg(format!("ws://127.0.0.1:{port}"))
        .arg(MAX_DEPTH_M.to_string())
        .arg(&rig.cameras[0].topic)
        .arg(CLIENT_TIMEOUT_S.to_string())
        .env(NODE_DIR_ENV, &node_dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| format!("cannot run node {CLIENT_SCRIPT}: {e}"))?;
    let stdout = client.stdout.take().ok_or("no stdout")?;
    let (lines_tx, lines) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if lines_tx.send(line).is_err() {
                break;
            }
        }
    });
    let first = lines
        .recv_timeout(TEST_TIMEOUT)
        .map_err(|e| format!("the Foxglove client did not subscribe: {e}"))?;
    assert_eq!(first, "subscribed");

    let context = dds_context(&dds)?;
    let mut ros_client = SpunNode::new(&context, "/", "mode360_foxglove_test")?;
    let depth_sub = create_subscription::<Image>(&mut ros_client.node, "/depth", reliable_qos())?;
    let mut cameras = Cameras::new(&mut ros_client, &rig, frame, STAMP_STEP_NS)?;
    let mut depths: BTreeMap<u64, Image> = BTreeMap::new();
    let t0 = Instant::now();
    let result: Value = loop {
        if t0.elapsed() > TEST_TIMEOUT {
            let _ = client.kill();
            return Err(format!("no result from the Foxglove client: {:?}", node.health()).into());
        }
        cameras.send_all()?;
        while let Some((m, _)) = depth_sub.take()? {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
        match lines.recv_timeout(SEND_PERIOD) {
            Ok(line) => break serde_json::from_str(&line)?,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(e) => return Err(format!("the Foxglove client ended: {e}").into()),
        }
    };
    let status = client.wait()?;
    assert!(status.success(), "the Foxglove client exited with {status}");
    let stamp = json_u64(&result, "/depth/stamp_ns")?;
    assert_eq!(json_u64(&result, "/points/stamp_ns")?, stamp);
    let t0 = Instant::now();
    while !depths.contains_key(&stamp) && t0.elapsed() < TEST_TIMEOUT {
        while let Some((m, _)) = depth_sub.take()? {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
        std::thread::sleep(SEND_PERIOD / 10);
    }
    let depth = depths
        .get(&stamp)
        .ok_or("no DDS depth of the live view's stamp")?;
    let range = float_from_image_msg(depth)?;
    let m = depth_metrics(&range.data, &ground_truth.data, MAX_DEPTH_M)?;
    let point_ranges = json_u64(&result, "/depth/point_ranges")?;
    println!(
        "Foxglove client decoded {WIDTH}x{} depth (delta1 {:.1} %), {} points (max xyz error {} m), camera {}",
        WIDTH / 2,
        m.delta1_pct,
        json_u64(&result, "/points/width")?,
        json_at(&result, "/points/max_xyz_error_m")?,
        json_str(&result, "/camera/topic")?,
    );

    // Depth: the same bytes as on DDS, and good depth.
    assert_eq!(json_str(&result, "/depth/fnv1a64")?, fnv1a64(&depth.data));
    assert_eq!(json_str(&result, "/depth/encoding")?, "32FC1");
    assert_eq!(json_str(&result, "/depth/frame_id")?, rig.output_frame_id);
    assert_eq!(json_u64(&result, "/depth/width")?, WIDTH as u64);
    assert_eq!(json_u64(&result, "/depth/height")?, WIDTH as u64 / 2);
    let finite = range.data.iter().filter(|r| r.is_finite()).count() as u64;
    assert_eq!(json_u64(&result, "/depth/finite_ranges")?, finite);
    assert!(m.delta1_pct >= MIN_DELTA1_PCT, "{m:?}");
    // REP 117: the sky is +Inf.
    assert!(json_u64(&result, "/depth/inf_ranges")? > 0);

    // Points: one per point range, at range x direction.
    assert!(point_ranges > (WIDTH * WIDTH / 8) as u64, "{point_ranges}");
    assert_eq!(json_u64(&result, "/points/width")?, point_ranges);
    assert_eq!(json_u64(&result, "/points/checked_points")?, point_ranges);
    assert_eq!(json_u64(&result, "/points/height")?, 1);
    assert_eq!(
        json_u64(&result, "/points/point_step")?,
        u64::from(POINT_STEP_BYTES)
    );
    let fields: Vec<(String, u64, u64, u64)> =
        serde_json::from_value(json_at(&result, "/points/fields")?.clone())?;
    let expected: Vec<(String, u64, u64, u64)> = POINT_FIELD_NAMES
        .iter()
        .enumerate()
        .map(|(k, n)| (n.to_string(), 4 * k as u64, FLOAT32, 1))
        .collect();
    assert_eq!(fields, expected);
    let max_err = json_at(&result, "/points/max_xyz_error_m")?
        .as_f64()
        .ok_or("max_xyz_error_m is not a number")?;
    assert!(max_err < MAX_XYZ_ERROR_M, "points off by {max_err} m");
    // Nobody subscribed to `points` on DDS: the clouds were built for the live view.
    let h = node.health();
    assert!(h.clouds_skipped < h.groups_processed, "{h:?}");

    // The camera image as we sent it.
    assert_eq!(json_str(&result, "/camera/topic")?, rig.cameras[0].topic);
    assert_eq!(json_str(&result, "/camera/encoding")?, "rgb8");
    assert_eq!(json_u64(&result, "/camera/width")?, WIDTH as u64);
    assert_eq!(
        json_str(&result, "/camera/fnv1a64")?,
        fnv1a64(camera_image.as_raw())
    );

    // The rig's transforms, as on DDS.
    let tf = json_at(&result, "/tf_static")?
        .as_array()
        .ok_or("tf_static is not a list")?;
    let expected = rig_tf_static(&rig).transforms;
    assert_eq!(tf.len(), expected.len());
    assert!(tf.len() >= rig.cameras.len());
    for (t, e) in tf.iter().zip(&expected) {
        assert_eq!(json_str(t, "/child")?, e.child_frame_id);
        assert_eq!(json_str(t, "/parent")?, e.header.frame_id);
        let translation: Vec<f64> = serde_json::from_value(json_at(t, "/translation")?.clone())?;
        let want = &e.transform.translation;
        assert_eq!(translation, vec![want.x, want.y, want.z]);
    }

    drop(cameras);
    drop(depth_sub);
    ros_client.stop()?;
    node.shutdown()?;
    Ok(())
}

/// Every topic the shipped Foxglove layout shows is one the live view advertises with the
/// node's defaults and the bundled rig, and it shows a panorama, the colour-mapped depth and
/// the cloud.
#[test]
fn the_foxglove_layout_shows_the_node_topics() -> TestResult {
    let rig = Rig::from_file(RIG_PATH)?;
    let path = crate::common::repo_path("launch_configs/foxglove_layout.json");
    let layout: Value = serde_json::from_str(&std::fs::read_to_string(&path)?)?;
    let mut advertised: Vec<String> = [DEPTH_TOPIC, POINTS_TOPIC, CONFIDENCE_TOPIC]
        .iter()
        .map(|t| resolve_topic("/", t))
        .collect();
    advertised.extend([DIAGNOSTICS_TOPIC.to_string(), TF_STATIC_TOPIC.to_string()]);
    advertised.extend(rig.cameras.iter().map(|c| c.topic.clone()));
    let panels = layout["configById"]
        .as_object()
        .ok_or("the layout has no configById")?;
    let mut image_topics = Vec::new();
    let mut scene_topics = Vec::new();
    for (id, config) in panels {
        if let Some(t) = config
            .pointer("/imageMode/imageTopic")
            .and_then(Value::as_str)
        {
            image_topics.push((t.to_string(), config["imageMode"].clone()));
        }
        if let Some(topics) = config["topics"].as_object() {
            scene_topics.extend(topics.keys().cloned());
            assert_eq!(
                config["followTf"].as_str(),
                Some(rig.rig_frame.as_str()),
                "{id}"
            );
        }
        if let Some(t) = config["topicToRender"].as_str() {
            scene_topics.push(t.to_string());
        }
    }
    for t in image_topics.iter().map(|(t, _)| t).chain(&scene_topics) {
        assert!(
            advertised.contains(t),
            "the layout shows {t}, which the node does not serve"
        );
    }
    let panorama = &rig.cameras[rig.reference].topic;
    assert!(image_topics.iter().any(|(t, _)| t == panorama));
    let (_, depth) = image_topics
        .iter()
        .find(|(t, _)| t == "/depth")
        .ok_or("no depth image panel")?;
    assert_eq!(depth["colorMode"], "colormap");
    assert!(depth["minValue"].as_f64() < depth["maxValue"].as_f64());
    assert!(scene_topics.contains(&"/points".to_string()));
    Ok(())
}
