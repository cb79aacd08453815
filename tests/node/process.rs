//! The `mode360 node` binary as a process (loopback DDS, own domain): a bag played twice in a
//! loop (restamped) with `/clock` into a node with `use_sim_time`; depth must come back for
//! frames of both repetitions, `/diagnostics` must be stamped and aged in simulated time, and
//! SIGINT must stop the process cleanly (exit code 0, within seconds) with a summary line whose
//! counters agree with what was sent and received.

use super::harness::{loopback, record_street_bag};
use super::node_process::NodeProcess;
use crate::common::TestResult;
use mode360::bag::RigBagReader;
use mode360::geometry::Rig;
use mode360::msgs::{DiagnosticArray, Image};
use mode360::node::diagnostics::diagnostic_value;
use mode360::node::player::{play_bag, PlayOptions};
use mode360::node::{create_subscription, dds_context, SpunNode};
use ros2_client::qos::History;
use ros2_client::QosProfile;
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

const MANIFEST_DIR: &str = env!("CARGO_MANIFEST_DIR");
/// Unique domain of this test file.
const DOMAIN_ID: u16 = 45;
const WIDTH: usize = 64;
const FRAMES: usize = 2;
const LOOPS: usize = 2;
/// Frames 0.5 s apart: inference at 64 px keeps up even on a loaded machine.
const PLAY_RATE: f64 = 0.2;
const UP_TIMEOUT: Duration = Duration::from_secs(60);
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(15);
const RECEIVE_TIMEOUT: Duration = Duration::from_secs(30);
/// The process must be gone this soon after SIGINT.
const EXIT_LIMIT: Duration = Duration::from_secs(5);
/// A `/diagnostics` message this long after the bag ended: with wall time its camera ages
/// would be at least this; with simulated time (the clock stopped with the bag) about 0.
const AGE_PROBE_DELAY: Duration = Duration::from_millis(1500);
const MAX_SIM_AGE_SECS: f64 = 0.2;
const POLL: Duration = Duration::from_millis(20);

