//! Interop with eProsima Fast DDS, the default middleware of ROS 2 Humble and Jazzy, both ways,
//! over loopback, the node in-process. The peer (`tests/interop/fastdds/fastdds_peer.cpp`,
//! types from fastddsgen) keeps Fast DDS's default participant QoS, so its builtin transports
//! (shared memory plus UDPv4) as in a stock ROS 2 install; RustDDS speaks UDP only, so the two
//! must settle on UDP.
//!
//! * `fastdds_subscriber_decodes_depth_and_points` (domain 51): we publish camera images with
//!   ros2-client; `fastdds_peer subscribe` receives the node's `depth` and `points` with its
//!   own types and reports what it decoded; it must equal what our own subscriber received,
//!   and its points must be range x ERP direction.
//! * `fastdds_publisher_feeds_the_node` (domain 52): `fastdds_peer publish` sends rendered rgb8
//!   camera images; the node's `depth` must carry the Fast DDS stamps and match the ground
//!   truth.
//!
//! Needs `MODE360_FASTDDS_PEER`: the built peer (`tests/interop/setup.sh DIR` builds it from
//! Debian's `libfastrtps-dev` and `fastddsgen`). Without it the tests are skipped, unless `CI`
//! is set, where they fail.

use super::harness::{assert_peer_decoded, json_u64, loopback, wait_for, Peer};
use crate::common::{reliable_qos, tool_from_env, TestResult, RIG_PATH};
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
use std::path::Path;
use std::time::{Duration, Instant};

/// The built Fast DDS peer (`tests/interop/setup.sh` prints its path).
const PEER_ENV: &str = "MODE360_FASTDDS_PEER";
const PEER_NAME: &str = "fastdds_peer";
/// What the peer reports of its participant when it keeps Fast DDS's default transports.
const DEFAULT_TRANSPORTS: &str = "builtin_transports=1 user_transports=0";
/// Domain of the Fast DDS subscriber test (unique among the test files).
const SUBSCRIBER_DOMAIN_ID: u16 = 51;
/// Domain of the Fast DDS publisher test (unique among the test files).
const PUBLISHER_DOMAIN_ID: u16 = 52;
const WIDTH: usize = 128;
const MAX_DEPTH_M: f64 = 1000.0;
const SEED: u64 = 3;
/// Frames the Fast DDS publisher sends.
const FRAMES: usize = 2;
/// Lowest acceptable delta1 (%) of a depth image on these frames (as the Cyclone test).
const MIN_DELTA1_PCT: f64 = 55.0;
/// Largest difference between a decoded point and range x direction (float32 rounding of
/// coordinates up to the 1000 m sky is about 1e-4 m).
const MAX_XYZ_ERROR_M: f64 = 1e-3;
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(20);
/// How long one published group may take to come back as depth before it is sent again.
const ROUND_TRIP_TIMEOUT: Duration = Duration::from_secs(8);
const TEST_TIMEOUT: Duration = Duration::from_secs(45);
const SEND_ATTEMPTS: usize = 3;

/// The peer's path, or `None` after printing why the test is skipped (panics under CI).
fn fastdds_peer() -> Option<String> {
    tool_from_env(
        PEER_ENV,
        "Fast DDS interop",
        &format!(
            "set {PEER_ENV} to the Fast DDS peer (tests/interop/setup.sh DIR builds it; needs \
             Debian's libfastrtps-dev and fastddsgen)"
        ),
    )
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
fn fastdds_subscriber_decodes_depth_and_points() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let Some(peer_path) = fastdds_peer() else {
        return Ok(());
    };
    let t_start = Instant::now();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, 1)?.remove(0);
    let dds = loopback(SUBSCRIBER_DOMAIN_ID);
    let node = spawn_node(node_params(), dds.clone())?;

    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_fastdds_sub_client")?;
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
        &peer_path,
        &[
            "subscribe".into(),
            "--domain".into(),
            SUBSCRIBER_DOMAIN_ID.to_string(),
            "--max-depth-m".into(),
            MAX_DEPTH_M.to_string(),
            "--timeout-s".into(),
            TEST_TIMEOUT.as_secs().to_string(),
        ],
    )?;
    let transports = peer.expect_line("ready", DISCOVERY_TIMEOUT)?;
    assert_eq!(transports, DEFAULT_TRANSPORTS);
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

    // Publish groups (new stamp each time) until the Fast DDS peer reports a decoded pair.
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
                    .ok_or(format!("{PEER_NAME} said '{line}'"))?
                    .to_string(),
            );
            break;
        }
    }
    let result: Value = serde_json::from_str(&result.ok_or_else(|| {
        format!(
            "Fast DDS subscriber got nothing for stamps {sent_stamps:?}; node health {:?}",
            node.health()
        )
    })?)?;
    eprintln!("[{:?}] fastdds result: {result}", t_start.elapsed());
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
        "Fast DDS decoded {}x{} depth, {} finite ranges, {} points, max xyz error {} m",
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

