//! `/diagnostics` content of the node and of replay: one status per camera (rate, age of the
//! newest image, bad messages with the last reason, whether it is waited for) and one for the
//! pipeline (sync counters, dropped groups, inference latency, degraded cameras).

use mode360_core::sync::{SyncError, SyncStats};
use mode360_health::calibration_drift::CalibrationDrift;
use mode360_health::lens_health::LensHealth;
use mode360_io::msgs::image::ImageMsgError;
use mode360_io::msgs::{DiagnosticArray, DiagnosticStatus, Header, KeyValue};
use std::collections::BTreeMap;

/// Prefix of every status name.
pub const DIAGNOSTIC_PREFIX: &str = "mode360";

/// Why a camera message was dropped; one `/diagnostics` counter each (`bad_<key>`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum BadImageReason {
    /// An image encoding the node does not read.
    Encoding,
    /// Width, height and step do not describe the data.
    Layout,
    /// Fewer data bytes than height x step.
    Truncated,
    /// Too large, or a compressed image that does not decode.
    Undecodable,
    /// Not the size the camera's model takes: an equirectangular camera's image must be 2:1,
    /// a fisheye or dual-fisheye camera's exactly its `image_size`.
    WrongSize,
    /// A stamp older than the camera's previous message (by less than the synchronizer's
    /// reset jump; a larger jump back restarts the synchronizer instead).
    OutOfOrder,
    /// A stamp far ahead of the node's clock or of the other cameras' newest stamps (a
    /// glitch: it would otherwise block the camera until that time).
    StampAhead,
    /// The middleware could not deliver the message (deserialization).
    Transport,
}

impl BadImageReason {
    /// Every reason, in the order of the diagnostics keys.
    pub const ALL: [Self; 8] = [
        Self::Encoding,
        Self::Layout,
        Self::Truncated,
        Self::Undecodable,
        Self::WrongSize,
        Self::OutOfOrder,
        Self::StampAhead,
        Self::Transport,
    ];

    /// The counter's key in `/diagnostics`, without the `bad_` prefix.
    pub fn key(self) -> &'static str {
        match self {
            Self::Encoding => "encoding",
            Self::Layout => "layout",
            Self::Truncated => "truncated",
            Self::Undecodable => "undecodable",
            Self::WrongSize => "wrong_size",
            Self::OutOfOrder => "out_of_order",
            Self::StampAhead => "stamp_ahead",
            Self::Transport => "transport",
        }
    }
}

impl From<&ImageMsgError> for BadImageReason {
    fn from(e: &ImageMsgError) -> Self {
        match e {
            ImageMsgError::UnsupportedEncoding { .. } | ImageMsgError::UnsupportedFormat { .. } => {
                Self::Encoding
            }
            ImageMsgError::StepTooSmall { .. } | ImageMsgError::DataTooLong { .. } => Self::Layout,
            ImageMsgError::DataTooShort { .. } => Self::Truncated,
            ImageMsgError::TooManyPixels { .. } => Self::WrongSize,
            _ => Self::Undecodable,
        }
    }
}

impl From<&SyncError> for BadImageReason {
    fn from(e: &SyncError) -> Self {
        match e {
            SyncError::OutOfOrder { .. } => Self::OutOfOrder,
            SyncError::Ahead { .. } => Self::StampAhead,
            SyncError::NoSuchStream { .. } => Self::Transport,
        }
    }
}

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
    /// Messages dropped as malformed (encoding, size, truncation, out-of-order stamps) or
    /// stamped far ahead.
    pub bad_messages: u64,
    /// Reason of the newest bad message.
    pub last_bad_reason: Option<String>,
    /// Kind of the newest bad message.
    pub last_bad_kind: Option<BadImageReason>,
    /// Messages dropped, by reason.
    pub bad_by_reason: BTreeMap<BadImageReason, u64>,
    /// Bad messages since the newest good one (0 after a good message).
    pub bad_since_good: u64,
    /// The lens check's latest finding (`None` before the first complete group).
    pub lens: Option<LensHealth>,
    /// The calibration drift check's latest finding (`None` before its first check).
    pub calibration: Option<CalibrationDrift>,
    /// Times this camera's stamp jumped back and restarted the synchronizer.
    pub clock_jumps_back: u64,
    /// Size of the newest such jump, seconds.
    pub last_clock_jump_s: Option<f64>,
}

