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

use super::dds_peer::{
    dds_peer_tests, DdsPeer, PeerResult, Publishing, PEER_DISCOVERY_TIMEOUT, PEER_WIDTH,
};
use super::harness::Peer;
use crate::common::tool_from_env;
use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use std::path::Path;

/// The built Fast DDS peer (`tests/interop/setup.sh` prints its path).
const PEER_ENV: &str = "MODE360_FASTDDS_PEER";
const PEER_NAME: &str = "fastdds_peer";
/// Domain of the Fast DDS subscriber test (unique among the test files).
const SUBSCRIBER_DOMAIN_ID: u16 = 51;
/// Domain of the Fast DDS publisher test (unique among the test files).
const PUBLISHER_DOMAIN_ID: u16 = 52;
/// What the peer reports of its participant when it keeps Fast DDS's default transports.
const DEFAULT_TRANSPORTS: &str = "builtin_transports=1 user_transports=0";

/// The built `fastdds_peer`.
struct FastDds {
    path: String,
}

impl FastDds {
    /// The peer, or `None` after printing why the test is skipped (panics under CI).
    fn from_env() -> Option<Self> {
        let path = tool_from_env(
            PEER_ENV,
            "Fast DDS interop",
            &format!(
                "set {PEER_ENV} to the Fast DDS peer (tests/interop/setup.sh DIR builds it; \
                 needs Debian's libfastrtps-dev and fastddsgen)"
            ),
        )?;
        Some(Self { path })
    }
}

impl DdsPeer for FastDds {
    const LABEL: &'static str = "Fast DDS";
    const TAG: &'static str = "fastdds";

    /// Also checks that the peer kept Fast DDS's default transports.
    fn start(&self, args: &[String]) -> PeerResult<Peer> {
        let peer = Peer::start(PEER_NAME, &self.path, args)?;
        let transports = peer.expect_line("ready", PEER_DISCOVERY_TIMEOUT)?;
        assert_eq!(transports, DEFAULT_TRANSPORTS);
        Ok(peer)
    }

    /// The image size and the cameras go on the command line; frame K is published on
    /// `publish K STAMP_NS FILE...`.
    fn publishing(&self, rig: &Rig, frames: &[RigFrame], dir: &Path) -> PeerResult<Publishing> {
        let commands = write_frames(frames, dir)?;
        let mut args = vec![
            "--width".into(),
            PEER_WIDTH.to_string(),
            "--height".into(),
            (PEER_WIDTH / 2).to_string(),
        ];
        for cam in &rig.cameras {
            args.extend(["--camera".into(), cam.topic.clone(), cam.frame_id.clone()]);
        }
        Ok(Publishing { args, commands })
    }
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

dds_peer_tests!(
    FastDds::from_env(),
    fastdds_subscriber_decodes_depth_and_points in SUBSCRIBER_DOMAIN_ID,
    fastdds_publisher_feeds_the_node in PUBLISHER_DOMAIN_ID,
);
