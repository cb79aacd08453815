//! The `mode360 node` binary's log records on `/rosout`, read by a third-party DDS (Eclipse
//! Cyclone DDS through `tests/interop/cyclone_peer.py rosout`, its own IDL type of
//! `rcl_interfaces/msg/Log`): the node started in a namespace with
//! `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` must publish its "up" record and, after SIGINT,
//! its "shutting down" record, each with rcl's logger name (`robot.mode360`), level INFO (20),
//! the source file, module and line; nothing of the DDS stack is forwarded.
//!
//! Needs `MODE360_PYTHON` (a Python with `cyclonedds`); skipped without it unless `CI` is set.

use crate::common::{TestResult, PYTHON_ENV};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const MANIFEST_DIR: &str = env!("CARGO_MANIFEST_DIR");
const PEER_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/interop/cyclone_peer.py");
/// Unique domain of this test file.
const DOMAIN_ID: u16 = 55;
const NAMESPACE: &str = "/robot";
/// rcl's logger name of node `mode360` in [`NAMESPACE`].
const LOGGER: &str = "robot.mode360";
/// `rcl_interfaces/msg/Log`'s INFO.
const INFO: u64 = 20;
const UP_TIMEOUT: Duration = Duration::from_secs(60);
const EXIT_TIMEOUT: Duration = Duration::from_secs(10);
const POLL: Duration = Duration::from_millis(20);

/// Kills the child if the test fails before it exits.
struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Waits for a record whose message contains `text`, collecting every record seen.
fn wait_for(
    lines: &mpsc::Receiver<String>,
    seen: &mut Vec<Value>,
    text: &str,
    timeout: Duration,
) -> Result<Value, Box<dyn std::error::Error>> {
    let t0 = Instant::now();
    loop {
        if let Some(r) = seen
            .iter()
            .find(|r| r["msg"].as_str().unwrap_or("").contains(text))
        {
            return Ok(r.clone());
        }
        let left = timeout.checked_sub(t0.elapsed()).ok_or_else(|| {
            format!("no /rosout record with '{text}' in {timeout:?}; seen: {seen:#?}")
        })?;
        match lines.recv_timeout(left) {
            Ok(line) => seen.push(serde_json::from_str(&line)?),
            Err(_) => continue,
        }
    }
}

fn assert_record(r: &Value, file_tail: &str) {
    assert_eq!(r["name"], LOGGER, "{r}");
    assert_eq!(r["level"].as_u64(), Some(INFO), "{r}");
    assert!(r["file"].as_str().unwrap_or("").ends_with(file_tail), "{r}");
    assert!(r["line"].as_u64().unwrap_or(0) > 0, "{r}");
    assert!(
        r["function"]
            .as_str()
            .unwrap_or("")
            .contains("mode360_node"),
        "{r}"
    );
    assert!(
        r["stamp_ns"].as_u64().unwrap_or(0) > 1_600_000_000_000_000_000,
        "{r}"
    );
}

#[test]
fn node_binary_logs_to_rosout_read_by_cyclone() -> TestResult {
    let Some(python) = std::env::var(PYTHON_ENV).ok().filter(|p| !p.is_empty()) else {
        let hint =
            format!("skipped /rosout interop: {PYTHON_ENV} is not set (tests/interop/setup.sh)");
        assert!(std::env::var_os("CI").is_none(), "CI is set: {hint}");
        println!("{hint}");
        return Ok(());
    };
    let _one_node_at_a_time = crate::common::live_node_lock();
    // The listener first: /rosout keeps only the last record for late joiners.
    let peer = Command::new(python)
        .arg(PEER_SCRIPT)
        .args([
            "rosout",
            "--domain",
            &DOMAIN_ID.to_string(),
            "--timeout-s",
            "90",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()?;
    let mut peer = ChildGuard(peer);
    let stdout = peer.0.stdout.take().ok_or("no peer stdout")?;
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let ready = lines.recv_timeout(UP_TIMEOUT)?;
    assert_eq!(ready, "ready");

    let dir = tempfile::tempdir()?;
    let params = dir.path().join("params.yaml");
    std::fs::write(
        &params,
        format!(
            "/**:\n  ros__parameters:\n    rig_file: {MANIFEST_DIR}/launch_configs/rig_deep360.yaml\n\
             \x20   output_width: 64\n    estimator: photometric\n"
        ),
    )?;
    let node = Command::new(env!("CARGO_BIN_EXE_mode360"))
        .args(["node", "--ros-args", "-r"])
        .arg(format!("__ns:={NAMESPACE}"))
        .arg("--params-file")
        .arg(&params)
        .env("ROS_DOMAIN_ID", DOMAIN_ID.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env_remove("ROS_LOCALHOST_ONLY")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()?;
    let mut node = ChildGuard(node);
    let mut seen = Vec::new();
    let up = wait_for(&lines, &mut seen, " up on domain", UP_TIMEOUT)?;
    assert_record(&up, "run.rs");

    // SAFETY: kill(2) on the pid of our own child process.
    let rc = unsafe { libc::kill(node.0.id() as libc::pid_t, libc::SIGINT) };
    assert_eq!(rc, 0, "kill failed");
    let down = wait_for(&lines, &mut seen, "SIGINT: shutting down", EXIT_TIMEOUT)?;
    assert_record(&down, "run.rs");
    let t0 = Instant::now();
    let status = loop {
        if let Some(status) = node.0.try_wait()? {
            break status;
        }
        if t0.elapsed() > EXIT_TIMEOUT {
            return Err("node still running after SIGINT".into());
        }
        std::thread::sleep(POLL);
    };
    assert!(status.success(), "{status}");
    for r in &seen {
        assert_eq!(r["name"], LOGGER, "{r}");
        let file = r["file"].as_str().unwrap_or("");
        assert!(
            !file.contains("rustdds") && !file.contains("ros2-client"),
            "{r}"
        );
    }
    Ok(())
}
