//! `mode360 play` at 512 as `tools/node_rss.sh` and `bench-node` use it: every camera image of
//! a rendered bag (four cameras, ground truth, labels and instances: about 2.6 MB a frame) at
//! the recorded 10 Hz must reach best-effort subscribers whole. RustDDS paces the fragments of
//! large samples (32 KiB/ms by default); a player paced below what its bag needs falls behind
//! and its writers' history drops images (with `MODE360_DDS_PACE_KIB_PER_MS=16` this test gets
//! 7 of 160). The node at 512 lost half its camera images that way before two fixes in the
//! pacing: a token bucket (late wake-ups of the event loop lowered the rate) and counting each
//! datagram at its size (on loopback the 64 kB budget was counted for every datagram);
//! docs/node.md, "Large outputs".

use super::harness::{loopback, record_street_bag};
use crate::common::{TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::msgs::Image;
use mode360::node::player::{play_bag, PlayOptions};
use mode360::node::{create_subscription, dds_context, sensor_qos, SpunNode};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Unique domain of this test file.
const DOMAIN_ID: u16 = 74;
const WIDTH: usize = 512;
/// Frames of the bag, played [`LOOPS`] times: 16 s of input at the recorded 10 Hz (a player
/// that falls behind loses images only once its backlog outgrows its writers' history).
const FRAMES: usize = 20;
const LOOPS: usize = 8;
/// rgb8 bytes of one camera image.
const IMAGE_BYTES: usize = WIDTH * WIDTH / 2 * 3;
/// Least share of each camera's images that must arrive whole (best effort on loopback: a
/// datagram may still be lost now and then).
const MIN_RECEIVED_SHARE: f64 = 0.9;
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(10);
/// After the player returns (it lingers 1 s), the last samples are in.
const DRAIN: Duration = Duration::from_millis(500);
const POLL: Duration = Duration::from_millis(5);

#[test]
fn the_player_delivers_every_camera_image_at_512() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let dir = tempfile::tempdir()?;
    let bag_path = dir.path().join("in_512.mcap");
    let rig = Rig::from_file(RIG_PATH)?;
    record_street_bag(&rig, 11, WIDTH, FRAMES, &bag_path)?;

    let dds = loopback(DOMAIN_ID);
    let context = dds_context(&dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_test_player_listener")?;
    let subs = rig
        .cameras
        .iter()
        .map(|c| {
            let sub = create_subscription::<Image>(&mut listener.node, &c.topic, sensor_qos())?;
            Ok((c.topic.clone(), sub))
        })
        .collect::<Result<Vec<_>, Box<dyn std::error::Error>>>()?;

    // Load every core as the node's network does while it receives (the player's event loop
    // then wakes late: the case the pacing got wrong).
    let stop_load = Arc::new(AtomicBool::new(false));
    let load: Vec<_> = (0..std::thread::available_parallelism().map_or(2, |n| n.get()))
        .map(|_| {
            let stop = stop_load.clone();
            std::thread::spawn(move || {
                let mut x = 1u64;
                while !stop.load(Ordering::Relaxed) {
                    for _ in 0..10_000 {
                        x = std::hint::black_box(
                            x.wrapping_mul(6364136223846793005).wrapping_add(1),
                        );
                    }
                }
            })
        })
        .collect();
    let topics: Vec<String> = rig.cameras.iter().map(|c| c.topic.clone()).collect();
    let player = {
        let bag_path = bag_path.clone();
        let dds = dds.clone();
        std::thread::spawn(move || {
            play_bag(&PlayOptions {
                input: bag_path,
                rate: 1.0,
                loops: LOOPS,
                publish_clock: false,
                dds,
                wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
                wait_topics: topics,
            })
            .map_err(|e| e.to_string())
        })
    };
    let mut whole: BTreeMap<String, BTreeSet<u64>> = BTreeMap::new();
    let mut partial = 0usize;
    let mut drain_from: Option<Instant> = None;
    while drain_from.is_none_or(|t| t.elapsed() < DRAIN) {
        for (topic, sub) in &subs {
            while let Some((image, _)) = sub.take()? {
                if image.data.len() == IMAGE_BYTES && image.width as usize == WIDTH {
                    whole
                        .entry(topic.clone())
                        .or_default()
                        .insert(image.header.stamp.to_nanos());
                } else {
                    partial += 1;
                }
            }
        }
        if drain_from.is_none() && player.is_finished() {
            drain_from = Some(Instant::now());
        }
        std::thread::sleep(POLL);
    }
    stop_load.store(true, Ordering::Relaxed);
    for l in load {
        l.join().map_err(|_| "a load thread panicked")?;
    }
    let played = player.join().map_err(|_| "the player panicked")??;
    let counts: Vec<(String, usize)> = rig
        .cameras
        .iter()
        .map(|c| {
            (
                c.topic.clone(),
                whole.get(&c.topic).map_or(0, BTreeSet::len),
            )
        })
        .collect();
    println!(
        "played {:?}; received whole per camera {counts:?}",
        played.published
    );
    assert_eq!(partial, 0, "images of the wrong size arrived");
    for (topic, n) in &counts {
        let sent = FRAMES * LOOPS;
        assert_eq!(played.published.get(topic), Some(&(sent as u64)), "{topic}");
        let share = *n as f64 / sent as f64;
        assert!(
            share >= MIN_RECEIVED_SHARE,
            "{topic}: {n} of {sent} images arrived ({counts:?})"
        );
    }
    Ok(())
}
