//! The node with a real ROS 2 client: rclpy with rmw_fastrtps_cpp and Fast DDS's defaults,
//! from the `ros-jazzy-rclpy` and `ros-kilted-rclpy` wheels (`tests/interop/setup.sh` makes a
//! venv of each), through `tests/interop/rclpy_peer.py`, the node in-process, over loopback.
//! Per distribution:
//!
//! * the two flows of every third-party DDS ([`dds_peer_tests`]): rclpy decodes `depth` and
//!   `points` exactly as our own subscriber received them, and rclpy as the camera driver
//!   feeds the node;
//! * `stream`: camera groups at 10 Hz for several seconds (128 wide, and 512), rclpy's
//!   default reliable subscriptions (what rviz and `ros2 topic echo` use) must get every
//!   `depth`, `confidence` and `points` message the node published, each within
//!   [`MAX_EXTRA_DELAY`] of our own subscriber in the node's process (the worst delay is
//!   printed); best-effort ones (sensor-data QoS, 128 wide) at least 90 %;
//! * `params`: `list_parameters`, `get_parameters`, `describe_parameters` and
//!   `set_parameters` as `ros2 param` calls them: every parameter listed with its value, a
//!   run-time one set, a start-time one refused with the reason;
//! * the driver's clock misbehaving (poisoned stamps, a reset, a loop, a flooding camera):
//!   `rclpy_time.rs`;
//! * `types`: every endpoint of the node that rclpy's graph shows (publishers,
//!   subscriptions, the parameter services' request and reply endpoints) carries the REP 2011
//!   type hash that rosidl generated for its type in that distribution.
//!
//! Needs `MODE360_RCLPY_JAZZY` / `MODE360_RCLPY_KILTED`: a Python with that distribution's
//! rclpy (setup.sh prints them). Without one its tests are skipped, unless `CI` is set.

use super::dds_peer::{
    dds_peer_tests, frames_json_publishing, DdsPeer, PeerResult, Publishing, PEER_DISCOVERY_TIMEOUT,
};
use super::harness::{loopback, render, wait_for, Cameras, Peer};
use crate::common::{reliable_qos, TestResult, RIG_PATH};
use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use mode360::msgs::{type_hash, Image, PointCloud2};
use mode360::node::param_docs;
use mode360::node::param_table::parameter;
use mode360::node::{create_subscription, dds_context, spawn_node, NodeParams, SpunNode};
use serde_json::Value;
use std::collections::BTreeMap;
use std::marker::PhantomData;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

const PEER_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/interop/rclpy_peer.py");
/// Output width of the streaming test (at 512 the camera images alone would keep the loaded
/// test machine busy). Its outputs are fragmented (the cloud is about 130 kB)
/// but fit Fast DDS's default 212,992-byte receive buffer.
///
/// At the node's default 512 (depth 0.5 MB, cloud up to 1.6 MB: `*_receives_every_output_at_512`)
/// RustDDS 0.15.1 as it ships sent a sample's fragments back to back, the reader's buffer
/// overflowed and repair brought outputs seconds late or never (4 of 7 confidence images, 2.7
/// to 5 s late); the vendored RustDDS paces them (docs/node.md).
const STREAM_WIDTH: usize = 128;
/// Output width of the measurement at the node's default size.
const FULL_WIDTH: usize = 512;
/// Camera groups a second in the streaming test.
const STREAM_RATE_HZ: f64 = 10.0;
/// How long the cameras stream.
const STREAM_DURATION: Duration = Duration::from_secs(8);
/// Share of the published messages a reliable rclpy subscription must receive (issue 39: at
/// least 99 %).
const MIN_RECEIVED_SHARE: f64 = 0.99;
/// The same for a best-effort one, which may lose a sample (a fragment lost is the sample
/// lost; nothing repairs it): 90 %, and always one sample, however few were published (on a
/// loaded machine the node publishes about 9 in the stream's 8 s, where 90 % allowed none).
const MIN_RECEIVED_SHARE_BEST_EFFORT: f64 = 0.9;