impl CameraHealth {
    /// Counts a dropped message.
    pub fn record_bad(&mut self, reason: BadImageReason, detail: String) {
        self.bad_messages += 1;
        self.bad_since_good += 1;
        *self.bad_by_reason.entry(reason).or_insert(0) += 1;
        self.last_bad_reason = Some(detail);
        self.last_bad_kind = Some(reason);
    }

    /// Counts a jump back of this camera's stamps by `jump_s` seconds (a synchronizer reset).
    pub fn record_clock_jump(&mut self, jump_s: f64) {
        self.clock_jumps_back += 1;
        self.last_clock_jump_s = Some(jump_s);
    }

    /// Counts a good message.
    pub fn record_good(&mut self) {
        self.received += 1;
        self.bad_since_good = 0;
    }

    /// True when everything the camera sent lately was dropped: it is not silent, its
    /// images are malformed.
    pub fn only_malformed(&self) -> bool {
        self.bad_since_good > 0 && (!self.active || self.received == 0)
    }
}

/// Health of the whole node.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeHealth {
    pub cameras: Vec<CameraHealth>,
    pub sync: SyncStats,
    /// Groups run through the pipeline.
    pub groups_processed: u64,
    /// Complete groups replaced in the 1-slot mailbox by a newer one before inference.
    pub groups_dropped: u64,
    /// Processed groups whose point cloud was not built: `points` had no subscriber.
    pub clouds_skipped: u64,
    /// Groups the pipeline failed on.
    pub pipeline_errors: u64,
    pub last_pipeline_error: Option<String>,
    /// Latency of the newest processed group, milliseconds.
    pub last_latency_ms: Option<f64>,
    /// Mean latency over all processed groups, milliseconds.
    pub mean_latency_ms: Option<f64>,
    /// Groups the inference worker took from its mailbox (the live node).
    pub groups_taken: u64,
    /// Mean time a group waited in the mailbox for the worker, milliseconds (the live node;
    /// `None` in replay and before the first group). Beside `mean_latency_ms` it says where a
    /// group's time goes: waiting behind the previous group or being processed.
    pub mean_mailbox_wait_ms: Option<f64>,
    /// A camera whose blocked fraction exceeds this is WARN (ERROR above
    /// [`LENS_ERROR_FRACTION`]); the `lens_warn_fraction` parameter.
    pub lens_warn_fraction: f64,
    /// The camera the drift check suspects is WARN when its correction exceeds this, degrees;
    /// the `calibration_warn_deg` parameter.
    pub calibration_warn_deg: f64,
    /// When the newest depth went out (the live node; `None` before the first).
    pub last_depth_at: Option<std::time::Instant>,
    /// Seconds since depth last went out, or since the node started before the first; `None`
    /// where it is not measured (replay). Above [`NO_DEPTH_ERROR_S`] the pipeline is ERROR.
    pub depth_age_s: Option<f64>,
}

/// The pipeline status is ERROR when no depth went out for longer than this, seconds, or
/// than [`NO_DEPTH_LATENCIES`] times the mean latency when that is longer (a slow estimator
/// is not a stall).
pub const NO_DEPTH_ERROR_S: f64 = 3.0;
/// See [`NO_DEPTH_ERROR_S`].
pub const NO_DEPTH_LATENCIES: f64 = 3.0;

/// Blocked fraction above which a camera is ERROR whatever the warning threshold.
pub const LENS_ERROR_FRACTION: f64 = 0.5;
/// Default of the `lens_warn_fraction` parameter.
pub const DEFAULT_LENS_WARN_FRACTION: f64 = 0.15;
/// Default of the `calibration_warn_deg` parameter.
pub const DEFAULT_CALIBRATION_WARN_DEG: f64 = 0.3;

impl Default for NodeHealth {
    fn default() -> Self {
        Self {
            cameras: Vec::new(),
            sync: SyncStats::default(),
            groups_processed: 0,
            groups_dropped: 0,
            clouds_skipped: 0,
            pipeline_errors: 0,
            last_pipeline_error: None,
            last_latency_ms: None,
            mean_latency_ms: None,
            groups_taken: 0,
            mean_mailbox_wait_ms: None,
            lens_warn_fraction: DEFAULT_LENS_WARN_FRACTION,
            calibration_warn_deg: DEFAULT_CALIBRATION_WARN_DEG,
            last_depth_at: None,
            depth_age_s: None,
        }
    }
}

