//! End to end over DDS (loopback, own domain): the node in-process, a rendered bag played
//! into it, `depth` and `points` received and checked against ground truth; then malformed
//! images are sent and the node must report them and keep publishing for good input.

use super::harness::loopback;
use crate::common::reliable_qos;
use crate::common::{TestResult, RIG_PATH};
use mode360::bag::RigBagReader;
use mode360::geometry::Rig;
use mode360::metrics::depth_metrics;
use mode360::msgs::image::{float_from_image_msg, image_msg_from_rgb};
use mode360::msgs::{Header, Image, PointCloud2};
use mode360::node::pipeline::is_point_range;
use mode360::node::player::{play_bag, PlayOptions};
use mode360::node::{create_publisher, create_subscription, dds_context, sensor_qos, SpunNode};
use mode360::node::{spawn_node, NodeParams};
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::SynthConfig;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 41;
const WIDTH: usize = 128;
const FRAMES: usize = 3;
const MAX_DEPTH_M: f64 = 1000.0;
/// Playback slowed down so that inference keeps up on a busy 2-core machine.
const PLAY_RATE: f64 = 0.25;
/// Lowest acceptable delta1 (%) of a received depth image (replay measures the same
/// estimator on these frames; see tests/replay_bag.rs).
const MIN_DELTA1_PCT: f64 = 55.0;
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(10);
const RECEIVE_TIMEOUT: Duration = Duration::from_secs(30);
const POLL: Duration = Duration::from_millis(20);
/// Stamp offset of the hand-sent messages after the bag (later than every bag stamp).
const LATE_OFFSET_NS: u64 = 100_000_000_000;

