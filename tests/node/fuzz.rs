//! A hostile sender on the camera topics (issue 39): a second writer on every camera topic
//! publishes, between the good groups of a well-behaved driver, samples drawn from a fixed
//! seed: random bytes, a good image's CDR cut short or with flipped bytes, an unknown
//! encoding, a size of 65535 x 65535 over a few bytes, a step of 2^32 - 1, stamps an hour
//! ahead, at 2^31 - 1 s and an hour back, images of another size, and 1 to 3 MB of random bytes
//! (fragmented samples). The raw samples are written by RustDDS as the bytes given, so the
//! node's reader sees exactly what a broken or hostile sender puts on the wire. Stamps are the
//! wall clock's, as a live driver's are (so an hour ahead is ahead of the receive time).
//!
//! Checked: after each burst, with the driver streaming good groups at 10 Hz, depth resumes
//! within [`RESUME_TIMEOUT`], the hostile samples that arrive are counted under a reason, the
//! pipeline never fails, and the node's resident memory after every burst stays within a
//! limit of the most it held under normal input (as many good groups before the first
//! burst): at 64 wide, the node in the test's process
//! (whose memory then counts sender and listener too), [`MEMORY_GROWTH_LIMIT_MIB`]; at the
//! node's default 512, the `mode360 node` binary as its own process, issue 39's 100 MiB
//! (`hostile_samples_at_512_leave_memory_within_100_mib`).

use super::harness::{loopback, render};
use super::node_process::NodeProcess;
use crate::common::{TestResult, RIG_PATH};
use mode360::geometry::Rig;
use mode360::memory::resident_mib;
use mode360::msgs::image::image_msg_from_rgb;
use mode360::msgs::{try_encode_cdr, Header, Image, RosMessage};
use mode360::node::{
    create_publisher, create_subscription, dds_context, sensor_qos, spawn_node, NodeHandle,
    NodeHealth, NodeParams, SpunNode,
};
use ros2_client::qos::History;
use ros2_client::{Publisher, QosProfile};
use serde::ser::SerializeTuple;
use std::collections::BTreeSet;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

const DOMAIN_ID: u16 = 65;
/// Domain of the run at 512.
const DOMAIN_ID_512: u16 = 67;
const WIDTH: usize = 64;
/// Bursts of hostile samples, each followed by a good group.
const ROUNDS: u64 = 12;
const HOSTILE_PER_ROUND: usize = 12;
const HOUR_NS: u64 = 3_600_000_000_000;
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(10);
/// Period of the good driver's groups.
const DRIVER_PERIOD: Duration = Duration::from_millis(100);
/// Depth must answer a good group within this after each burst.
const RESUME_TIMEOUT: Duration = Duration::from_secs(20);
const POLL: Duration = Duration::from_millis(20);
/// How long the node process may take to come up, and to exit after SIGINT.
const UP_TIMEOUT: Duration = Duration::from_secs(60);
const EXIT_LIMIT: Duration = Duration::from_secs(10);
/// The process may hold this much more memory after any burst than after the warm-up
/// (at 64 wide).
const MEMORY_GROWTH_LIMIT_MIB: f64 = 300.0;
/// The same at 512 (issue 39's target: within 100 MiB after each attack).
const MEMORY_GROWTH_LIMIT_512_MIB: f64 = 100.0;
/// Good groups answered before memory is first read.
const WARMUP_GROUPS: usize = 6;
/// The fuzz seed.
const SEED: u64 = 0x6d6f_6465_3336_3039;

/// Bytes published as they are: the body of a `sensor_msgs/msg/Image` sample (after the
/// encapsulation header, which RustDDS writes) as a broken or hostile sender produces it.
struct RawImage(Vec<u8>);

impl std::fmt::Debug for RawImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RawImage({} bytes)", self.0.len())
    }
}

impl serde::Serialize for RawImage {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // A CDR tuple is its elements, one after the other: the bytes, unframed.
        let mut t = s.serialize_tuple(self.0.len())?;
        for b in &self.0 {
            t.serialize_element(b)?;
        }
        t.end()
    }
}

impl<'de> serde::Deserialize<'de> for RawImage {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        serde::de::IgnoredAny::deserialize(d)?;
        Ok(Self(Vec::new()))
    }
}

impl RosMessage for RawImage {
    const TYPE_NAME: &'static str = Image::TYPE_NAME;
}

/// What a hostile sample is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Hostile {
    RandomBytes,
    Truncated,
    FlippedBytes,
    UnknownEncoding,
    HugeSize,
    HugeStep,
    StampHourAhead,
    StampMax,
    StampHourBack,
    OtherSize,
    LargeRandom,
}