impl NodeHealth {
    /// Takes the pipeline's lens findings (rig order) into the cameras' health.
    pub fn record_lens(&mut self, lens: &[LensHealth]) {
        for (cam, health) in self.cameras.iter_mut().zip(lens) {
            cam.lens = Some(health.clone());
        }
    }

    /// Takes the pipeline's calibration drift findings (rig order) into the cameras' health.
    pub fn record_calibration(&mut self, drift: &[CalibrationDrift]) {
        for (cam, d) in self.cameras.iter_mut().zip(drift) {
            cam.calibration = Some(d.clone());
        }
    }

    /// The health of a node starting on these cameras (`(name, topic)` in rig order), each
    /// active and nothing counted yet.
    pub fn of_cameras<'a>(cameras: impl IntoIterator<Item = (&'a str, String)>) -> Self {
        Self {
            cameras: cameras
                .into_iter()
                .map(|(name, topic)| CameraHealth {
                    name: name.to_string(),
                    topic,
                    active: true,
                    ..Default::default()
                })
                .collect(),
            ..Default::default()
        }
    }

    /// Counts a group whose depth went out now, run through the pipeline in `latency` (the
    /// node and `replay` both keep their books with this and [`Self::record_checks`]);
    /// `cloud_built`: false when the cloud was skipped for want of a subscriber.
    pub fn record_group(&mut self, latency: std::time::Duration, cloud_built: bool) {
        self.record_processed(latency.as_secs_f64() * 1e3);
        self.clouds_skipped += u64::from(!cloud_built);
        self.last_depth_at = Some(std::time::Instant::now());
    }

    /// Counts a group the worker took from the mailbox after it waited there `wait` (the
    /// running mean over every group taken).
    pub fn record_mailbox_wait(&mut self, wait: std::time::Duration) {
        self.groups_taken += 1;
        let ms = wait.as_secs_f64() * 1e3;
        self.mean_mailbox_wait_ms = Some(running_mean(
            self.mean_mailbox_wait_ms,
            self.groups_taken,
            ms,
        ));
    }

    /// Takes a group's rig health checks (rig order) into the cameras' health.
    pub fn record_checks(&mut self, lens: &[LensHealth], drift: &[CalibrationDrift]) {
        self.record_lens(lens);
        self.record_calibration(drift);
    }

    /// Counts a group run through the pipeline in `latency_ms` (the newest latency and the
    /// running mean over every processed group).
    pub fn record_processed(&mut self, latency_ms: f64) {
        self.groups_processed += 1;
        self.mean_latency_ms = Some(running_mean(
            self.mean_latency_ms,
            self.groups_processed,
            latency_ms,
        ));
        self.last_latency_ms = Some(latency_ms);
    }

    /// One line for a person: groups processed and lost, images per camera, and what the
    /// synchronizer dropped and why ("groups: 3 processed, 1 replaced, 0 failed; images
    /// received: cam1 4, ...; dropped by sync: 1 unmatched, 0 far ahead, ...").
    pub fn summary(&self) -> String {
        let cams: Vec<String> = self
            .cameras
            .iter()
            .map(|c| format!("{} {}", c.name, c.received))
            .collect();
        let bad: u64 = self.cameras.iter().map(|c| c.bad_messages).sum();
        let s = &self.sync;
        format!(
            "groups: {} processed (mean latency {} ms), {} replaced by a newer one, {} failed; \
             images received: {}; \
             malformed: {bad}; dropped by sync: {} unmatched, {} far ahead, {} out of order, \
             {} queue overflow; clock resets: {}",
            self.groups_processed,
            opt_ms(self.mean_latency_ms),
            self.groups_dropped,
            self.pipeline_errors,
            cams.join(", "),
            s.unmatched,
            s.ahead,
            s.out_of_order,
            s.overflow,
            s.resets
        )
    }
}

fn kv(key: &str, value: impl ToString) -> KeyValue {
    KeyValue {
        key: key.to_string(),
        value: value.to_string(),
    }
}