#[test]
fn node_binary_follows_looped_bag_in_sim_time_and_stops_on_sigint() -> TestResult {
    let _one_node_at_a_time = crate::common::live_node_lock();
    let dir = tempfile::tempdir()?;
    let rig_path = format!("{MANIFEST_DIR}/launch_configs/rig_deep360.yaml");
    let rig = Rig::from_file(&rig_path)?;
    let bag_path = dir.path().join("in.mcap");
    record_street_bag(&rig, 3, WIDTH, FRAMES, &bag_path)?;
    let params_path = dir.path().join("params.yaml");
    std::fs::write(
        &params_path,
        format!(
            "mode360:\n  ros__parameters:\n    rig_file: {rig_path}\n    output_width: {WIDTH}\n\
             \x20   use_sim_time: true\n    camera_timeout_s: 30.0\n"
        ),
    )?;

    let node = NodeProcess::spawn(&params_path, DOMAIN_ID, UP_TIMEOUT)?;

    let dds = loopback(DOMAIN_ID);
    let context = dds_context(&dds)?;
    let mut listener = SpunNode::new(&context, "/", "mode360_process_test_listener")?;
    let qos = QosProfile::publisher_default().history(History::KeepLast { depth: 10 });
    let depth_sub = create_subscription::<Image>(&mut listener.node, "/depth", qos.clone())?;
    let diag_sub = create_subscription::<DiagnosticArray>(&mut listener.node, "/diagnostics", qos)?;
    let t0 = Instant::now();
    while depth_sub.get_publisher_count(&listener.node) == 0 && t0.elapsed() < DISCOVERY_TIMEOUT {
        std::thread::sleep(POLL);
    }

    let played = play_bag(&PlayOptions {
        input: bag_path.clone(),
        rate: PLAY_RATE,
        loops: LOOPS,
        publish_clock: true,
        dds: dds.clone(),
        wait_for_subscribers: Some(DISCOVERY_TIMEOUT),
        wait_topics: rig.cameras.iter().map(|c| c.topic.clone()).collect(),
    })?;
    let play_end = Instant::now();
    for cam in &rig.cameras {
        assert_eq!(
            played.published.get(&cam.topic),
            Some(&((FRAMES * LOOPS) as u64))
        );
    }
    assert_eq!(played.loops_played, LOOPS);
    let timing = played.timing.ok_or("no loop timing")?;
    // The synthetic bag: 10 Hz frames, so one repetition is shifted by (FRAMES - 1 + 1) x 100 ms.
    assert_eq!(timing.period_ns, 100_000_000);
    assert_eq!(timing.offset_ns(1), FRAMES as u64 * 100_000_000);
    let bag_stamps: BTreeSet<u64> = RigBagReader::open(&bag_path)?
        .frames()
        .map(|f| f.map(|f| f.stamp_ns))
        .collect::<Result<_, _>>()?;
    assert_eq!(bag_stamps.len(), FRAMES);
    let loop_of = |stamp: u64| -> Option<usize> {
        (0..LOOPS).find(|&k| {
            stamp
                .checked_sub(timing.offset_ns(k))
                .is_some_and(|s| bag_stamps.contains(&s))
        })
    };
    let last_sim_ns = timing.first_ns + timing.offset_ns(LOOPS - 1) + timing.duration_ns;

    // Depth for both repetitions, and a /diagnostics message well after the bag ended.
    let mut depth_stamps: BTreeSet<u64> = BTreeSet::new();
    let mut diags: Vec<(Instant, DiagnosticArray)> = Vec::new();
    let t0 = Instant::now();
    let done = |stamps: &BTreeSet<u64>, diags: &[(Instant, DiagnosticArray)]| {
        let loops: BTreeSet<usize> = stamps.iter().filter_map(|&s| loop_of(s)).collect();
        loops.len() == LOOPS && diags.iter().any(|(t, _)| *t >= play_end + AGE_PROBE_DELAY)
    };
    while !done(&depth_stamps, &diags) && t0.elapsed() < RECEIVE_TIMEOUT {
        while let Some((m, _)) = depth_sub.take()? {
            depth_stamps.insert(m.header.stamp.to_nanos());
        }
        while let Some((m, _)) = diag_sub.take()? {
            diags.push((Instant::now(), m));
        }
        std::thread::sleep(POLL);
    }
    for &s in &depth_stamps {
        assert!(loop_of(s).is_some(), "depth stamp {s} is no played stamp");
    }
    let loops_seen: BTreeSet<usize> = depth_stamps.iter().filter_map(|&s| loop_of(s)).collect();
    assert_eq!(
        loops_seen.len(),
        LOOPS,
        "depth only for repetitions {loops_seen:?}: {depth_stamps:?}"
    );
    // Simulated time: diagnostics stamps lie inside the bag's (restamped) time, not today.
    let sim_stamped: Vec<u64> = diags
        .iter()
        .map(|(_, d)| d.header.stamp.to_nanos())
        .filter(|&s| s != 0)
        .collect();
    assert!(
        !sim_stamped.is_empty(),
        "no diagnostics after the first /clock"
    );
    for &s in &sim_stamped {
        assert!(
            s >= timing.first_ns && s <= last_sim_ns,
            "diagnostics stamp {s} outside [{}, {last_sim_ns}]",
            timing.first_ns
        );
    }
    let (_, late) = diags
        .iter()
        .rev()
        .find(|(t, _)| *t >= play_end + AGE_PROBE_DELAY)
        .ok_or("no diagnostics after the bag ended")?;
    assert_eq!(late.header.stamp.to_nanos(), last_sim_ns);
    for cam in &rig.cameras {
        let age: f64 = diagnostic_value(late, &format!("mode360: camera {}", cam.name), "age_s")
            .ok_or("no age_s")?
            .parse()?;
        assert!(age <= MAX_SIM_AGE_SECS, "{}: age {age} s", cam.name);
    }

    // SIGINT: clean exit with a summary.
    let exit = node.interrupt(EXIT_LIMIT)?;
    println!(
        "exit after {:.2} s: {:?}; stdout: {}",
        exit.exit_s, exit.status, exit.stdout
    );
    assert_eq!(exit.status.code(), Some(0), "stderr: {:#?}", exit.log);
    while let Some((m, _)) = depth_sub.take()? {
        depth_stamps.insert(m.header.stamp.to_nanos());
    }
    let summary = exit.summary()?;
    let line = summary.line.as_str();
    let get = |k: &str| summary.get(k);
    let groups = (FRAMES * LOOPS) as u64;
    let n_cams = rig.cameras.len() as u64;
    let images = groups * n_cams;
    // Looped frames are not rejected as out of order (that would count as bad).
    assert_eq!(get("images_bad")?, 0, "{line}");
    assert_eq!(get("pipeline_errors")?, 0, "{line}");
    // Camera images are best effort: on a loaded machine one may be lost, which leaves its
    // partners unmatched. Every image received is in a group, unmatched, or still queued.
    assert!(get("images_in")? <= images, "{line}");
    assert!(get("frames_in")? <= groups, "{line}");
    assert!(get("frames_in")? >= LOOPS as u64, "{line}");
    assert!(
        get("frames_in")? * n_cams + get("images_unmatched")? <= get("images_in")?,
        "{line}"
    );
    assert_eq!(
        get("frames_out")? + get("frames_dropped")?,
        get("frames_in")?,
        "{line}"
    );
    // Every published depth reached the (reliable) listener.
    assert_eq!(get("frames_out")?, depth_stamps.len() as u64, "{line}");

    drop(depth_sub);
    drop(diag_sub);
    listener.stop()?;
    Ok(())
}