/// How rclpy subscribes in the streaming test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reliability {
    /// rclpy's default (what rviz and `ros2 topic echo` use).
    Reliable,
    /// rclpy's sensor-data QoS.
    BestEffort,
}

impl Reliability {
    /// Of `published` messages, how many rclpy must receive.
    fn min_received(self, published: u64) -> u64 {
        let share = match self {
            Self::Reliable => MIN_RECEIVED_SHARE,
            Self::BestEffort => MIN_RECEIVED_SHARE_BEST_EFFORT,
        };
        let by_share = (share * published as f64).ceil() as u64;
        match self {
            Self::Reliable => by_share,
            Self::BestEffort => by_share.min(published.saturating_sub(1)),
        }
    }
}
/// How much later than our own in-process subscriber rclpy may get a message: a bound that
/// catches repair taking many seconds (the failure at 512). The 0.5 s is a latency
/// target, printed by the test (the worst delay per topic), not asserted: at 128 under load a
/// message now and then comes 0.8 to 1.0 s late (one heartbeat period of RustDDS's writer, 1 s:
/// a lost datagram repaired at the next heartbeat).
const MAX_EXTRA_DELAY: Duration = Duration::from_secs(3);
/// How long the cameras stream on after the counted groups, while the outputs drain.
const DRAIN: Duration = Duration::from_secs(4);
const POLL: Duration = Duration::from_millis(5);

/// A ROS 2 distribution whose rclpy wheels the tests run.
pub(crate) trait Distro {
    const ENV: &'static str;
    const LABEL: &'static str;
    const TAG: &'static str;
}

pub(crate) struct Jazzy;
impl Distro for Jazzy {
    const ENV: &'static str = "MODE360_RCLPY_JAZZY";
    const LABEL: &'static str = "rclpy (Jazzy)";
    const TAG: &'static str = "rclpy_jazzy";
}

pub(crate) struct Kilted;
impl Distro for Kilted {
    const ENV: &'static str = "MODE360_RCLPY_KILTED";
    const LABEL: &'static str = "rclpy (Kilted)";
    const TAG: &'static str = "rclpy_kilted";
}

/// `rclpy_peer.py` run by a Python with distribution `D`'s rclpy.
pub(crate) struct Rclpy<D> {
    python: String,
    distro: PhantomData<D>,
}