/// The mean of `count` values, `mean` being that of the first `count - 1` (`None`: none yet)
/// and `x` the newest: `mean + (x - mean) / count`.
fn running_mean(mean: Option<f64>, count: u64, x: f64) -> f64 {
    let mean = mean.unwrap_or(0.0);
    mean + (x - mean) / count as f64
}

fn opt_ms(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.1}"))
}

/// The level and message of a camera whose lens looks blocked (`None` when it looks clear).
fn lens_status(cam: &CameraHealth, warn_fraction: f64) -> Option<(u8, String)> {
    let lens = cam.lens.as_ref()?;
    let level = if lens.blocked_fraction > LENS_ERROR_FRACTION {
        DiagnosticStatus::ERROR
    } else if lens.blocked_fraction > warn_fraction {
        DiagnosticStatus::WARN
    } else {
        return None;
    };
    Some((
        level,
        format!(
            "lens looks blocked or soiled: {:.0} % of its view ({} of its view)",
            100.0 * lens.blocked_fraction,
            lens.region.as_deref().unwrap_or("unknown part")
        ),
    ))
}

/// The level and message of the camera the drift check suspects, when turning it by more than
/// `warn_deg` would make the cameras agree better (`None` otherwise).
fn calibration_status(cam: &CameraHealth, warn_deg: f64) -> Option<(u8, String)> {
    let drift = cam.calibration.as_ref()?;
    (drift.suspect && drift.correction_deg > warn_deg).then(|| {
        (
            DiagnosticStatus::WARN,
            format!(
                "calibration looks off: turning this camera by {:.2} deg would make it agree \
                 with the others (mode360 rig refine)",
                drift.correction_deg
            ),
        )
    })
}

/// The `/diagnostics` message of `health` stamped `stamp_ns`.
pub fn diagnostic_array(stamp_ns: u64, hardware_id: &str, health: &NodeHealth) -> DiagnosticArray {
    let mut status: Vec<DiagnosticStatus> = health
        .cameras
        .iter()
        .map(|cam| camera_status(cam, health, hardware_id))
        .collect();
    status.push(pipeline_status(health, hardware_id));
    DiagnosticArray {
        header: Header::new(stamp_ns, ""),
        status,
    }
}

/// One camera's status: its images, then its lens and calibration findings where they are
/// at least as grave.
fn camera_status(cam: &CameraHealth, health: &NodeHealth, hardware_id: &str) -> DiagnosticStatus {
    let (level, message) = if cam.only_malformed() {
        let what = match cam.last_bad_kind {
            Some(BadImageReason::StampAhead) => "images stamped far ahead",
            _ => "malformed images",
        };
        (
            DiagnosticStatus::ERROR,
            format!(
                "sending only {what}: {}",
                cam.last_bad_reason.as_deref().unwrap_or("")
            ),
        )
    } else if !cam.active {
        (DiagnosticStatus::WARN, "timed out, not waited for".into())
    } else if cam.received == 0 {
        (DiagnosticStatus::WARN, "no images yet".into())
    } else if cam.bad_messages > 0 {
        (
            DiagnosticStatus::WARN,
            "receiving, some messages dropped".into(),
        )
    } else {
        (DiagnosticStatus::OK, "receiving".into())
    };
    let (level, message) = match lens_status(cam, health.lens_warn_fraction) {
        Some((lens_level, lens_message)) if lens_level >= level => (lens_level, lens_message),
        _ => (level, message),
    };
    let (level, message) = match calibration_status(cam, health.calibration_warn_deg) {
        Some((cal_level, cal_message)) if cal_level > level => (cal_level, cal_message),
        Some((cal_level, cal_message)) if cal_level == level && level != DiagnosticStatus::OK => {
            (level, format!("{message}; {cal_message}"))
        }
        _ => (level, message),
    };
    let mut values = vec![
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
        kv(
            "blocked_fraction",
            cam.lens
                .as_ref()
                .map_or_else(|| "n/a".into(), |l| format!("{:.3}", l.blocked_fraction)),
        ),
        kv(
            "lens_decided_fraction",
            cam.lens
                .as_ref()
                .map_or_else(|| "n/a".into(), |l| format!("{:.3}", l.decided_fraction)),
        ),
        kv(
            "calibration_correction_deg",
            cam.calibration
                .as_ref()
                .map_or_else(|| "n/a".into(), |d| format!("{:.3}", d.correction_deg)),
        ),
        kv("clock_jumped_back", cam.clock_jumps_back),
        kv(
            "last_clock_jump_s",
            cam.last_clock_jump_s
                .map_or_else(|| "n/a".into(), |j| format!("{j:.3}")),
        ),
    ];
    values.extend(BadImageReason::ALL.iter().map(|r| {
        kv(
            &format!("bad_{}", r.key()),
            cam.bad_by_reason.get(r).copied().unwrap_or(0),
        )
    }));
    DiagnosticStatus {
        level,
        name: format!("{DIAGNOSTIC_PREFIX}: camera {}", cam.name),
        message,
        hardware_id: hardware_id.to_string(),
        values,
    }
}