#[test]
fn node_publishes_depth_and_points_and_survives_bad_input() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let t_start = Instant::now();
    let dir = tempfile::tempdir()?;
    let bag_path = dir.path().join("in.mcap");
    let rig = Rig::from_file(RIG_PATH)?;
    record_synthetic_bag(&RecordOptions {
        rig: rig.clone(),
        config: SynthConfig {
            seed: 3,
            width: WIDTH,
            max_depth_m: MAX_DEPTH_M,
            ..Default::default()
        },
        frames: FRAMES,
        first_frame: 0,
        out: bag_path.clone(),
        show_progress: false,
    })?;
    let reader = RigBagReader::open(&bag_path)?;
    let frames: Vec<_> = reader.frames().collect::<Result<_, _>>()?;
    let gt_by_stamp: BTreeMap<u64, _> = frames
        .iter()
        .filter_map(|f| Some((f.stamp_ns, f.ground_truth.clone()?)))
        .collect();

    let dds = loopback(DOMAIN_ID);
    let params = NodeParams {
        rig_file: RIG_PATH.into(),
        output_width: WIDTH,
        max_depth_m: MAX_DEPTH_M,
        camera_timeout_s: 30.0,
        ..Default::default()
    };
    let node = spawn_node(params, dds.clone())?;
    eprintln!("[{:?}] spawned", t_start.elapsed());

    // Listener.
    let context = dds_context(&dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_test_listener")?;
    let depth_sub = create_subscription::<Image>(&mut listener.node, "/depth", reliable_qos())?;
    let points_sub =
        create_subscription::<PointCloud2>(&mut listener.node, "/points", reliable_qos())?;

    // Wait until the node's outputs are matched, then play.
    let t0 = Instant::now();
    while (depth_sub.get_publisher_count(&listener.node) == 0
        || points_sub.get_publisher_count(&listener.node) == 0)
        && t0.elapsed() < DISCOVERY_TIMEOUT
    {
        std::thread::sleep(POLL);
    }
    eprintln!("[{:?}] discovery done", t_start.elapsed());
    let played = play_bag(&PlayOptions {
        input: bag_path.clone(),
        rate: PLAY_RATE,
        loops: 1,
        publish_clock: true,
        dds: dds.clone(),
        wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
        wait_topics: rig.cameras.iter().map(|c| c.topic.clone()).collect(),
    })?;
    for cam in &rig.cameras {
        assert_eq!(played.published.get(&cam.topic), Some(&(FRAMES as u64)));
    }

    eprintln!("[{:?}] played", t_start.elapsed());
    // Collect outputs until every played stamp was answered or time runs out (the 1-slot
    // mailbox may drop a group when inference falls behind; at least one must arrive).
    let mut depths: BTreeMap<u64, Image> = BTreeMap::new();
    let mut clouds: BTreeMap<u64, PointCloud2> = BTreeMap::new();
    let t0 = Instant::now();
    while t0.elapsed() < RECEIVE_TIMEOUT
        && (depths.len() < FRAMES || clouds.len() < FRAMES)
        && !(node.health().groups_processed as usize + node.health().groups_dropped as usize
            >= FRAMES
            && depths.len() as u64 >= node.health().groups_processed
            && clouds.len() as u64 >= node.health().groups_processed)
    {
        while let Some((m, _)) = depth_sub.take()? {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
        while let Some((m, _)) = points_sub.take()? {
            clouds.insert(m.header.stamp.to_nanos(), m);
        }
        std::thread::sleep(POLL);
    }
    let health = node.health();
    println!(
        "received {} depth, {} points; processed {}, dropped {}, latency {:?} ms",
        depths.len(),
        clouds.len(),
        health.groups_processed,
        health.groups_dropped,
        health.mean_latency_ms
    );
    assert!(!depths.is_empty(), "no depth received; health {health:?}");
    let mut clouds_checked = 0;
    for (stamp, depth) in &depths {
        let gt = gt_by_stamp
            .get(stamp)
            .ok_or("depth stamp is not an input stamp")?;
        assert_eq!(depth.header.frame_id, rig.output_frame_id);
        let range = float_from_image_msg(depth)?;
        assert_eq!((range.width, range.height), (WIDTH, WIDTH / 2));
        let m = depth_metrics(&range.data, &gt.data, MAX_DEPTH_M)?;
        println!("stamp {stamp}: delta1 {:.2}%", m.delta1_pct);
        assert!(m.delta1_pct >= MIN_DELTA1_PCT, "{m:?}");
        if let Some(cloud) = clouds.get(stamp) {
            let valid = range
                .data
                .iter()
                .filter(|&&r| is_point_range(r, MAX_DEPTH_M as f32))
                .count();
            assert!(valid > 0, "stamp {stamp}: no depth pixel is a point");
            assert_eq!(cloud.width as usize, valid);
            assert_eq!(cloud.header.frame_id, rig.output_frame_id);
            clouds_checked += 1;
        }
    }
    // every processed group publishes both; at least one pair must have been compared
    assert!(
        clouds_checked > 0,
        "no point cloud matched a depth stamp ({} clouds, {} depths)",
        clouds.len(),
        depths.len()
    );
    for stamp in clouds.keys() {
        assert!(
            depths.contains_key(stamp),
            "cloud stamp {stamp} without depth"
        );
    }

    eprintln!("[{:?}] phase1 checked", t_start.elapsed());
    // Bad input: wrong encoding on cam1, truncated data on cam2, then good groups.
    // Own context: a second node on the listener's context would not see discovery events.
    let sender_context = dds_context(&dds)?;
    let mut sender = SpunNode::new(&sender_context, "/", "mode360_test_sender")?;
    let pubs = rig
        .cameras
        .iter()
        .map(|c| create_publisher::<Image>(&mut sender.node, &c.topic, sensor_qos()))
        .collect::<Result<Vec<_>, _>>()?;
    let t0 = Instant::now();
    while pubs
        .iter()
        .any(|p| p.get_subscription_count(&sender.node) == 0)
        && t0.elapsed() < DISCOVERY_TIMEOUT
    {
        std::thread::sleep(POLL);
    }
    eprintln!("[{:?}] sender matched", t_start.elapsed());
    let frame = &frames[0];
    let late = frame.stamp_ns + LATE_OFFSET_NS;
    let mut wrong = image_msg_from_rgb(
        Header::new(late, &rig.cameras[0].frame_id),
        &frame.images[0],
    );
    wrong.encoding = "16UC1".into();
    let mut truncated = image_msg_from_rgb(
        Header::new(late, &rig.cameras[1].frame_id),
        &frame.images[1],
    );
    truncated.data.truncate(truncated.data.len() / 2);
    pubs[0].publish(wrong).map_err(|e| format!("{e:?}"))?;
    pubs[1].publish(truncated).map_err(|e| format!("{e:?}"))?;
    let mut good_stamp = None;
    let t0 = Instant::now();
    let mut k = 1;
    while good_stamp.is_none() && t0.elapsed() < RECEIVE_TIMEOUT {
        let stamp = late + k * 1_000_000;
        for (i, p) in pubs.iter().enumerate() {
            let msg = image_msg_from_rgb(
                Header::new(stamp, &rig.cameras[i].frame_id),
                &frame.images[i],
            );
            p.publish(msg).map_err(|e| format!("{e:?}"))?;
        }
        let wait = Instant::now();
        while good_stamp.is_none() && wait.elapsed() < Duration::from_secs(3) {
            while let Some((m, _)) = depth_sub.take()? {
                if m.header.stamp.to_nanos() > late {
                    good_stamp = Some((m.header.stamp.to_nanos(), m));
                }
            }
            std::thread::sleep(POLL);
        }
        k += 1;
    }
    let (stamp, depth) = good_stamp.ok_or("no depth for good input after bad messages")?;
    assert!(stamp > late);
    let m = depth_metrics(
        &float_from_image_msg(&depth)?.data,
        &frame.ground_truth.as_ref().ok_or("no gt")?.data,
        MAX_DEPTH_M,
    )?;
    assert!(m.delta1_pct >= MIN_DELTA1_PCT);
    let health = node.health();
    assert!(health.cameras[0].bad_messages >= 1, "{health:?}");
    assert!(health.cameras[1].bad_messages >= 1, "{health:?}");
    let r0 = health.cameras[0]
        .last_bad_reason
        .clone()
        .unwrap_or_default();
    let r1 = health.cameras[1]
        .last_bad_reason
        .clone()
        .unwrap_or_default();
    assert!(r0.contains("16UC1"), "{r0}");
    assert!(r1.contains("bytes"), "{r1}");

    eprintln!("[{:?}] phase2 done", t_start.elapsed());
    drop(pubs);
    sender.stop()?;
    drop(depth_sub);
    drop(points_sub);
    listener.stop()?;
    eprintln!("[{:?}] listener stopped", t_start.elapsed());
    let final_health = node.shutdown()?;
    assert!(final_health.groups_processed >= 2);
    Ok(())
}
