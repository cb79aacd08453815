//! Camera dropout over DDS (loopback, own domain): a camera that falls silent is timed out,
//! the node keeps publishing from the other three, and takes the camera back when it returns.

use super::harness::{loopback, render, Cameras};
use crate::common::{TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::msgs::Image;
use mode360::node::{create_subscription, dds_context, spawn_node, NodeParams, SpunNode};
use ros2_client::qos::History;
use ros2_client::QosProfile;
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 42;
const WIDTH: usize = 64;
const CAMERA_TIMEOUT_S: f64 = 0.5;
const PHASE_TIMEOUT: Duration = Duration::from_secs(20);
const SEND_PERIOD: Duration = Duration::from_millis(200);
const STAMP_STEP_NS: u64 = 10_000_000;
const DROPPED_CAMERA: usize = 3;

#[test]
fn silent_camera_is_timed_out_and_taken_back() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, 5, WIDTH)?;
    let dds = loopback(DOMAIN_ID);
    let node = spawn_node(
        NodeParams {
            rig_file: RIG_PATH.into(),
            output_width: WIDTH,
            camera_timeout_s: CAMERA_TIMEOUT_S,
            ..Default::default()
        },
        dds.clone(),
    )?;
    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_dropout_client")?;
    let depth_sub = create_subscription::<Image>(
        &mut client.node,
        "/depth",
        QosProfile::publisher_default().history(History::KeepLast { depth: 10 }),
    )?;
    let mut cameras = Cameras::new(&mut client, &rig, frame, STAMP_STEP_NS)?;
    // Phase 1: three cameras only; after the timeout the node publishes without cam4.
    let three: Vec<usize> = (0..rig.cameras.len())
        .filter(|&i| i != DROPPED_CAMERA)
        .collect();
    let mut got_degraded = false;
    let t0 = Instant::now();
    while !got_degraded && t0.elapsed() < PHASE_TIMEOUT {
        let sent = cameras.send(&three)?;
        std::thread::sleep(SEND_PERIOD);
        while let Some((m, _)) = depth_sub.take()? {
            got_degraded |= m.header.stamp.to_nanos() <= sent;
        }
    }
    let h = node.health();
    assert!(got_degraded, "no depth without the silent camera: {h:?}");
    assert!(!h.cameras[DROPPED_CAMERA].active);
    assert!(h.cameras[..DROPPED_CAMERA].iter().all(|c| c.active));
    // Phase 2: all four again; the camera is taken back.
    let t0 = Instant::now();
    while !node.health().cameras[DROPPED_CAMERA].active && t0.elapsed() < PHASE_TIMEOUT {
        cameras.send_all()?;
        std::thread::sleep(SEND_PERIOD);
    }
    let h = node.health();
    assert!(h.cameras[DROPPED_CAMERA].active, "{h:?}");
    assert!(h.cameras[DROPPED_CAMERA].received >= 1);
    drop(cameras);
    drop(depth_sub);
    client.stop()?;
    let final_health = node.shutdown()?;
    assert!(final_health.groups_processed >= 1);
    Ok(())
}
