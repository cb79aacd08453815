//! Interop with a third-party DDS (Eclipse Cyclone DDS through its Python binding), both ways,
//! over loopback, the node in-process:
//!
//! * `cyclone_subscriber_decodes_depth_and_points` (domain 43): we publish camera images with
//!   ros2-client; `tests/interop/cyclone_peer.py subscribe` receives the node's `depth` and
//!   `points` with its own IDL types and reports what it decoded; it must equal what our own
//!   subscriber received, and its points must be range x ERP direction.
//! * `cyclone_publisher_feeds_the_node` (domain 44): `cyclone_peer.py publish` sends rendered
//!   rgb8 camera images; the node's `depth` must carry the Cyclone stamps and match the
//!   ground truth.
//!
//! Needs `MODE360_PYTHON`: a Python with `cyclonedds` (`tests/interop/setup.sh DIR` makes one).
//! Without it the tests are skipped, unless `CI` is set, where they fail.

use super::harness::{assert_peer_decoded, json_u64, loopback, wait_for, Peer};
use crate::common::reliable_qos;
use crate::common::PYTHON_ENV;
use crate::common::{TestResult, RIG_PATH};
use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use mode360::metrics::depth_metrics;
use mode360::msgs::image::{float_from_image_msg, image_msg_from_rgb};
use mode360::msgs::{Header, Image, PointCloud2};
use mode360::node::{create_publisher, create_subscription, dds_context, sensor_qos, SpunNode};
use mode360::node::{spawn_node, NodeParams};
use mode360::synth::{SynthConfig, SynthRenderer};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const PEER_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/interop/cyclone_peer.py");
const PEER_NAME: &str = "cyclone_peer.py";
/// Domain of the Cyclone-subscriber test (unique among the test files).
const SUBSCRIBER_DOMAIN_ID: u16 = 43;
/// Domain of the Cyclone-publisher test (unique among the test files).
const PUBLISHER_DOMAIN_ID: u16 = 44;
const WIDTH: usize = 128;
const MAX_DEPTH_M: f64 = 1000.0;
const SEED: u64 = 3;
/// Frames the Cyclone publisher sends.
const FRAMES: usize = 2;
/// Lowest acceptable delta1 (%) of a depth image on these frames (as tests/node_dds.rs).
const MIN_DELTA1_PCT: f64 = 55.0;
/// Largest difference between a decoded point and range x direction (float32 rounding of
/// coordinates up to the 1000 m sky is about 1e-4 m).
const MAX_XYZ_ERROR_M: f64 = 1e-3;
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(20);
/// How long one published group may take to come back as depth before it is sent again.
const ROUND_TRIP_TIMEOUT: Duration = Duration::from_secs(8);
const TEST_TIMEOUT: Duration = Duration::from_secs(45);
const SEND_ATTEMPTS: usize = 3;