impl<D: Distro> Rclpy<D> {
    /// The peer, or `None` after printing why the test is skipped (panics under CI).
    pub(crate) fn from_env() -> Option<Self> {
        let python = std::env::var(D::ENV).ok().filter(|p| !p.is_empty());
        let problem = match python {
            None => format!("{} is not set", D::ENV),
            Some(python) => match Command::new(&python)
                .args(["-c", "import rclpy, rmw_fastrtps_cpp"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
            {
                Ok(s) if s.success() => {
                    return Some(Self {
                        python,
                        distro: PhantomData,
                    })
                }
                Ok(s) => format!("{}={python} cannot import rclpy ({s})", D::ENV),
                Err(e) => format!("{}={python} does not run: {e}", D::ENV),
            },
        };
        let hint = format!(
            "skipped {} interop: {problem}; tests/interop/setup.sh DIR makes one",
            D::LABEL
        );
        assert!(std::env::var_os("CI").is_none(), "CI is set: {hint}");
        println!("{hint}");
        None
    }

    fn run(&self, args: &[String]) -> PeerResult<Peer> {
        let mut script_args = vec![PEER_SCRIPT.to_string()];
        script_args.extend_from_slice(args);
        Peer::start(D::LABEL, &self.python, &script_args)
    }
}

impl<D: Distro> DdsPeer for Rclpy<D> {
    const LABEL: &'static str = D::LABEL;
    const TAG: &'static str = D::TAG;

    fn start(&self, args: &[String]) -> PeerResult<Peer> {
        let peer = self.run(args)?;
        peer.expect_line("ready", PEER_DISCOVERY_TIMEOUT)?;
        Ok(peer)
    }

    fn publishing(&self, rig: &Rig, frames: &[RigFrame], dir: &Path) -> PeerResult<Publishing> {
        frames_json_publishing(rig, frames, dir)
    }
}

pub(crate) fn wall_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// Per stamp, when a subscriber got the message (wall clock, ns).
type Arrivals = BTreeMap<u64, u64>;

/// rclpy's `stream` result for `topic`: stamp -> receive time.
fn peer_arrivals(result: &Value, topic: &str) -> PeerResult<Arrivals> {
    let pairs: Vec<(String, String)> = serde_json::from_value(result[topic].clone())?;
    pairs
        .into_iter()
        .map(|(s, r)| Ok((s.parse()?, r.parse()?)))
        .collect()
}

/// rclpy must have received at least `min_received` of the `published` messages of
/// `topic`, each at most [`MAX_EXTRA_DELAY`] after our own subscriber got it (where ours did);
/// returns (received, published, worst extra delay).
fn check_topic(
    topic: &str,
    ours: &Arrivals,
    theirs: &Arrivals,
    published: u64,
    min_received: u64,
) -> PeerResult<(usize, u64, Duration)> {
    let delays: Vec<String> = theirs
        .iter()
        .map(|(s, &r)| match ours.get(s) {
            Some(&t) => format!("{s}: {:+.3} s", (r as f64 - t as f64) * 1e-9),
            None => format!("{s}: (not ours)"),
        })
        .collect();
    println!(
        "{topic}: node published {published}, ours {}, rclpy {}: {delays:?}",
        ours.len(),
        theirs.len()
    );
    let received = theirs.len();
    assert!(
        received as u64 >= min_received,
        "{topic}: rclpy got {received} of {published} (at least {min_received}); ours got {:?}, rclpy {:?}",
        ours.keys().collect::<Vec<_>>(),
        theirs.keys().collect::<Vec<_>>()
    );
    let worst_ns = theirs
        .iter()
        .filter_map(|(s, &r)| ours.get(s).map(|&t| r.saturating_sub(t)))
        .max()
        .unwrap_or(0);
    let worst = Duration::from_nanos(worst_ns);
    assert!(
        worst <= MAX_EXTRA_DELAY,
        "{topic}: rclpy got a message {worst:?} after our own subscriber"
    );
    Ok((received, published, worst))
}

/// The streaming test of distribution `D` in `domain_id` at output `width` (see the module
/// docs).
fn rclpy_receives_every_output<D: Distro>(
    domain_id: u16,
    width: usize,
    reliability: Reliability,
) -> TestResult {
    let Some(peer) = Rclpy::<D>::from_env() else {
        return Ok(());
    };
    let _one_node_at_a_time = crate::common::live_node_lock();
    let rig = Rig::from_file(RIG_PATH)?;
    let dds = loopback(domain_id);
    let node = spawn_node(
        NodeParams {
            rig_file: RIG_PATH.into(),
            output_width: width,
            camera_timeout_s: 30.0,
            ..Default::default()
        },
        dds.clone(),
    )?;
    let context = dds_context(&dds)?;
    let mut client = SpunNode::new(&context, "/", &format!("mode360_{}_stream", D::TAG))?;
    let depth = create_subscription::<Image>(&mut client.node, "/depth", reliable_qos())?;
    let confidence = create_subscription::<Image>(&mut client.node, "/confidence", reliable_qos())?;
    let points = create_subscription::<PointCloud2>(&mut client.node, "/points", reliable_qos())?;
    let matched = wait_for(PEER_DISCOVERY_TIMEOUT, || {
        depth.get_publisher_count(&client.node) > 0
            && confidence.get_publisher_count(&client.node) > 0
            && points.get_publisher_count(&client.node) > 0
    });
    assert!(matched, "our subscriber did not match the node's outputs");
    let mut stream_args = vec!["stream".into(), "--domain".into(), domain_id.to_string()];
    if reliability == Reliability::BestEffort {
        stream_args.push("--best-effort".into());
    }
    let mut rclpy = peer.start(&stream_args)?;
    let frame = render(&rig, 3, width)?;
    let mut cameras = Cameras::new(&mut client, &rig, frame, 100_000_000)?;

    let mut ours: [Arrivals; 3] = Default::default();
    let take = |ours: &mut [Arrivals; 3]| -> PeerResult<()> {
        while let Some((m, _)) = depth.take()? {
            ours[0].insert(m.header.stamp.to_nanos(), wall_ns());
        }
        while let Some((m, _)) = confidence.take()? {
            ours[1].insert(m.header.stamp.to_nanos(), wall_ns());
        }
        while let Some((m, _)) = points.take()? {
            ours[2].insert(m.header.stamp.to_nanos(), wall_ns());
        }
        Ok(())
    };
    // The cameras stream on while the outputs drain, as a live rig would: the groups counted
    // are those whose images were sent in the first STREAM_DURATION; later traffic only makes
    // sure the last counted ones are not the writer's last words.
    let period = Duration::from_secs_f64(1.0 / STREAM_RATE_HZ);
    let t0 = Instant::now();
    let mut next = t0;
    let mut counted_stamps = std::collections::BTreeSet::new();
    while t0.elapsed() < STREAM_DURATION + DRAIN {
        if Instant::now() >= next {
            let stamp = cameras.send_all()?;
            if t0.elapsed() < STREAM_DURATION {
                counted_stamps.insert(stamp);
            }
            next += period;
        }
        take(&mut ours)?;
        std::thread::sleep(POLL);
    }
    rclpy.send("quit")?;
    let result: Value = serde_json::from_str(&rclpy.expect_line("result", DRAIN)?)?;
    rclpy.finish(DRAIN)?;
    let topics = ["/depth", "/confidence", "/points"];
    let mut theirs = Vec::new();
    for topic in topics {
        theirs.push(peer_arrivals(&result, topic)?);
    }
    // A counted group was published if anyone got any of its outputs (the node publishes
    // all three for every group it processes).
    let in_window = |a: &Arrivals| -> Arrivals {
        a.iter()
            .filter(|(s, _)| counted_stamps.contains(s))
            .map(|(&s, &t)| (s, t))
            .collect()
    };
    let published: std::collections::BTreeSet<u64> = ours
        .iter()
        .chain(theirs.iter())
        .flat_map(|a| in_window(a).into_keys())
        .collect();
    let published = published.len() as u64;
    assert!(published >= 3, "the node published only {published} groups");
    let health = node.health();
    assert!(health.groups_processed >= published && health.pipeline_errors == 0);
    for (k, topic) in topics.iter().enumerate() {
        let (got, of, worst) = check_topic(
            topic,
            &in_window(&ours[k]),
            &in_window(&theirs[k]),
            published,
            reliability.min_received(published),
        )?;
        println!(
            "{} {reliability:?}: {topic} {got} of {of}, at most {worst:?} after our subscriber",
            D::LABEL
        );
    }
    Ok(())
}

/// The parameter test of distribution `D` in `domain_id` (see the module docs).
fn rclpy_reads_and_sets_parameters<D: Distro>(domain_id: u16) -> TestResult {
    let Some(peer) = Rclpy::<D>::from_env() else {
        return Ok(());
    };
    let _one_node_at_a_time = crate::common::live_node_lock();
    let dds = loopback(domain_id);
    let params = NodeParams {
        rig_file: RIG_PATH.into(),
        output_width: 64,
        ..Default::default()
    };
    let node = spawn_node(params.clone(), dds)?;
    let rclpy = peer.run(&[
        "params".into(),
        "--domain".into(),
        domain_id.to_string(),
        "--set".into(),
        "max_depth_m=250.0".into(),
        "--refused".into(),
        "output_width=128".into(),
        // Every name in one request: a reply of several datagrams behind this host's MTU.
        "--describe".into(),
        "all".into(),
    ])?;
    let result: Value =
        serde_json::from_str(&rclpy.expect_line("result", PEER_DISCOVERY_TIMEOUT * 2)?)?;
    rclpy.finish(DRAIN)?;
    let names: Vec<String> = serde_json::from_value(result["names"].clone())?;
    for expected in [
        "output_width",
        "max_depth_m",
        "estimator",
        "rig_file",
        "use_sim_time",
    ] {
        assert!(
            names.iter().any(|n| n == expected),
            "{expected} not in {names:?}"
        );
    }
    assert_eq!(result["values"]["output_width"], 64);
    assert_eq!(result["values"]["estimator"], "ssmode");
    assert_eq!(result["values"]["max_depth_m"], params.max_depth_m);
    // rcl_interfaces/msg/ParameterType: 2 integer, 3 double, 4 string.
    assert_eq!(result["types"]["output_width"], 2);
    assert_eq!(result["types"]["max_depth_m"], 3);
    assert_eq!(result["types"]["estimator"], 4);
    // Every parameter described in one reply, each with its type (0: not set), the README's
    // description, and read-only unless it changes at run time.
    let described = result["described"].as_array().cloned().unwrap_or_default();
    assert_eq!(described.len(), names.len(), "{described:?}");
    for d in &described {
        let name = d["name"].as_str().unwrap_or_default();
        assert!(names.iter().any(|n| n == name), "{d}");
        assert_ne!(result["types"][name], 0, "{d}");
        let Some(spec) = parameter(name) else {
            continue;
        };
        assert_eq!(d["read_only"], !spec.runtime, "{d}");
        let expected = param_docs::description(name).unwrap_or_default();
        assert!(expected.len() > 10, "{name}: {expected}");
        assert_eq!(d["description"].as_str(), Some(expected.as_str()), "{d}");
    }
    let read_only = |name: &str| {
        described
            .iter()
            .find(|d| d["name"] == name)
            .map(|d| d["read_only"].clone())
    };
    assert_eq!(read_only("output_width"), Some(Value::Bool(true)));
    assert_eq!(read_only("max_depth_m"), Some(Value::Bool(false)));
    let ranges = |name: &str| {
        described
            .iter()
            .find(|d| d["name"] == name)
            .map(|d| d["ranges"].to_string())
    };
    assert_eq!(ranges("min_confidence").as_deref(), Some("[[0.0,1.0]]"));
    assert_eq!(ranges("foxglove_port").as_deref(), Some("[[0,65535]]"));
    assert_eq!(result["set"]["successful"], true, "{}", result["set"]);
    assert_eq!(result["after_set"], 250.0);
    assert_eq!(result["refused"]["successful"], false);
    let reason = result["refused"]["reason"].as_str().unwrap_or("");
    assert!(
        reason.contains("output_width") && reason.contains("restart"),
        "{reason}"
    );
    assert_eq!(node.health().pipeline_errors, 0);
    Ok(())
}

/// The type-hash test of distribution `D` in `domain_id` (see the module docs).
fn rclpy_sees_type_hashes_on_every_endpoint<D: Distro>(domain_id: u16) -> TestResult {
    let Some(peer) = Rclpy::<D>::from_env() else {
        return Ok(());
    };
    let _one_node_at_a_time = crate::common::live_node_lock();
    let params = NodeParams {
        rig_file: RIG_PATH.into(),
        output_width: 64,
        ..Default::default()
    };
    let node = spawn_node(params, loopback(domain_id))?;
    let rclpy = peer.run(&["types".into(), "--domain".into(), domain_id.to_string()])?;
    let result: Value =
        serde_json::from_str(&rclpy.expect_line("result", PEER_DISCOVERY_TIMEOUT * 2)?)?;
    rclpy.finish(DRAIN)?;
    let endpoints = result["endpoints"].as_array().cloned().unwrap_or_default();
    let field = |e: &Value, key: &str| e[key].as_str().unwrap_or_default().to_string();
    let mut per_kind: BTreeMap<String, usize> = BTreeMap::new();
    let mut without_rosidl_hash = Vec::new();
    for e in &endpoints {
        *per_kind.entry(field(e, "kind")).or_default() += 1;
        let (topic, type_name, hash) = (field(e, "topic"), field(e, "type"), field(e, "hash"));
        match e["expected"].as_str() {
            Some(expected) => assert_eq!(hash, expected, "{topic} ({type_name})"),
            None => without_rosidl_hash.push((type_name, hash)),
        }
    }
    println!(
        "{}: {} endpoints of the node, per kind {per_kind:?}; without a rosidl hash in the wheels: {without_rosidl_hash:?}",
        D::LABEL,
        endpoints.len()
    );
    // depth, confidence, points, /diagnostics, /tf_static, /rosout, /parameter_events.
    assert!(
        per_kind.get("publisher").copied().unwrap_or(0) >= 7,
        "{per_kind:?}"
    );
    assert!(
        per_kind.get("subscription").copied().unwrap_or(0) >= 4,
        "{per_kind:?}"
    );
    // The six parameter services, a request reader and a reply writer each.
    assert_eq!(per_kind.get("service request"), Some(&6), "{per_kind:?}");
    assert_eq!(per_kind.get("service reply"), Some(&6), "{per_kind:?}");
    // rclpy's wheels have no tf2_msgs: /tf_static's hash is checked against rosidl's
    // generated constant in mode360-io's unit test instead.
    let tf_hash = type_hash::type_hash("tf2_msgs/msg/TFMessage")?.to_string();
    for (type_name, hash) in &without_rosidl_hash {
        assert_eq!(type_name, "tf2_msgs/msg/TFMessage");
        assert_eq!(hash, &tf_hash);
    }
    assert_eq!(node.health().pipeline_errors, 0);
    Ok(())
}

dds_peer_tests!(
    Rclpy::<Jazzy>::from_env(),
    rclpy_jazzy_subscriber_decodes_depth_and_points in 56,
    rclpy_jazzy_publisher_feeds_the_node in 57,
);

dds_peer_tests!(
    Rclpy::<Kilted>::from_env(),
    rclpy_kilted_subscriber_decodes_depth_and_points in 58,
    rclpy_kilted_publisher_feeds_the_node in 59,
);

#[test]
fn rclpy_jazzy_receives_every_output() -> TestResult {
    rclpy_receives_every_output::<Jazzy>(60, STREAM_WIDTH, Reliability::Reliable)
}

#[test]
fn rclpy_kilted_receives_every_output() -> TestResult {
    rclpy_receives_every_output::<Kilted>(61, STREAM_WIDTH, Reliability::Reliable)
}

/// The target at the node's default size (fragmented outputs up to 1.6 MB against
/// Fast DDS's default receive buffer; see [`STREAM_WIDTH`]).
#[test]
fn rclpy_jazzy_receives_every_output_at_512() -> TestResult {
    rclpy_receives_every_output::<Jazzy>(64, FULL_WIDTH, Reliability::Reliable)
}

/// The same with Kilted's rclpy.
#[test]
fn rclpy_kilted_receives_every_output_at_512() -> TestResult {
    rclpy_receives_every_output::<Kilted>(66, FULL_WIDTH, Reliability::Reliable)
}

/// Best-effort subscriptions (rclpy's sensor-data QoS) at the streaming test's width.
#[test]
fn rclpy_jazzy_best_effort_receives_the_outputs() -> TestResult {
    rclpy_receives_every_output::<Jazzy>(72, STREAM_WIDTH, Reliability::BestEffort)
}

#[test]
fn rclpy_kilted_best_effort_receives_the_outputs() -> TestResult {
    rclpy_receives_every_output::<Kilted>(73, STREAM_WIDTH, Reliability::BestEffort)
}

#[test]
fn rclpy_jazzy_reads_and_sets_parameters() -> TestResult {
    rclpy_reads_and_sets_parameters::<Jazzy>(62)
}

#[test]
fn rclpy_kilted_reads_and_sets_parameters() -> TestResult {
    rclpy_reads_and_sets_parameters::<Kilted>(63)
}

#[test]
fn rclpy_jazzy_sees_type_hashes_on_every_endpoint() -> TestResult {
    rclpy_sees_type_hashes_on_every_endpoint::<Jazzy>(68)
}

#[test]
fn rclpy_kilted_sees_type_hashes_on_every_endpoint() -> TestResult {
    rclpy_sees_type_hashes_on_every_endpoint::<Kilted>(69)
}
