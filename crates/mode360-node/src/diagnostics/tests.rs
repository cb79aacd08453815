//! Tests of the parent module.

use super::*;

#[test]
fn a_camera_sending_only_malformed_images_is_malformed_not_silent() {
    let mut cam = CameraHealth {
        name: "cam3".into(),
        active: true,
        ..Default::default()
    };
    cam.record_good();
    cam.record_bad(
        BadImageReason::Encoding,
        "unsupported encoding 'yuv422'".into(),
    );
    assert!(
        !cam.only_malformed(),
        "active with a good image: some dropped"
    );
    cam.active = false;
    cam.record_bad(
        BadImageReason::Encoding,
        "unsupported encoding 'yuv422'".into(),
    );
    cam.record_bad(BadImageReason::Truncated, "truncated".into());
    assert!(cam.only_malformed());
    let health = NodeHealth {
        cameras: vec![cam.clone()],
        ..Default::default()
    };
    let array = diagnostic_array(1, "test", &health);
    let status = &array.status[0];
    assert_eq!(status.level, DiagnosticStatus::ERROR);
    assert_eq!(status.message, "sending only malformed images: truncated");
    assert_eq!(
        diagnostic_value(&array, "mode360: camera cam3", "bad_encoding"),
        Some("2")
    );
    assert_eq!(
        diagnostic_value(&array, "mode360: camera cam3", "bad_truncated"),
        Some("1")
    );
    assert_eq!(
        diagnostic_value(&array, "mode360: camera cam3", "bad_layout"),
        Some("0")
    );
    cam.record_good();
    assert_eq!(
        (cam.bad_since_good, cam.bad_messages, cam.received),
        (0, 3, 2)
    );
    assert!(!cam.only_malformed());
}

#[test]
fn stamps_ahead_and_clock_jumps_are_named_not_malformed() {
    let error = SyncError::Ahead {
        stream: 0,
        stamp_ns: 3_600_000_000_000,
        reference: mode360_core::sync::TimeReference::Receipt,
        reference_ns: 0,
    };
    let reason = BadImageReason::from(&error);
    assert_eq!(reason, BadImageReason::StampAhead);
    let mut cam = CameraHealth {
        name: "cam2".into(),
        active: true,
        ..Default::default()
    };
    cam.record_bad(reason, error.to_string());
    cam.record_clock_jump(20.0);
    let health = NodeHealth {
        cameras: vec![cam],
        sync: SyncStats {
            ahead: 1,
            resets: 1,
            ..Default::default()
        },
        ..Default::default()
    };
    let array = diagnostic_array(1, "test", &health);
    let status = &array.status[0];
    assert_eq!(status.level, DiagnosticStatus::ERROR);
    assert!(
        status
            .message
            .starts_with("sending only images stamped far ahead: stream 0: stamp"),
        "{}",
        status.message
    );
    let value = |name: &str, key: &str| diagnostic_value(&array, name, key);
    assert_eq!(value("mode360: camera cam2", "bad_stamp_ahead"), Some("1"));
    assert_eq!(value("mode360: camera cam2", "bad_out_of_order"), Some("0"));
    assert_eq!(
        value("mode360: camera cam2", "clock_jumped_back"),
        Some("1")
    );
    assert_eq!(
        value("mode360: camera cam2", "last_clock_jump_s"),
        Some("20.000")
    );
    assert_eq!(value("mode360: pipeline", "sync_stamp_ahead"), Some("1"));
    assert_eq!(value("mode360: pipeline", "sync_resets"), Some("1"));
}

#[test]
fn statuses_carry_counters_and_levels() {
    let health = NodeHealth {
        cameras: vec![
            CameraHealth {
                name: "cam1".into(),
                received: 10,
                rate_hz: 9.5,
                active: true,
                ..Default::default()
            },
            CameraHealth {
                name: "cam2".into(),
                received: 3,
                active: false,
                bad_messages: 2,
                last_bad_reason: Some("unsupported encoding '16UC1'".into()),
                ..Default::default()
            },
        ],
        groups_dropped: 4,
        last_latency_ms: Some(12.34),
        ..Default::default()
    };
    let a = diagnostic_array(7, "rig", &health);
    assert_eq!(a.status.len(), 3);
    assert_eq!(a.status[0].level, DiagnosticStatus::OK);
    assert_eq!(a.status[1].level, DiagnosticStatus::WARN);
    assert_eq!(a.status[2].level, DiagnosticStatus::WARN);
    assert_eq!(
        diagnostic_value(&a, "mode360: camera cam2", "bad_messages"),
        Some("2")
    );
    assert_eq!(
        diagnostic_value(&a, "mode360: pipeline", "degraded_cameras"),
        Some("cam2")
    );
    assert_eq!(
        diagnostic_value(&a, "mode360: pipeline", "groups_dropped_mailbox"),
        Some("4")
    );
    assert_eq!(
        diagnostic_value(&a, "mode360: pipeline", "last_latency_ms"),
        Some("12.3")
    );
}

