//! QoS overrides and `publish_tf` over DDS (loopback, own domain): the node's camera 1
//! subscription overridden to reliable (`qos_overrides./cam1/image_raw.subscription.
//! reliability: reliable`) no longer matches a best-effort camera publisher but matches a
//! reliable one, while the other cameras keep the best-effort default; with
//! `publish_tf: false` no `/tf_static` reaches a latched subscriber.

use super::harness::loopback;
use crate::common::{TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::msgs::{Image, TFMessage};
use mode360::node::params::NodeParams;
use mode360::node::{
    create_publisher, create_subscription, dds_context, latched_qos, sensor_qos, spawn_node,
    SpunNode,
};
use ros2_client::QosProfile;
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 48;
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a latched `/tf_static` would take to arrive if it were published.
const TF_WAIT: Duration = Duration::from_secs(2);
const POLL: Duration = Duration::from_millis(20);

#[test]
fn camera_qos_override_and_publish_tf_off_are_seen_on_dds() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let mut params = NodeParams::from_args(&[
        "--ros-args".to_string(),
        "-p".into(),
        format!(
            "qos_overrides.{}.subscription.reliability:=reliable",
            rig.cameras[0].topic
        ),
        "-p".into(),
        "publish_tf:=false".into(),
    ])?;
    params.rig_file = RIG_PATH.into();
    params.output_width = 64;
    let dds = loopback(DOMAIN_ID);
    let node = spawn_node(params, dds.clone())?;
    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_qos_client")?;
    let tf_sub = create_subscription::<TFMessage>(&mut client.node, "/tf_static", latched_qos())?;
    // Best-effort publishers for every camera, and a reliable one for camera 1.
    let best_effort = rig
        .cameras
        .iter()
        .map(|c| create_publisher::<Image>(&mut client.node, &c.topic, sensor_qos()))
        .collect::<Result<Vec<_>, _>>()?;
    let reliable = create_publisher::<Image>(
        &mut client.node,
        &rig.cameras[0].topic,
        QosProfile::publisher_default(),
    )?;
    let t0 = Instant::now();
    let matched = |p: &ros2_client::Publisher<Image>| p.get_subscription_count(&client.node);
    while (best_effort[1..].iter().any(|p| matched(p) == 0) || matched(&reliable) == 0)
        && t0.elapsed() < DISCOVERY_TIMEOUT
    {
        std::thread::sleep(POLL);
    }
    assert_eq!(
        matched(&reliable),
        1,
        "the reliable camera 1 publisher did not match"
    );
    for (i, p) in best_effort.iter().enumerate().skip(1) {
        assert_eq!(matched(p), 1, "best-effort camera {} did not match", i + 1);
    }
    assert_eq!(
        matched(&best_effort[0]),
        0,
        "a best-effort publisher matched the reliable camera 1 subscription"
    );
    let t0 = Instant::now();
    let mut tf_messages = 0;
    while t0.elapsed() < TF_WAIT {
        while tf_sub.take()?.is_some() {
            tf_messages += 1;
        }
        std::thread::sleep(POLL);
    }
    assert_eq!(tf_messages, 0, "/tf_static arrived with publish_tf: false");
    drop(best_effort);
    drop(reliable);
    drop(tf_sub);
    client.stop()?;
    node.shutdown()?;
    Ok(())
}
