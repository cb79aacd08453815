//! Lazy outputs over DDS (loopback, own domain): while nobody subscribes to `points` the node
//! publishes depth but builds no point cloud (counted on its health); once a subscriber
//! matches, clouds arrive with one point per finite depth pixel. `depth/compressedDepth` is
//! likewise encoded only for a subscriber, and decodes to the `depth` of its stamp.

use super::harness::{loopback, render, Cameras};
use crate::common::{reliable_qos, TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::msgs::compressed_depth::{
    decode_compressed_depth, quantization_params, DEFAULT_DEPTH_QUANTIZATION,
};
use mode360::msgs::image::float_from_image_msg;
use mode360::msgs::{CompressedImage, Image, PointCloud2};
use mode360::node::pipeline::is_point_range;
use mode360::node::{create_subscription, dds_context, spawn_node, NodeParams, SpunNode};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 47;
const WIDTH: usize = 64;
const MAX_DEPTH_M: f64 = 1000.0;
const PHASE_TIMEOUT: Duration = Duration::from_secs(20);
const SEND_PERIOD: Duration = Duration::from_millis(200);
const POLL: Duration = Duration::from_millis(20);
const STAMP_STEP_NS: u64 = 100_000_000;
/// Depth images to receive before anybody subscribes to `points`.
const DEPTHS_WITHOUT_POINTS: usize = 3;

#[test]
fn points_are_built_only_while_someone_subscribes() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, 8, WIDTH)?;
    let dds = loopback(DOMAIN_ID);
    let node = spawn_node(
        NodeParams {
            rig_file: RIG_PATH.into(),
            output_width: WIDTH,
            max_depth_m: MAX_DEPTH_M,
            ..Default::default()
        },
        dds.clone(),
    )?;
    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_lazy_client")?;
    let depth_sub = create_subscription::<Image>(&mut client.node, "/depth", reliable_qos())?;
    let mut cameras = Cameras::new(&mut client, &rig, frame, STAMP_STEP_NS)?;
    let mut depths: BTreeMap<u64, Image> = BTreeMap::new();

    // Phase 1: depth only.
    let t0 = Instant::now();
    while depths.len() < DEPTHS_WITHOUT_POINTS && t0.elapsed() < PHASE_TIMEOUT {
        cameras.send_all()?;
        std::thread::sleep(SEND_PERIOD);
        while let Some((m, _)) = depth_sub.take()? {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
    }
    let h = node.health();
    assert!(depths.len() >= DEPTHS_WITHOUT_POINTS, "{h:?}");
    assert!(h.groups_processed >= DEPTHS_WITHOUT_POINTS as u64, "{h:?}");
    assert_eq!(
        h.clouds_skipped, h.groups_processed,
        "a cloud was built with nobody subscribed: {h:?}"
    );

    // Phase 2: a points subscriber appears; clouds come, one point per finite pixel.
    let points_sub =
        create_subscription::<PointCloud2>(&mut client.node, "/points", reliable_qos())?;
    let compressed_sub = create_subscription::<CompressedImage>(
        &mut client.node,
        "/depth/compressedDepth",
        reliable_qos(),
    )?;
    let mut compressed: BTreeMap<u64, CompressedImage> = BTreeMap::new();
    let skipped_before = h.clouds_skipped;
    let t0 = Instant::now();
    let mut cloud: Option<PointCloud2> = None;
    while cloud.is_none() && t0.elapsed() < PHASE_TIMEOUT {
        cameras.send_all()?;
        std::thread::sleep(SEND_PERIOD);
        while let Some((m, _)) = depth_sub.take()? {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
        while let Some((m, _)) = points_sub.take()? {
            cloud = Some(m);
        }
        while let Some((m, _)) = compressed_sub.take()? {
            compressed.insert(m.header.stamp.to_nanos(), m);
        }
    }
    let cloud = cloud.ok_or_else(|| format!("no cloud after subscribing: {:?}", node.health()))?;
    // The depth of the same stamp may still be on its way.
    let t0 = Instant::now();
    let cloud_stamp = cloud.header.stamp.to_nanos();
    while !depths.contains_key(&cloud_stamp) && t0.elapsed() < PHASE_TIMEOUT {
        while let Some((m, _)) = depth_sub.take()? {
            depths.insert(m.header.stamp.to_nanos(), m);
        }
        std::thread::sleep(POLL);
    }
    let range = float_from_image_msg(depths.get(&cloud_stamp).ok_or("no depth for the cloud")?)?;
    let wanted = range
        .data
        .iter()
        .filter(|&&r| is_point_range(r, MAX_DEPTH_M as f32))
        .count();
    assert!(wanted > 0);
    assert_eq!(cloud.width as usize, wanted);
    // compressedDepth of a stamp decodes to its depth within half a quantization step. Codes
    // are uniform in inverse depth (`a / r + b`), so half a code step away from `r` on the far
    // side is `1 / (1 / r - 1 / (2 a))`: `r^2 / (2 a - r)` further (about `r^2 / (2 a)` near).
    let t0 = Instant::now();
    while !compressed.contains_key(&cloud_stamp) && t0.elapsed() < PHASE_TIMEOUT {
        while let Some((m, _)) = compressed_sub.take()? {
            compressed.insert(m.header.stamp.to_nanos(), m);
        }
        std::thread::sleep(POLL);
    }
    let decoded = decode_compressed_depth(
        compressed
            .get(&cloud_stamp)
            .ok_or("no compressedDepth for the cloud's stamp")?,
    )?;
    let (a, _) = quantization_params(DEFAULT_DEPTH_QUANTIZATION, MAX_DEPTH_M as f32);
    let mut compared = 0;
    for (&d, &r) in decoded.data.iter().zip(&range.data) {
        if is_point_range(r, MAX_DEPTH_M as f32) {
            assert!(
                (d - r).abs() <= r * r / (2.0 * a - r) * 1.001 + 1e-4,
                "{d} vs {r}"
            );
            compared += 1;
        } else {
            assert!(d.is_nan(), "{d} where depth is {r}");
        }
    }
    assert_eq!(compared, wanted);
    drop(compressed_sub);
    let h = node.health();
    assert!(h.groups_processed > h.clouds_skipped, "{h:?}");
    assert!(h.clouds_skipped >= skipped_before);
    drop(cameras);
    drop(depth_sub);
    drop(points_sub);
    client.stop()?;
    node.shutdown()?;
    Ok(())
}