#[test]
fn a_blocked_lens_turns_warn_then_error_naming_where() {
    let status = |fraction: f64| {
        let mut health = NodeHealth {
            cameras: vec![CameraHealth {
                name: "cam3".into(),
                active: true,
                received: 5,
                ..Default::default()
            }],
            ..Default::default()
        };
        health.record_lens(&[LensHealth {
            blocked_fraction: fraction,
            decided_fraction: 1.0,
            region: Some("middle front".into()),
        }]);
        let array = diagnostic_array(1, "test", &health);
        let s = array.status[0].clone();
        let value = diagnostic_value(&array, &s.name, "blocked_fraction").map(String::from);
        (s.level, s.message, value)
    };
    let (level, message, value) = status(0.05);
    assert_eq!(
        (level, message.as_str()),
        (DiagnosticStatus::OK, "receiving")
    );
    assert_eq!(value.as_deref(), Some("0.050"));
    let (level, message, _) = status(0.3);
    assert_eq!(level, DiagnosticStatus::WARN);
    assert!(
        message.contains("blocked") && message.contains("30 %") && message.contains("middle front"),
        "{message}"
    );
    assert_eq!(status(0.6).0, DiagnosticStatus::ERROR);
    let fresh = diagnostic_array(
        1,
        "test",
        &NodeHealth {
            cameras: vec![CameraHealth::default()],
            ..Default::default()
        },
    );
    assert_eq!(
        diagnostic_value(&fresh, &fresh.status[0].name, "blocked_fraction"),
        Some("n/a")
    );
}

#[test]
fn a_stalled_pipeline_is_error_with_the_reason() {
    let camera = |name: &str, received: u64| CameraHealth {
        name: name.into(),
        active: true,
        received,
        ..Default::default()
    };
    let pipeline = |h: &NodeHealth| {
        diagnostic_array(0, "hw", h)
            .status
            .into_iter()
            .find(|s| s.name == "mode360: pipeline")
            .expect("pipeline status")
    };
    let mut health = NodeHealth {
        cameras: vec![camera("a", 10), camera("b", 0)],
        depth_age_s: Some(1.0),
        ..Default::default()
    };
    // Recent depth: not an error.
    assert_ne!(pipeline(&health).level, DiagnosticStatus::ERROR);
    // No depth for 5 s: ERROR, naming the silent camera.
    health.depth_age_s = Some(5.0);
    let s = pipeline(&health);
    assert_eq!(s.level, DiagnosticStatus::ERROR);
    assert_eq!(s.message, "no depth for 5.0 s: no images from b");
    // A pipeline error is the reason before silence.
    health.last_pipeline_error = Some("sizes".into());
    assert_eq!(
        pipeline(&health).message,
        "no depth for 5.0 s: the pipeline fails: sizes"
    );
    // A slow estimator (2 s a group) is not a stall at 5 s.
    health.mean_latency_ms = Some(2000.0);
    assert_ne!(pipeline(&health).level, DiagnosticStatus::ERROR);
    health.mean_latency_ms = None;
    // Not measured (replay): never an error for it.
    health.depth_age_s = None;
    assert_ne!(pipeline(&health).level, DiagnosticStatus::ERROR);
    assert!(pipeline(&health)
        .values
        .iter()
        .any(|kv| kv.key == "depth_age_s" && kv.value == "n/a"));
}

#[test]
fn processed_groups_keep_the_newest_and_the_mean_latency() {
    let mut h = NodeHealth::of_cameras([("cam1", "/cam1/image_raw".to_string())]);
    assert_eq!(
        (h.cameras[0].name.as_str(), h.cameras[0].active),
        ("cam1", true)
    );
    for ms in [300.0, 500.0, 400.0, 1000.0] {
        h.record_processed(ms);
    }
    assert_eq!(h.groups_processed, 4);
    assert_eq!(h.last_latency_ms, Some(1000.0));
    let mean = h.mean_latency_ms.unwrap_or(f64::NAN);
    assert!((mean - 550.0).abs() < 1e-9, "{mean}");
}

#[test]
fn groups_taken_keep_the_mean_mailbox_wait_on_diagnostics() {
    let mut h = NodeHealth::of_cameras([("cam1", "/cam1/image_raw".to_string())]);
    let wait_of = |h: &NodeHealth| {
        let report = diagnostic_array(0, "mode360", h);
        diagnostic_value(&report, "mode360: pipeline", "mean_mailbox_wait_ms").map(str::to_string)
    };
    assert_eq!(h.mean_mailbox_wait_ms, None);
    assert_eq!(wait_of(&h).as_deref(), Some("n/a"));
    for ms in [0, 90, 30] {
        h.record_mailbox_wait(std::time::Duration::from_millis(ms));
    }
    assert_eq!(h.groups_taken, 3);
    let mean = h.mean_mailbox_wait_ms.unwrap_or(f64::NAN);
    assert!((mean - 40.0).abs() < 1e-9, "{mean}");
    assert_eq!(wait_of(&h).as_deref(), Some("40.0"));
}

#[test]
fn the_summary_line_names_every_count() {
    let mut health = NodeHealth::of_cameras([("cam1", "/cam1".into()), ("cam2", "/cam2".into())]);
    health.cameras[0].received = 4;
    health.cameras[1].received = 3;
    health.cameras[1].record_bad(BadImageReason::Truncated, "truncated".into());
    health.record_processed(2000.0);
    health.record_processed(3000.0);
    health.groups_dropped = 1;
    health.sync.unmatched = 2;
    health.sync.ahead = 5;
    health.sync.resets = 1;
    assert_eq!(
        health.summary(),
        "groups: 2 processed (mean latency 2500.0 ms), 1 replaced by a newer one, 0 failed; \
         images received: cam1 4, cam2 3; malformed: 1; dropped by sync: 2 unmatched, \
         5 far ahead, 0 out of order, 0 queue overflow; clock resets: 1"
    );
}