impl Hostile {
    const ALL: [Self; 11] = [
        Self::RandomBytes,
        Self::Truncated,
        Self::FlippedBytes,
        Self::UnknownEncoding,
        Self::HugeSize,
        Self::HugeStep,
        Self::StampHourAhead,
        Self::StampMax,
        Self::StampHourBack,
        Self::OtherSize,
        Self::LargeRandom,
    ];
}

/// xorshift64*: a fixed sequence from [`SEED`].
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }
}

/// Now on the wall clock, nanoseconds since the epoch: the stamps of a live driver.
fn wall_clock_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The CDR body (no encapsulation header) of `msg`.
fn body(msg: &Image) -> Result<Vec<u8>, String> {
    let cdr = try_encode_cdr(msg).map_err(|e| e.to_string())?;
    Ok(cdr[4..].to_vec())
}

/// A hostile sample of `kind` for a camera whose good image is `good`.
fn hostile(kind: Hostile, good: &Image, rng: &mut Rng) -> Result<Vec<u8>, String> {
    let mut msg = good.clone();
    let stamp = good.header.stamp.to_nanos();
    Ok(match kind {
        Hostile::RandomBytes => {
            let n = rng.below(3000);
            rng.bytes(n)
        }
        Hostile::Truncated => {
            let mut b = body(good)?;
            b.truncate(rng.below(b.len()));
            b
        }
        Hostile::FlippedBytes => {
            let mut b = body(good)?;
            for _ in 0..8 {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
            b
        }
        Hostile::UnknownEncoding => {
            msg.encoding = "yuv422_yuy2".into();
            body(&msg)?
        }
        Hostile::HugeSize => {
            (msg.width, msg.height, msg.step) = (65535, 65535, 3 * 65535);
            msg.data.truncate(64);
            body(&msg)?
        }
        Hostile::HugeStep => {
            msg.step = u32::MAX;
            body(&msg)?
        }
        Hostile::StampHourAhead => {
            msg.header = Header::new(stamp + HOUR_NS, &good.header.frame_id);
            body(&msg)?
        }
        Hostile::StampMax => {
            msg.header = Header::new((i32::MAX as u64) * 1_000_000_000, &good.header.frame_id);
            body(&msg)?
        }
        Hostile::StampHourBack => {
            msg.header = Header::new(stamp.saturating_sub(HOUR_NS), &good.header.frame_id);
            body(&msg)?
        }
        Hostile::OtherSize => {
            let half = good.width / 2;
            (msg.width, msg.height, msg.step) = (half, half / 2, 3 * half);
            msg.data.truncate((3 * half * half / 2) as usize);
            body(&msg)?
        }
        Hostile::LargeRandom => {
            let n = 1_000_000 + rng.below(2_000_000);
            rng.bytes(n)
        }
    })
}

#[test]
fn hostile_camera_samples_are_counted_and_depth_keeps_flowing() -> TestResult {
    fuzz(
        DOMAIN_ID,
        WIDTH,
        MEMORY_GROWTH_LIMIT_MIB,
        Placement::InProcess,
    )
}

/// The attack at the node's default size against issue 39's memory target, the node as its
/// own process so that its resident memory is read apart from the sender's and listener's
/// (about 50 s in a test build). Measured: 483 and 470 MiB under normal input, at most 546 and
/// 512 MiB after a burst (+63, +42).
#[test]
fn hostile_samples_at_512_leave_memory_within_100_mib() -> TestResult {
    fuzz(
        DOMAIN_ID_512,
        512,
        MEMORY_GROWTH_LIMIT_512_MIB,
        Placement::OwnProcess,
    )
}

/// Where the node under attack runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Placement {
    /// In the test's process ([`spawn_node`]): its health is read directly.
    InProcess,
    /// The `mode360 node` binary: its own memory is measured, its counters come from its
    /// exit summary.
    OwnProcess,
}

/// The node under attack.
enum Target {
    InProcess(NodeHandle),
    OwnProcess(NodeProcess, tempfile::TempDir),
}

impl Target {
    fn start(placement: Placement, domain_id: u16, width: usize) -> Result<Self, String> {
        Ok(match placement {
            Placement::InProcess => Self::InProcess(
                spawn_node(
                    NodeParams {
                        rig_file: RIG_PATH.into(),
                        output_width: width,
                        ..Default::default()
                    },
                    loopback(domain_id),
                )
                .map_err(|e| e.to_string())?,
            ),
            Placement::OwnProcess => {
                let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
                let params = dir.path().join("params.yaml");
                std::fs::write(
                    &params,
                    format!(
                        "mode360:\n  ros__parameters:\n    rig_file: {RIG_PATH}\n    \
                         output_width: {width}\n"
                    ),
                )
                .map_err(|e| e.to_string())?;
                Self::OwnProcess(NodeProcess::spawn(&params, domain_id, UP_TIMEOUT)?, dir)
            }
        })
    }

