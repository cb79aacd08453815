//! The third-party DDS tests (`cyclone`, `fastdds`): the check of what a peer decoded of the
//! node's outputs ([`assert_peer_decoded`]), and both tests' flows
//! ([`peer_decodes_depth_and_points`], [`peer_feeds_the_node`]) for a [`DdsPeer`], declared
//! per peer by [`dds_peer_tests`]. The peer process itself is [`Peer`] in `harness`.

use crate::common::{reliable_qos, TestResult, RIG_PATH};
use crate::harness::{fnv1a64, json_str, json_u64, loopback, wait_for, Peer};
use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use mode360::metrics::depth_metrics;
use mode360::msgs::image::{float_from_image_msg, image_msg_from_rgb};
use mode360::msgs::{Header, Image, PointCloud2};
use mode360::node::pipeline::{is_point_range, POINT_FIELD_NAMES, POINT_STEP_BYTES};
use mode360::node::{
    create_publisher, create_subscription, dds_context, sensor_qos, spawn_node, NodeHandle,
    NodeParams, SpunNode,
};
use mode360::synth::{SynthConfig, SynthRenderer};
use ros2_client::Context;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::MutexGuard;
use std::time::{Duration, Instant};

/// What a peer's subscriber decoded of the node's outputs.
#[derive(Debug)]
pub struct DecodedOutputs {
    /// Ranges of the depth image that are finite.
    pub finite_ranges: usize,
    /// Points in the cloud: one per range in (0, max_depth_m).
    pub points: usize,
    /// Largest distance of a decoded x, y or z from range x ERP direction.
    pub max_xyz_error_m: f64,
}

/// Asserts that a peer's `result` JSON (the `summarize` of `tests/interop/cyclone_peer.py`,
/// also written by `fastdds_peer`) describes exactly the `depth` and `cloud` our own
/// subscriber received: headers, sizes, range counts, the bytes' FNV-1a hashes, the point
/// fields, and points within `max_xyz_error_m` of range x direction.
pub fn assert_peer_decoded(
    result: &Value,
    depth: &Image,
    cloud: &PointCloud2,
    output_frame_id: &str,
    max_depth_m: f64,
    max_xyz_error_m: f64,
) -> Result<DecodedOutputs, Box<dyn std::error::Error>> {
    let range = float_from_image_msg(depth)?;
    let (width, height) = (range.width, range.height);
    let finite = range.data.iter().filter(|r| r.is_finite()).count();
    let point_ranges = range
        .data
        .iter()
        .filter(|&&r| is_point_range(r, max_depth_m as f32))
        .count();

    assert_eq!(json_str(result, "/depth/frame_id")?, output_frame_id);
    assert_eq!(json_str(result, "/points/frame_id")?, output_frame_id);
    assert_eq!(json_str(result, "/depth/encoding")?, "32FC1");
    assert_eq!(json_u64(result, "/depth/width")?, width as u64);
    assert_eq!(json_u64(result, "/depth/height")?, height as u64);
    assert_eq!(json_u64(result, "/depth/step")?, 4 * width as u64);
    assert_eq!(json_u64(result, "/depth/finite_ranges")?, finite as u64);
    assert_eq!(
        json_u64(result, "/depth/point_ranges")?,
        point_ranges as u64
    );
    assert!(
        point_ranges > width * height / 4,
        "only {point_ranges} points"
    );
    assert_eq!(json_str(result, "/depth/fnv1a64")?, fnv1a64(&depth.data));
    assert_eq!(json_u64(result, "/points/width")?, cloud.width as u64);
    assert_eq!(cloud.width as usize, point_ranges);
    assert_eq!(json_u64(result, "/points/height")?, 1);
    assert_eq!(
        json_u64(result, "/points/point_step")?,
        u64::from(POINT_STEP_BYTES)
    );
    assert_eq!(
        json_u64(result, "/points/checked_points")?,
        point_ranges as u64
    );
    let fields: Vec<(String, u64, u64, u64)> =
        serde_json::from_value(result["points"]["fields"].clone())?;
    let expected_fields: Vec<(String, u64, u64, u64)> = POINT_FIELD_NAMES
        .iter()
        .enumerate()
        .map(|(k, n)| (n.to_string(), 4 * k as u64, 7, 1))
        .collect();
    assert_eq!(fields, expected_fields);
    let max_err = result["points"]["max_xyz_error_m"]
        .as_f64()
        .ok_or("no max_xyz_error_m")?;
    assert!(max_err < max_xyz_error_m, "points off by {max_err} m");
    assert_eq!(json_str(result, "/points/fnv1a64")?, fnv1a64(&cloud.data));
    Ok(DecodedOutputs {
        finite_ranges: finite,
        points: cloud.width as usize,
        max_xyz_error_m: max_err,
    })
}