/// Writes each camera image of `frames` as raw rgb8 into `dir`; per frame, the peer's
/// `publish K STAMP_NS FILE...` command.
fn write_frames(
    frames: &[RigFrame],
    dir: &Path,
) -> Result<Vec<String>, Box<dyn std::error::Error>> {
    let mut commands = Vec::new();
    for (k, frame) in frames.iter().enumerate() {
        let mut command = format!("publish {k} {}", frame.stamp_ns);
        for (i, img) in frame.images.iter().enumerate() {
            let path = dir.join(format!("frame{k}_cam{i}.rgb"));
            std::fs::write(&path, img.as_raw())?;
            let path = path.to_str().ok_or("temporary path is not UTF-8")?;
            if path.contains(char::is_whitespace) {
                return Err(format!("temporary path '{path}' contains white space").into());
            }
            command.push(' ');
            command.push_str(path);
        }
        commands.push(command);
    }
    Ok(commands)
}

#[test]
fn fastdds_publisher_feeds_the_node() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let Some(peer_path) = fastdds_peer() else {
        return Ok(());
    };
    let t_start = Instant::now();
    let rig = Rig::from_file(RIG_PATH)?;
    let frames = render(&rig, FRAMES)?;
    let dir = tempfile::tempdir()?;
    let commands = write_frames(&frames, dir.path())?;
    let dds = loopback(PUBLISHER_DOMAIN_ID);
    let node = spawn_node(node_params(), dds.clone())?;
    let context = dds_context(&dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_fastdds_pub_listener")?;
    let depth_sub = create_subscription::<Image>(&mut listener.node, "/depth", reliable_qos())?;
    let matched = wait_for(DISCOVERY_TIMEOUT, || {
        depth_sub.get_publisher_count(&listener.node) > 0
    });
    assert!(matched, "listener did not match the node's depth");

    let mut args = vec![
        "publish".to_string(),
        "--domain".into(),
        PUBLISHER_DOMAIN_ID.to_string(),
        "--width".into(),
        WIDTH.to_string(),
        "--height".into(),
        (WIDTH / 2).to_string(),
        "--timeout-s".into(),
        DISCOVERY_TIMEOUT.as_secs().to_string(),
    ];
    for cam in &rig.cameras {
        args.extend(["--camera".into(), cam.topic.clone(), cam.frame_id.clone()]);
    }
    let mut peer = Peer::start(PEER_NAME, &peer_path, &args)?;
    let transports = peer.expect_line("ready", DISCOVERY_TIMEOUT)?;
    assert_eq!(transports, DEFAULT_TRANSPORTS);
    eprintln!("[{:?}] fastdds publisher matched", t_start.elapsed());

    // Lockstep: one frame at a time, sent again (same stamp) if its depth does not come back.
    let mut answered: BTreeMap<u64, Image> = BTreeMap::new();
    for (k, (frame, command)) in frames.iter().zip(&commands).enumerate() {
        let mut depth = None;
        for _ in 0..SEND_ATTEMPTS {
            peer.send(command)?;
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
                "no depth for Fast DDS frame {k} (stamp {}); node health {:?}",
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
            "Fast DDS frame stamp {}: delta1 {:.2}%, AbsRel {:.3}",
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