    /// The node's resident memory: the whole test process's when it runs inside it.
    fn resident_mib(&self) -> Option<f64> {
        match self {
            Self::InProcess(_) => resident_mib(),
            Self::OwnProcess(p, _) => p.resident_mib(),
        }
    }

    /// What to show when depth does not resume.
    fn state(&self) -> String {
        match self {
            Self::InProcess(node) => format!("health {:#?}", node.health()),
            Self::OwnProcess(p, _) => format!("node log {:#?}", p.log),
        }
    }
}

/// The fuzz run (module docs) at `width` in `domain_id`; resident memory after every burst
/// must stay within `growth_limit_mib` of the most the node held under normal input (the same
/// number of good groups without an attack, after the warm-up).
fn fuzz(domain_id: u16, width: usize, growth_limit_mib: f64, placement: Placement) -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let frame = render(&rig, 11, width)?;
    let dds = loopback(domain_id);
    let node = Target::start(placement, domain_id, width)?;
    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", "mode360_fuzz_client")?;
    let reliable = QosProfile::publisher_default().history(History::KeepLast { depth: 10 });
    let depth_sub = create_subscription::<Image>(&mut client.node, "/depth", reliable)?;
    let good_pubs: Vec<Publisher<Image>> = rig
        .cameras
        .iter()
        .map(|c| create_publisher::<Image>(&mut client.node, &c.topic, sensor_qos()))
        .collect::<Result<_, _>>()?;
    let raw_pubs: Vec<Publisher<RawImage>> = rig
        .cameras
        .iter()
        .map(|c| create_publisher::<RawImage>(&mut client.node, &c.topic, sensor_qos()))
        .collect::<Result<_, _>>()?;
    let t0 = Instant::now();
    while (good_pubs
        .iter()
        .any(|p| p.get_subscription_count(&client.node) == 0)
        || raw_pubs
            .iter()
            .any(|p| p.get_subscription_count(&client.node) == 0)
        || depth_sub.get_publisher_count(&client.node) == 0)
        && t0.elapsed() < DISCOVERY_TIMEOUT
    {
        std::thread::sleep(POLL);
    }
    let good = |i: usize, stamp_ns: u64| {
        image_msg_from_rgb(
            Header::new(stamp_ns, &rig.cameras[i].frame_id),
            &frame.images[i],
        )
    };
    let mut depth_stamps = BTreeSet::new();
    let mut resume_s: Vec<f64> = Vec::new();
    // The driver streams good groups at DRIVER_PERIOD until depth answers one of them: depth
    // must resume within RESUME_TIMEOUT (a jump back delivered after a group's images restarts
    // the synchronizer and costs that group).
    let mut stream_until_depth = || -> Result<(), String> {
        let t0 = Instant::now();
        let mut sent_stamps = BTreeSet::new();
        let mut next_send = t0;
        loop {
            if Instant::now() >= next_send {
                let stamp_ns = wall_clock_ns();
                for (i, p) in good_pubs.iter().enumerate() {
                    p.publish(good(i, stamp_ns)).map_err(|e| format!("{e:?}"))?;
                }
                sent_stamps.insert(stamp_ns);
                next_send += DRIVER_PERIOD;
            }
            while let Ok(Some((m, _))) = depth_sub.take() {
                depth_stamps.insert(m.header.stamp.to_nanos());
            }
            if sent_stamps.iter().any(|s| depth_stamps.contains(s)) {
                resume_s.push(t0.elapsed().as_secs_f64());
                return Ok(());
            }
            if t0.elapsed() > RESUME_TIMEOUT {
                return Err(format!(
                    "no depth within {RESUME_TIMEOUT:?} for any of {} good groups; {}",
                    sent_stamps.len(),
                    node.state()
                ));
            }
            std::thread::sleep(POLL);
        }
    };
    // Memory is compared with the node under normal input: the first groups grow the
    // allocator's pools to the sizes a frame needs, and they keep growing a little for a while
    // (at 512, +45 MiB over the next 12 groups without any attack). So after the warm-up the
    // driver streams as many rounds of good groups as there will be bursts, and the highest
    // resident size seen then is the normal level.
    for _ in 0..WARMUP_GROUPS {
        stream_until_depth()?;
    }
    let mut rss_normal: Vec<f64> = node.resident_mib().into_iter().collect();
    for _ in 0..ROUNDS {
        stream_until_depth()?;
        rss_normal.extend(node.resident_mib());
    }
    let rss_before = rss_normal.iter().copied().reduce(f64::max);
    let mut rss_after_bursts: Vec<f64> = Vec::new();
    let mut rng = Rng(SEED);
    let mut sent: Vec<Hostile> = Vec::new();
    for _round in 0..ROUNDS {
        for _ in 0..HOSTILE_PER_ROUND {
            let cam = rng.below(raw_pubs.len());
            // Every kind comes up: the first rounds go through them in order.
            let kind = match sent.len() {
                n if n < Hostile::ALL.len() => Hostile::ALL[n],
                _ => Hostile::ALL[rng.below(Hostile::ALL.len())],
            };
            // Stamped like a live driver's images, between two good groups.
            let bytes = hostile(kind, &good(cam, wall_clock_ns()), &mut rng)?;
            raw_pubs[cam]
                .publish(RawImage(bytes))
                .map_err(|e| format!("publishing a hostile sample: {e:?}"))?;
            sent.push(kind);
        }
        stream_until_depth()?;
        rss_after_bursts.extend(node.resident_mib());
    }
    let rss_after = node.resident_mib();
    eprintln!(
        "fuzz at {width}: {} hostile samples ({} kinds), depth resumed after {resume_s:.1?} s, RSS of the {} under normal input {rss_normal:.0?} MiB, after each burst {rss_after_bursts:.0?}, at the end {rss_after:?} MiB",
        sent.len(),
        Hostile::ALL.len(),
        match placement {
            Placement::InProcess => "test process",
            Placement::OwnProcess => "node process",
        }
    );
    if let Some(before) = rss_before {
        let worst = rss_after_bursts.iter().copied().fold(before, f64::max);
        assert!(
            worst - before < growth_limit_mib,
            "resident memory grew from {before:.0} MiB under normal input to {worst:.0} MiB \
             after a burst (limit {growth_limit_mib} MiB): {rss_after_bursts:.0?}"
        );
    }
    drop(raw_pubs);
    client.stop()?;
    drop(context);
    match node {
        Target::InProcess(node) => {
            check_counted(&node.health(), &sent);
            node.shutdown()?;
        }
        Target::OwnProcess(process, _dir) => {
            let exit = process.interrupt(EXIT_LIMIT)?;
            assert_eq!(exit.status.code(), Some(0), "{:#?}", exit.log);
            println!("node summary: {}", exit.stdout.trim());
            let summary = exit.summary()?;
            let count = |key: &str| summary.get(key);
            assert_eq!(count("pipeline_errors")?, 0, "{}", summary.line);
            let countable = countable(&sent);
            let counted = count("images_bad")?;
            assert!(
                counted * 10 >= countable * 8,
                "{counted} of {countable} malformed samples counted: {}",
                summary.line
            );
        }
    }
    Ok(())
}