/// Output width of the node in the third-party DDS tests (the height is half).
pub const PEER_WIDTH: usize = 128;
/// `max_depth_m` of the node and of the rendering in the third-party DDS tests.
const PEER_MAX_DEPTH_M: f64 = 1000.0;
/// How long discovery between the node, our client and a peer may take.
pub const PEER_DISCOVERY_TIMEOUT: Duration = Duration::from_secs(20);
/// How long a subscribing peer waits for the node's outputs before it gives up.
const PEER_TEST_TIMEOUT: Duration = Duration::from_secs(45);
/// Seed of the street the third-party DDS tests render.
const PEER_SEED: u64 = 3;
/// Frames a publishing peer sends.
const PEER_FRAMES: usize = 2;
/// Lowest acceptable delta1 (%) of a depth image on these frames (as `dds`).
const PEER_MIN_DELTA1_PCT: f64 = 55.0;
/// Largest difference between a decoded point and range x direction (float32 rounding of
/// coordinates up to the 1000 m sky is about 1e-4 m).
const PEER_MAX_XYZ_ERROR_M: f64 = 1e-3;
/// How long one published group may take to come back as depth before it is sent again.
const ROUND_TRIP_TIMEOUT: Duration = Duration::from_secs(8);
const SEND_ATTEMPTS: usize = 3;
const PEER_EXIT_TIMEOUT: Duration = Duration::from_secs(10);

/// What differs between the third-party DDS tests (`cyclone`, `fastdds`): the peer's names,
/// how it is started and how it is told to publish.
pub trait DdsPeer {
    /// How messages name the DDS ("Cyclone", "Fast DDS").
    const LABEL: &'static str;
    /// Lower-case tag of log lines and our client nodes' names ("cyclone", "fastdds").
    const TAG: &'static str;

    /// Starts the peer with `args` (`subscribe ...` or `publish ...`) and waits until it said
    /// `ready`. Subscribing, it then says `result JSON` (see [`assert_peer_decoded`]) once it
    /// decoded a depth image and the cloud of the same stamp.
    fn start(&self, args: &[String]) -> PeerResult<Peer>;

    /// Writes the camera images of `frames` (of `rig`) into `dir`, and says how the peer is
    /// told to publish them.
    fn publishing(&self, rig: &Rig, frames: &[RigFrame], dir: &Path) -> PeerResult<Publishing>;
}

/// A peer's result, errors boxed.
pub type PeerResult<T> = Result<T, Box<dyn std::error::Error>>;

/// How a [`DdsPeer`] is told to publish rendered frames.
pub struct Publishing {
    /// The peer's `publish` arguments besides `--domain` and `--timeout-s`.
    pub args: Vec<String>,
    /// Per frame, the command after which the peer publishes frame K's images under the
    /// frame's stamp and says `published K STAMP_NS`.
    pub commands: Vec<String>,
}

/// The start of both third-party DDS tests: the node (one at a time) on the bundled rig in a
/// loopback domain, and a client node of ours there.
struct PeerTestNode {
    t_start: Instant,
    rig: Rig,
    node: NodeHandle,
    client: SpunNode,
    _context: Context,
    _one_node_at_a_time: MutexGuard<'static, ()>,
}

impl PeerTestNode {
    /// The node and our client `mode360_{P::TAG}_{role}` in `domain_id`, with `peer`; `None`
    /// where `peer` is (the test is skipped).
    fn start<P: DdsPeer>(
        peer: Option<P>,
        domain_id: u16,
        role: &str,
    ) -> PeerResult<Option<(P, Self)>> {
        let Some(peer) = peer else {
            return Ok(None);
        };
        let one_node_at_a_time = crate::common::live_node_lock();
        let t_start = Instant::now();
        let rig = Rig::from_file(RIG_PATH)?;
        let dds = loopback(domain_id);
        let params = NodeParams {
            rig_file: RIG_PATH.into(),
            output_width: PEER_WIDTH,
            max_depth_m: PEER_MAX_DEPTH_M,
            camera_timeout_s: 30.0,
            ..Default::default()
        };
        let node = spawn_node(params, dds.clone())?;
        let context = dds_context(&dds)?;
        let client = SpunNode::new(&context, "/", &format!("mode360_{}_{role}", P::TAG))?;
        let setup = Self {
            t_start,
            rig,
            node,
            client,
            _context: context,
            _one_node_at_a_time: one_node_at_a_time,
        };
        Ok(Some((peer, setup)))
    }
}

