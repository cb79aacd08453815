//! `/diagnostics` content of the node and of replay: one status per camera (rate, age of the
//! newest image, bad messages with the last reason, whether it is waited for) and one for the
//! pipeline (sync counters, dropped groups, inference latency, degraded cameras).

use crate::msgs::{DiagnosticArray, DiagnosticStatus, Header, KeyValue};
use crate::sync::SyncStats;

/// Prefix of every status name.
pub const DIAGNOSTIC_PREFIX: &str = "mode360";

/// Health of one camera stream.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraHealth {
    pub name: String,
    pub topic: String,
    /// Good messages received in total.
    pub received: u64,
    /// Good messages a second over the last reporting period.
    pub rate_hz: f64,
    /// Seconds since the newest good message (`None` before the first).
    pub age_s: Option<f64>,
    /// False while the camera is timed out and not waited for.
    pub active: bool,
    /// Messages dropped as malformed (encoding, size, truncation, out-of-order stamps).
    pub bad_messages: u64,
    /// Reason of the newest bad message.
    pub last_bad_reason: Option<String>,
}

/// Health of the whole node.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeHealth {
    pub cameras: Vec<CameraHealth>,
    pub sync: SyncStats,
    /// Groups run through the pipeline.
    pub groups_processed: u64,
    /// Complete groups replaced in the 1-slot mailbox by a newer one before inference.
    pub groups_dropped: u64,
    /// Groups the pipeline failed on.
    pub pipeline_errors: u64,
    pub last_pipeline_error: Option<String>,
    /// Latency of the newest processed group, milliseconds.
    pub last_latency_ms: Option<f64>,
    /// Mean latency over all processed groups, milliseconds.
    pub mean_latency_ms: Option<f64>,
}

fn kv(key: &str, value: impl ToString) -> KeyValue {
    KeyValue {
        key: key.to_string(),
        value: value.to_string(),
    }
}

fn opt_ms(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.1}"))
}

/// The `/diagnostics` message of `health` stamped `stamp_ns`.
pub fn diagnostic_array(stamp_ns: u64, hardware_id: &str, health: &NodeHealth) -> DiagnosticArray {
    let mut status = Vec::with_capacity(health.cameras.len() + 1);
    for cam in &health.cameras {
        let (level, message) = if !cam.active {
            (DiagnosticStatus::WARN, "timed out, not waited for")
        } else if cam.received == 0 {
            (DiagnosticStatus::WARN, "no images yet")
        } else if cam.bad_messages > 0 {
            (DiagnosticStatus::WARN, "receiving, some messages dropped")
        } else {
            (DiagnosticStatus::OK, "receiving")
        };
        status.push(DiagnosticStatus {
            level,
            name: format!("{DIAGNOSTIC_PREFIX}: camera {}", cam.name),
            message: message.to_string(),
            hardware_id: hardware_id.to_string(),
            values: vec![
                kv("topic", &cam.topic),
                kv("received", cam.received),
                kv("rate_hz", format!("{:.2}", cam.rate_hz)),
                kv(
                    "age_s",
                    cam.age_s
                        .map_or_else(|| "n/a".into(), |a| format!("{a:.3}")),
                ),
                kv("active", cam.active),
                kv("bad_messages", cam.bad_messages),
                kv(
                    "last_bad_reason",
                    cam.last_bad_reason.as_deref().unwrap_or(""),
                ),
            ],
        });
    }
    let degraded: Vec<&str> = health
        .cameras
        .iter()
        .filter(|c| !c.active)
        .map(|c| c.name.as_str())
        .collect();
    let level = if health.pipeline_errors > 0 || !degraded.is_empty() {
        DiagnosticStatus::WARN
    } else {
        DiagnosticStatus::OK
    };
    status.push(DiagnosticStatus {
        level,
        name: format!("{DIAGNOSTIC_PREFIX}: pipeline"),
        message: if degraded.is_empty() {
            "all cameras in use".into()
        } else {
            format!("degraded: without {}", degraded.join(", "))
        },
        hardware_id: hardware_id.to_string(),
        values: vec![
            kv("groups_processed", health.groups_processed),
            kv("groups_dropped_mailbox", health.groups_dropped),
            kv("sync_groups", health.sync.groups),
            kv("sync_unmatched", health.sync.unmatched),
            kv("sync_overflow", health.sync.overflow),
            kv("sync_out_of_order", health.sync.out_of_order),
            kv("pipeline_errors", health.pipeline_errors),
            kv(
                "last_pipeline_error",
                health.last_pipeline_error.as_deref().unwrap_or(""),
            ),
            kv("last_latency_ms", opt_ms(health.last_latency_ms)),
            kv("mean_latency_ms", opt_ms(health.mean_latency_ms)),
            kv("degraded_cameras", degraded.join(",")),
        ],
    });
    DiagnosticArray {
        header: Header::new(stamp_ns, ""),
        status,
    }
}

/// The value of `key` in the status named `name` (for tests and tools).
pub fn diagnostic_value<'a>(array: &'a DiagnosticArray, name: &str, key: &str) -> Option<&'a str> {
    array
        .status
        .iter()
        .find(|s| s.name == name)?
        .values
        .iter()
        .find(|kv| kv.key == key)
        .map(|kv| kv.value.as_str())
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
