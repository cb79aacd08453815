//! Helpers shared by the integration test binaries (`tests/core`, `tests/model`,
//! `tests/bags`, `tests/node`): paths in the repository, the bundled rig, third-party tools
//! from the environment, numeric references, and a lock for the live-node tests.
#![allow(dead_code)] // each binary uses its own subset

use mode360::geometry::Rig;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};

/// The Python with the interop packages (`tests/interop/setup.sh DIR` makes one).
pub const PYTHON_ENV: &str = "MODE360_PYTHON";
/// A folder holding `node_modules` with Foxglove's decoders (`tests/interop/setup.sh`).
pub const NODE_DIR_ENV: &str = "MODE360_NODE_DIR";
/// The bundled Deep360 rig, relative to the repository root.
pub const DEEP360_RIG: &str = "launch_configs/rig_deep360.yaml";

/// The bundled Deep360 rig, as an absolute path.
pub const RIG_PATH: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/launch_configs/rig_deep360.yaml"
);

/// What the tests that use `?` return.
pub type TestResult = Result<(), Box<dyn std::error::Error>>;

/// `rel` inside the repository.
pub fn repo_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The bundled Deep360 rig (`launch_configs/rig_deep360.yaml`).
pub fn deep360_rig() -> Rig {
    Rig::from_file(repo_path(DEEP360_RIG)).expect("launch_configs/rig_deep360.yaml")
}

/// The value of `var`, or `None` after printing `skipped {what}: {hint}`. Under CI (`CI` set)
/// a missing tool fails the test instead: CI installs every peer.
pub fn tool_from_env(var: &str, what: &str, hint: &str) -> Option<String> {
    match std::env::var(var) {
        Ok(value) if !value.is_empty() => Some(value),
        _ => {
            let message = format!("skipped {what}: {hint}");
            assert!(std::env::var_os("CI").is_none(), "CI is set: {message}");
            println!("{message}");
            None
        }
    }
}

/// The Python with numpy (`MODE360_PYTHON`), or `None` after saying why `what` is skipped.
pub fn python_with_numpy(what: &str) -> Option<String> {
    tool_from_env(
        PYTHON_ENV,
        what,
        &format!("set {PYTHON_ENV} to a Python with numpy (tests/interop/setup.sh)"),
    )
}

/// Serializes the tests that run a live node over DDS: each binary used to run alone, and two
/// nodes doing inference at once on a small CI machine would stretch their timeouts.
pub fn live_node_lock() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Reliable QoS keeping the last 10 samples, for test publishers and listeners.
pub fn reliable_qos() -> ros2_client::QosProfile {
    ros2_client::QosProfile::publisher_default()
        .history(ros2_client::qos::History::KeepLast { depth: 10 })
}

/// Numeric references shared with `mode360-model`'s own tests (one file, both binaries).
#[path = "../../crates/mode360-model/tests/common/numeric.rs"]
mod numeric;
#[allow(unused_imports)] // not every binary uses them
pub use numeric::*;