/// The pipeline's status: ERROR when no depth went out for long, WARN when degraded or failing.
fn pipeline_status(health: &NodeHealth, hardware_id: &str) -> DiagnosticStatus {
    let degraded: Vec<&str> = health
        .cameras
        .iter()
        .filter(|c| !c.active)
        .map(|c| c.name.as_str())
        .collect();
    let stall_s = health.mean_latency_ms.map_or(NO_DEPTH_ERROR_S, |ms| {
        (NO_DEPTH_LATENCIES * ms / 1e3).max(NO_DEPTH_ERROR_S)
    });
    let stalled = health.depth_age_s.filter(|age| *age > stall_s);
    let level = if stalled.is_some() {
        DiagnosticStatus::ERROR
    } else if health.pipeline_errors > 0 || !degraded.is_empty() {
        DiagnosticStatus::WARN
    } else {
        DiagnosticStatus::OK
    };
    let message = match stalled {
        Some(age) => format!("no depth for {age:.1} s: {}", stall_reason(health)),
        None if degraded.is_empty() => "all cameras in use".into(),
        None => format!("degraded: without {}", degraded.join(", ")),
    };
    DiagnosticStatus {
        level,
        name: format!("{DIAGNOSTIC_PREFIX}: pipeline"),
        message,
        hardware_id: hardware_id.to_string(),
        values: vec![
            kv("groups_processed", health.groups_processed),
            kv("groups_dropped_mailbox", health.groups_dropped),
            kv("points_skipped_no_subscriber", health.clouds_skipped),
            kv("sync_groups", health.sync.groups),
            kv("sync_unmatched", health.sync.unmatched),
            kv("sync_overflow", health.sync.overflow),
            kv("sync_out_of_order", health.sync.out_of_order),
            kv("sync_stamp_ahead", health.sync.ahead),
            kv("sync_resets", health.sync.resets),
            kv("pipeline_errors", health.pipeline_errors),
            kv(
                "last_pipeline_error",
                health.last_pipeline_error.as_deref().unwrap_or(""),
            ),
            kv("last_latency_ms", opt_ms(health.last_latency_ms)),
            kv("mean_latency_ms", opt_ms(health.mean_latency_ms)),
            kv("mean_mailbox_wait_ms", opt_ms(health.mean_mailbox_wait_ms)),
            kv("degraded_cameras", degraded.join(",")),
            kv(
                "depth_age_s",
                health
                    .depth_age_s
                    .map_or_else(|| "n/a".into(), |a| format!("{a:.1}")),
            ),
        ],
    }
}

/// Why no depth goes out, as far as the counters tell: cameras dropping every image (with
/// their reason), the last pipeline error, or too few cameras sending.
fn stall_reason(health: &NodeHealth) -> String {
    let dropping: Vec<String> = health
        .cameras
        .iter()
        .filter(|c| c.only_malformed())
        .map(|c| {
            format!(
                "camera '{}' drops every image ({})",
                c.name,
                c.last_bad_reason.as_deref().unwrap_or("bad images")
            )
        })
        .collect();
    if !dropping.is_empty() {
        return dropping.join("; ");
    }
    if let Some(e) = &health.last_pipeline_error {
        return format!("the pipeline fails: {e}");
    }
    let silent: Vec<&str> = health
        .cameras
        .iter()
        .filter(|c| !c.active || c.received == 0)
        .map(|c| c.name.as_str())
        .collect();
    if !silent.is_empty() {
        return format!("no images from {}", silent.join(", "));
    }
    "no complete group of images (see sync_* and the cameras' statuses)".into()
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
mod tests;