/// Frames `0..frames` of the street the third-party DDS tests render.
fn peer_frames(rig: &Rig, frames: usize) -> PeerResult<Vec<RigFrame>> {
    let renderer = SynthRenderer::new(SynthConfig {
        seed: PEER_SEED,
        width: PEER_WIDTH,
        max_depth_m: PEER_MAX_DEPTH_M,
        ..Default::default()
    })?;
    Ok((0..frames).map(|k| renderer.render_frame(rig, k)).collect())
}

/// Writes each camera image of `frames` as raw rgb8 and a publishing peer's frames.json
/// (`cyclone_peer.py publish`, `rclpy_peer.py publish`).
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
        "width": PEER_WIDTH,
        "height": PEER_WIDTH / 2,
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

/// How the Python peers (`cyclone_peer.py`, `rclpy_peer.py`) are told to publish: the frames in
/// `frames.json` (`--frames`, [`write_frames`]), frame K on `publish K`.
pub fn frames_json_publishing(
    rig: &Rig,
    frames: &[RigFrame],
    dir: &Path,
) -> PeerResult<Publishing> {
    let spec = write_frames(rig, frames, dir)?;
    let args = vec!["--frames".into(), spec.display().to_string()];
    let commands = (0..frames.len()).map(|k| format!("publish {k}")).collect();
    Ok(Publishing { args, commands })
}

/// Declares the two tests of a [`DdsPeer`]: `$subscriber_test`
/// ([`peer_decodes_depth_and_points`]) in domain `$subscriber_domain` and `$publisher_test`
/// ([`peer_feeds_the_node`]) in `$publisher_domain`, each with the peer `$peer` makes (an
/// `Option<impl DdsPeer>`, `None` where the tests are skipped).
macro_rules! dds_peer_tests {
    ($peer:expr, $subscriber_test:ident in $subscriber_domain:expr,
     $publisher_test:ident in $publisher_domain:expr $(,)?) => {
        #[test]
        fn $subscriber_test() -> $crate::common::TestResult {
            $crate::dds_peer::peer_decodes_depth_and_points($peer, $subscriber_domain)
        }

        #[test]
        fn $publisher_test() -> $crate::common::TestResult {
            $crate::dds_peer::peer_feeds_the_node($peer, $publisher_domain)
        }
    };
}
pub(crate) use dds_peer_tests;

/// The subscriber test against peer `P` in `domain_id`: we publish camera groups (a new stamp
/// each time) until the peer reports a decoded `depth` and `points` pair, which must equal
/// what our own subscriber received of the same stamp ([`assert_peer_decoded`]).
pub fn peer_decodes_depth_and_points<P: DdsPeer>(peer: Option<P>, domain_id: u16) -> TestResult {
    let Some((peer, mut setup)) = PeerTestNode::start(peer, domain_id, "sub_client")? else {
        return Ok(());
    };
    let (label, tag) = (P::LABEL, P::TAG);
    let (t_start, rig) = (setup.t_start, &setup.rig);
    let frame = peer_frames(rig, 1)?.remove(0);
    let depth_sub = create_subscription::<Image>(&mut setup.client.node, "/depth", reliable_qos())?;
    let points_sub =
        create_subscription::<PointCloud2>(&mut setup.client.node, "/points", reliable_qos())?;
    let pubs = rig
        .cameras
        .iter()
        .map(|c| create_publisher::<Image>(&mut setup.client.node, &c.topic, sensor_qos()))
        .collect::<Result<Vec<_>, _>>()?;

    let peer = peer.start(&[
        "subscribe".into(),
        "--domain".into(),
        domain_id.to_string(),
        "--max-depth-m".into(),
        PEER_MAX_DEPTH_M.to_string(),
        "--timeout-s".into(),
        PEER_TEST_TIMEOUT.as_secs().to_string(),
    ])?;
    let matched = wait_for(PEER_DISCOVERY_TIMEOUT, || {
        pubs.iter()
            .all(|p| p.get_subscription_count(&setup.client.node) > 0)
            && depth_sub.get_publisher_count(&setup.client.node) > 0
            && points_sub.get_publisher_count(&setup.client.node) > 0
    });
    assert!(
        matched,
        "our client did not match the node within {PEER_DISCOVERY_TIMEOUT:?}"
    );
    eprintln!("[{:?}] discovery done", t_start.elapsed());

    // Publish groups (new stamp each time) until the peer reports a decoded pair.
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
        result = peer.next_with("result ", ROUND_TRIP_TIMEOUT)?;
        if result.is_some() {
            break;
        }
    }
    let result: Value = serde_json::from_str(&result.ok_or_else(|| {
        format!(
            "{label} subscriber got nothing for stamps {sent_stamps:?}; node health {:?}",
            setup.node.health()
        )
    })?)?;
    eprintln!("[{:?}] {tag} result: {result}", t_start.elapsed());
    peer.finish(PEER_EXIT_TIMEOUT)?;

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
        PEER_MAX_DEPTH_M,
        PEER_MAX_XYZ_ERROR_M,
    )?;
    println!(
        "{label} decoded {}x{} depth, {} finite ranges, {} points, max xyz error {} m",
        PEER_WIDTH,
        PEER_WIDTH / 2,
        decoded.finite_ranges,
        decoded.points,
        decoded.max_xyz_error_m
    );

    drop(pubs);
    drop(depth_sub);
    drop(points_sub);
    setup.client.stop()?;
    let health = setup.node.shutdown()?;
    assert!(health.groups_processed >= 1);
    assert!(
        health.cameras.iter().all(|c| c.bad_messages == 0),
        "{health:?}"
    );
    eprintln!("[{:?}] done", t_start.elapsed());
    Ok(())
}