/// The Python with `cyclonedds`, or `None` after printing why the test is skipped (panics
/// under CI).
fn cyclone_python() -> Option<String> {
    let python = std::env::var(PYTHON_ENV).ok().filter(|p| !p.is_empty());
    let problem = match &python {
        None => format!("{PYTHON_ENV} is not set"),
        Some(p) => match Command::new(p)
            .args(["-c", "import cyclonedds"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
        {
            Ok(s) if s.success() => return python,
            Ok(s) => format!("{PYTHON_ENV}={p} cannot import cyclonedds ({s})"),
            Err(e) => format!("{PYTHON_ENV}={p} does not run: {e}"),
        },
    };
    let hint = format!(
        "skipped Cyclone DDS interop: {problem}; set {PYTHON_ENV}=<python with cyclonedds> \
         (tests/interop/setup.sh DIR makes one)"
    );
    assert!(std::env::var_os("CI").is_none(), "CI is set: {hint}");
    println!("{hint}");
    None
}

fn node_params() -> NodeParams {
    NodeParams {
        rig_file: RIG_PATH.into(),
        output_width: WIDTH,
        max_depth_m: MAX_DEPTH_M,
        camera_timeout_s: 30.0,
        ..Default::default()
    }
}

fn render(rig: &Rig, frames: usize) -> Result<Vec<RigFrame>, Box<dyn std::error::Error>> {
    let renderer = SynthRenderer::new(SynthConfig {
        seed: SEED,
        width: WIDTH,
        max_depth_m: MAX_DEPTH_M,
        ..Default::default()
    })?;
    Ok((0..frames).map(|k| renderer.render_frame(rig, k)).collect())
}

#[test]
fn cyclone_subscriber_decodes_depth_and_points() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let Some(python) = cyclone_python() else {
        return Ok(());
    };
    let t_start = Instant::now();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, 1)?.remove(0);
    let dds = loopback(SUBSCRIBER_DOMAIN_ID);
    let node = spawn_node(node_params(), dds.clone())?;

    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_cyclone_sub_client")?;
    let depth_sub = create_subscription::<Image>(&mut client.node, "/depth", reliable_qos())?;
    let points_sub =
        create_subscription::<PointCloud2>(&mut client.node, "/points", reliable_qos())?;
    let pubs = rig
        .cameras
        .iter()
        .map(|c| create_publisher::<Image>(&mut client.node, &c.topic, sensor_qos()))
        .collect::<Result<Vec<_>, _>>()?;

    let peer = Peer::start(
        PEER_NAME,
        &python,
        &[
            PEER_SCRIPT.into(),
            "subscribe".into(),
            "--domain".into(),
            SUBSCRIBER_DOMAIN_ID.to_string(),
            "--max-depth-m".into(),
            MAX_DEPTH_M.to_string(),
            "--timeout-s".into(),
            TEST_TIMEOUT.as_secs().to_string(),
        ],
    )?;
    peer.expect_line("ready", DISCOVERY_TIMEOUT)?;
    let matched = wait_for(DISCOVERY_TIMEOUT, || {
        pubs.iter()
            .all(|p| p.get_subscription_count(&client.node) > 0)
            && depth_sub.get_publisher_count(&client.node) > 0
            && points_sub.get_publisher_count(&client.node) > 0
    });
    assert!(
        matched,
        "our client did not match the node within {DISCOVERY_TIMEOUT:?}"
    );
    eprintln!("[{:?}] discovery done", t_start.elapsed());

    // Publish groups (new stamp each time) until the Cyclone peer reports a decoded pair.
    let mut sent_stamps = Vec::new();
    let mut result = None;
    for attempt in 0..SEND_ATTEMPTS {
        let stamp = frame.stamp_ns + attempt as u64 * 1_000_000;
        for (i, p) in pubs.iter().enumerate() {
            let msg = image_msg_from_rgb(
                Header::new(stamp, &rig.cameras[i].frame_id),
                &frame.images[i],
            );
            p.publish(msg).map_err(|e| format!("{e:?}"))?;
        }
        sent_stamps.push(stamp);
        if let Some(line) = peer.next_line(ROUND_TRIP_TIMEOUT)? {
            result = Some(
                line.strip_prefix("result ")
                    .ok_or(format!("cyclone_peer.py said '{line}'"))?
                    .to_string(),
            );
            break;
        }
    }
    let result: Value = serde_json::from_str(&result.ok_or_else(|| {
        format!(
            "Cyclone subscriber got nothing for stamps {sent_stamps:?}; node health {:?}",
            node.health()
        )
    })?)?;
    eprintln!("[{:?}] cyclone result: {result}", t_start.elapsed());
    peer.finish(Duration::from_secs(10))?;

    // What our own subscriber received for the same stamp.
    let stamp = json_u64(&result, "/depth/stamp_ns")?;
    assert!(
        sent_stamps.contains(&stamp),
        "{stamp} not in {sent_stamps:?}"
    );
    assert_eq!(json_u64(&result, "/points/stamp_ns")?, stamp);
    let mut depths: BTreeMap<u64, Image> = BTreeMap::new();
    let mut clouds: BTreeMap<u64, PointCloud2> = BTreeMap::new();
    let got_both = wait_for(ROUND_TRIP_TIMEOUT, || {
        while let Ok(Some((m, _))) = depth_sub.take() {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
        while let Ok(Some((m, _))) = points_sub.take() {
            clouds.insert(m.header.stamp.to_nanos(), m);
        }
        depths.contains_key(&stamp) && clouds.contains_key(&stamp)
    });
    assert!(got_both, "our subscriber did not receive stamp {stamp}");
    let decoded = assert_peer_decoded(
        &result,
        &depths[&stamp],
        &clouds[&stamp],
        &rig.output_frame_id,
        MAX_DEPTH_M,
        MAX_XYZ_ERROR_M,
    )?;
    println!(
        "cyclone decoded {}x{} depth, {} finite ranges, {} points, max xyz error {} m",
        WIDTH,
        WIDTH / 2,
        decoded.finite_ranges,
        decoded.points,
        decoded.max_xyz_error_m
    );

    drop(pubs);
    drop(depth_sub);
    drop(points_sub);
    client.stop()?;
    let health = node.shutdown()?;
    assert!(health.groups_processed >= 1);
    assert!(
        health.cameras.iter().all(|c| c.bad_messages == 0),
        "{health:?}"
    );
    eprintln!("[{:?}] done", t_start.elapsed());
    Ok(())
}

/// Writes each camera image of `frames` as raw rgb8 and the publisher's frames.json.
fn write_frames(
    rig: &Rig,
    frames: &[RigFrame],
    dir: &Path,
) -> Result<PathBuf, Box<dyn std::error::Error>> {
    let mut spec_frames = Vec::new();
    for (k, frame) in frames.iter().enumerate() {
        let mut files = Vec::new();
        for (i, img) in frame.images.iter().enumerate() {
            let path = dir.join(format!("frame{k}_cam{i}.rgb"));
            std::fs::write(&path, img.as_raw())?;
            files.push(path.display().to_string());
        }
        spec_frames.push(serde_json::json!({
            "stamp_ns": frame.stamp_ns.to_string(),
            "files": files,
        }));
    }
    let spec = serde_json::json!({
        "width": WIDTH,
        "height": WIDTH / 2,
        "cameras": rig.cameras.iter().map(|c| serde_json::json!({
            "topic": c.topic,
            "frame_id": c.frame_id,
        })).collect::<Vec<_>>(),
        "frames": spec_frames,
    });
    let path = dir.join("frames.json");
    std::fs::write(&path, spec.to_string())?;
    Ok(path)
}

#[test]
fn cyclone_publisher_feeds_the_node() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let Some(python) = cyclone_python() else {
        return Ok(());
    };
    let t_start = Instant::now();
    let rig = Rig::from_file(RIG_PATH)?;
    let frames = render(&rig, FRAMES)?;
    let dir = tempfile::tempdir()?;
    let spec = write_frames(&rig, &frames, dir.path())?;
    let dds = loopback(PUBLISHER_DOMAIN_ID);
    let node = spawn_node(node_params(), dds.clone())?;
    let context = dds_context(&dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_cyclone_pub_listener")?;
    let depth_sub = create_subscription::<Image>(&mut listener.node, "/depth", reliable_qos())?;
    let matched = wait_for(DISCOVERY_TIMEOUT, || {
        depth_sub.get_publisher_count(&listener.node) > 0
    });
    assert!(matched, "listener did not match the node's depth");

    let mut peer = Peer::start(
        PEER_NAME,
        &python,
        &[
            PEER_SCRIPT.into(),
            "publish".into(),
            "--domain".into(),
            PUBLISHER_DOMAIN_ID.to_string(),
            "--frames".into(),
            spec.display().to_string(),
            "--timeout-s".into(),
            DISCOVERY_TIMEOUT.as_secs().to_string(),
        ],
    )?;
    peer.expect_line("ready", DISCOVERY_TIMEOUT)?;
    eprintln!("[{:?}] cyclone publisher matched", t_start.elapsed());

    // Lockstep: one frame at a time, sent again (same stamp) if its depth does not come back.
    let mut answered: BTreeMap<u64, Image> = BTreeMap::new();
    for (k, frame) in frames.iter().enumerate() {
        let mut depth = None;
        for _ in 0..SEND_ATTEMPTS {
            peer.send(&format!("publish {k}"))?;
            let said = peer.expect_line("published", ROUND_TRIP_TIMEOUT)?;
            assert_eq!(said, format!("{k} {}", frame.stamp_ns));
            let mut got = None;
            wait_for(ROUND_TRIP_TIMEOUT, || {
                while let Ok(Some((m, _))) = depth_sub.take() {
                    if m.header.stamp.to_nanos() == frame.stamp_ns {
                        got = Some(m);
                    } else {
                        answered.insert(m.header.stamp.to_nanos(), m);
                    }
                }
                got.is_some()
            });
            if got.is_some() {
                depth = got;
                break;
            }
        }
        let depth = depth.ok_or_else(|| {
            format!(
                "no depth for Cyclone frame {k} (stamp {}); node health {:?}",
                frame.stamp_ns,
                node.health()
            )
        })?;
        answered.insert(frame.stamp_ns, depth);
    }
    peer.send("quit")?;
    peer.finish(Duration::from_secs(10))?;
    eprintln!("[{:?}] all frames answered", t_start.elapsed());

    let published: Vec<u64> = frames.iter().map(|f| f.stamp_ns).collect();
    assert_eq!(answered.keys().copied().collect::<Vec<_>>(), published);
    for frame in &frames {
        let depth = &answered[&frame.stamp_ns];
        assert_eq!(depth.header.frame_id, rig.output_frame_id);
        let range = float_from_image_msg(depth)?;
        assert_eq!((range.width, range.height), (WIDTH, WIDTH / 2));
        let gt = frame
            .ground_truth
            .as_ref()
            .ok_or("frame without ground truth")?;
        let m = depth_metrics(&range.data, &gt.data, MAX_DEPTH_M)?;
        println!(
            "Cyclone frame stamp {}: delta1 {:.2}%, AbsRel {:.3}",
            frame.stamp_ns, m.delta1_pct, m.abs_rel
        );
        assert!(m.delta1_pct >= MIN_DELTA1_PCT, "{m:?}");
    }

    drop(depth_sub);
    listener.stop()?;
    let health = node.shutdown()?;
    for cam in &health.cameras {
        assert!(cam.received >= FRAMES as u64, "{health:?}");
        assert_eq!(cam.bad_messages, 0, "{health:?}");
    }
    eprintln!("[{:?}] done", t_start.elapsed());
    Ok(())
}