/// The hostile samples that must be counted as bad: all but the large ones (best effort may
/// lose them), a stamp an hour back (it restarts the synchronizer instead), an image of
/// another size (left out of groups) and flipped bytes (mostly in the pixels: a valid image).
fn countable(sent: &[Hostile]) -> u64 {
    sent.iter()
        .filter(|k| {
            !matches!(
                k,
                Hostile::LargeRandom
                    | Hostile::StampHourBack
                    | Hostile::OtherSize
                    | Hostile::FlippedBytes
            )
        })
        .count() as u64
}

/// The in-process node counted (nearly) every countable sample, under several reasons, and
/// never failed.
fn check_counted(health: &NodeHealth, sent: &[Hostile]) {
    assert_eq!(
        health.pipeline_errors, 0,
        "{:?}",
        health.last_pipeline_error
    );
    let countable = countable(sent);
    let counted: u64 = health.cameras.iter().map(|c| c.bad_messages).sum();
    assert!(
        counted * 10 >= countable * 8,
        "{counted} of {countable} malformed samples counted: {health:#?}"
    );
    let reasons: BTreeSet<_> = health
        .cameras
        .iter()
        .flat_map(|c| c.bad_by_reason.keys().copied())
        .collect();
    assert!(reasons.len() >= 4, "reasons counted: {reasons:?}");
    eprintln!(
        "bad counted {:?}",
        health
            .cameras
            .iter()
            .map(|c| &c.bad_by_reason)
            .collect::<Vec<_>>()
    );
}
