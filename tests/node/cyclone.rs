//! Interop with a third-party DDS (Eclipse Cyclone DDS through its Python binding), both ways,
//! over loopback, the node in-process:
//!
//! * `cyclone_subscriber_decodes_depth_and_points` (domain 43): we publish camera images with
//!   ros2-client; `tests/interop/cyclone_peer.py subscribe` receives the node's `depth` and
//!   `points` with its own IDL types and reports what it decoded; it must equal what our own
//!   subscriber received, and its points must be range x ERP direction.
//! * `cyclone_publisher_feeds_the_node` (domain 44): `cyclone_peer.py publish` sends rendered
//!   rgb8 camera images; the node's `depth` must carry the Cyclone stamps and match the
//!   ground truth.
//!
//! Needs `MODE360_PYTHON`: a Python with `cyclonedds` (`tests/interop/setup.sh DIR` makes one).
//! Without it the tests are skipped, unless `CI` is set, where they fail.

use super::dds_peer::{
    dds_peer_tests, frames_json_publishing, DdsPeer, PeerResult, Publishing, PEER_DISCOVERY_TIMEOUT,
};
use super::harness::Peer;
use crate::common::PYTHON_ENV;
use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use std::path::Path;
use std::process::{Command, Stdio};

const PEER_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/interop/cyclone_peer.py");
const PEER_NAME: &str = "cyclone_peer.py";
/// Domain of the Cyclone-subscriber test (unique among the test files).
const SUBSCRIBER_DOMAIN_ID: u16 = 43;
/// Domain of the Cyclone-publisher test (unique among the test files).
const PUBLISHER_DOMAIN_ID: u16 = 44;

/// `cyclone_peer.py` run by a Python with `cyclonedds`.
struct Cyclone {
    python: String,
}

impl Cyclone {
    /// The peer, or `None` after printing why the test is skipped (panics under CI).
    fn from_env() -> Option<Self> {
        let python = std::env::var(PYTHON_ENV).ok().filter(|p| !p.is_empty());
        let problem = match python {
            None => format!("{PYTHON_ENV} is not set"),
            Some(python) => match Command::new(&python)
                .args(["-c", "import cyclonedds"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
            {
                Ok(s) if s.success() => return Some(Self { python }),
                Ok(s) => format!("{PYTHON_ENV}={python} cannot import cyclonedds ({s})"),
                Err(e) => format!("{PYTHON_ENV}={python} does not run: {e}"),
            },
        };
        let hint = format!(
            "skipped Cyclone DDS interop: {problem}; set {PYTHON_ENV}=<python with cyclonedds> \
             (tests/interop/setup.sh DIR makes one)"
        );
        assert!(std::env::var_os("CI").is_none(), "CI is set: {hint}");
        println!("{hint}");
        None
    }
}

impl DdsPeer for Cyclone {
    const LABEL: &'static str = "Cyclone";
    const TAG: &'static str = "cyclone";

    fn start(&self, args: &[String]) -> PeerResult<Peer> {
        let mut script_args = vec![PEER_SCRIPT.to_string()];
        script_args.extend_from_slice(args);
        let peer = Peer::start(PEER_NAME, &self.python, &script_args)?;
        peer.expect_line("ready", PEER_DISCOVERY_TIMEOUT)?;
        Ok(peer)
    }

    /// The frames go to `frames.json` (`--frames`); frame K is published on `publish K`.
    fn publishing(&self, rig: &Rig, frames: &[RigFrame], dir: &Path) -> PeerResult<Publishing> {
        frames_json_publishing(rig, frames, dir)
    }
}

dds_peer_tests!(
    Cyclone::from_env(),
    cyclone_subscriber_decodes_depth_and_points in SUBSCRIBER_DOMAIN_ID,
    cyclone_publisher_feeds_the_node in PUBLISHER_DOMAIN_ID,
);