/// The publisher test against peer `P` in `domain_id`: the peer publishes rendered frames in
/// lockstep (a frame again, same stamp, if its depth does not come back); the node's `depth`
/// must carry exactly the peer's stamps and match the ground truth.
pub fn peer_feeds_the_node<P: DdsPeer>(peer: Option<P>, domain_id: u16) -> TestResult {
    let Some((peer, mut setup)) = PeerTestNode::start(peer, domain_id, "pub_listener")? else {
        return Ok(());
    };
    let (label, tag) = (P::LABEL, P::TAG);
    let (t_start, rig) = (setup.t_start, &setup.rig);
    let frames = peer_frames(rig, PEER_FRAMES)?;
    let dir = tempfile::tempdir()?;
    let depth_sub = create_subscription::<Image>(&mut setup.client.node, "/depth", reliable_qos())?;
    let matched = wait_for(PEER_DISCOVERY_TIMEOUT, || {
        depth_sub.get_publisher_count(&setup.client.node) > 0
    });
    assert!(matched, "listener did not match the node's depth");

    let Publishing {
        args: publish_args,
        commands,
    } = peer.publishing(rig, &frames, dir.path())?;
    assert_eq!(commands.len(), frames.len());
    let mut args = vec![
        "publish".to_string(),
        "--domain".into(),
        domain_id.to_string(),
        "--timeout-s".into(),
        PEER_DISCOVERY_TIMEOUT.as_secs().to_string(),
    ];
    args.extend(publish_args);
    let mut peer = peer.start(&args)?;
    eprintln!("[{:?}] {tag} publisher matched", t_start.elapsed());

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
                "no depth for {label} frame {k} (stamp {}); node health {:?}",
                frame.stamp_ns,
                setup.node.health()
            )
        })?;
        answered.insert(frame.stamp_ns, depth);
    }
    peer.send("quit")?;
    peer.finish(PEER_EXIT_TIMEOUT)?;
    eprintln!("[{:?}] all frames answered", t_start.elapsed());

    let published: Vec<u64> = frames.iter().map(|f| f.stamp_ns).collect();
    assert_eq!(answered.keys().copied().collect::<Vec<_>>(), published);
    for frame in &frames {
        let depth = &answered[&frame.stamp_ns];
        assert_eq!(depth.header.frame_id, rig.output_frame_id);
        let range = float_from_image_msg(depth)?;
        assert_eq!((range.width, range.height), (PEER_WIDTH, PEER_WIDTH / 2));
        let gt = frame
            .ground_truth
            .as_ref()
            .ok_or("frame without ground truth")?;
        let m = depth_metrics(&range.data, &gt.data, PEER_MAX_DEPTH_M)?;
        println!(
            "{label} frame stamp {}: delta1 {:.2}%, AbsRel {:.3}",
            frame.stamp_ns, m.delta1_pct, m.abs_rel
        );
        assert!(m.delta1_pct >= PEER_MIN_DELTA1_PCT, "{m:?}");
    }

    drop(depth_sub);
    setup.client.stop()?;
    let health = setup.node.shutdown()?;
    for cam in &health.cameras {
        assert!(cam.received >= PEER_FRAMES as u64, "{health:?}");
        assert_eq!(cam.bad_messages, 0, "{health:?}");
    }
    eprintln!("[{:?}] done", t_start.elapsed());
    Ok(())
}
