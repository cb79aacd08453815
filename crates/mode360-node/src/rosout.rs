//! The node's log records on `/rosout` (`rcl_interfaces/msg/Log`), as every rclcpp and rclpy
//! node does, so `ros2 topic echo /rosout`, rqt_console and Foxglove's log panel show them.
//!
//! Logging is `tracing`; the binary installs [`RosoutLayer`] (with [`rosout_filter`]) beside
//! its stderr output, and the
//! running node attaches its `/rosout` writer ([`attach`], detached when the returned guard
//! drops). Each event at [`ROSOUT_MIN_LEVEL`] or above becomes one `Log` record: the node's name
//! as the logger name, the message with the event's other fields (`key=value`), the source
//! file, module and line. Events from the DDS stack itself (RustDDS, ros2-client) are not
//! forwarded: publishing one could log again, and they are not the node's. While no node is
//! attached the layer does nothing.

use ros2_client::builtin_interfaces::Time;
use ros2_client::{Log, NodeLoggingHandle, RosoutRaw};
use std::cell::Cell;
use std::fmt::Write as _;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::filter::{LevelFilter, Targets};
use tracing_subscriber::layer::Context;
use tracing_subscriber::Layer;

/// The least severe level forwarded (rclcpp's default logger level is INFO).
pub const ROSOUT_MIN_LEVEL: Level = Level::INFO;
/// Targets never forwarded: the DDS stack publishing the records.
const DDS_TARGETS: [&str; 2] = ["rustdds", "ros2_client"];

/// How long detaching waits after the last record was published, so that the writer sends
/// it before the node goes (RustDDS sends from its own thread; a record logged just before
/// shutdown, such as "SIGINT: shutting down", is otherwise lost with the participant).
pub const ROSOUT_LINGER: Duration = Duration::from_millis(200);

/// When the last record was published.
static LAST_PUBLISHED: Mutex<Option<Instant>> = Mutex::new(None);

/// The attached node: its `/rosout` writer and logger name.
struct Attached {
    handle: NodeLoggingHandle,
    name: String,
}

/// The node attached to every [`RosoutLayer`] of the process (one node runs per process).
static ATTACHED: Mutex<Option<Arc<Attached>>> = Mutex::new(None);

thread_local! {
    /// Set while this thread publishes a record, so nothing logged meanwhile loops back.
    static PUBLISHING: Cell<bool> = const { Cell::new(false) };
}

/// Detaches the node from `/rosout` when dropped.
#[must_use = "the node is detached from /rosout when the guard drops"]
pub struct RosoutGuard(());

impl Drop for RosoutGuard {
    fn drop(&mut self) {
        let last = LAST_PUBLISHED.lock().ok().and_then(|t| *t);
        if let Some(left) = last.and_then(|t| ROSOUT_LINGER.checked_sub(t.elapsed())) {
            std::thread::sleep(left);
        }
        if let Ok(mut slot) = ATTACHED.lock() {
            *slot = None;
        }
    }
}

/// Sends the process's log records to `/rosout` through `handle` (the node's, created with
/// `enable_rosout`), under the logger name `name` (the node's name, as rclcpp's logger is).
pub fn attach(handle: NodeLoggingHandle, name: impl Into<String>) -> RosoutGuard {
    if let Ok(mut slot) = ATTACHED.lock() {
        *slot = Some(Arc::new(Attached {
            handle,
            name: name.into(),
        }));
    }
    RosoutGuard(())
}

/// What [`RosoutLayer`] should see, as a per-layer filter: [`ROSOUT_MIN_LEVEL`] and above,
/// nothing of the DDS stack (so their debug events cost nothing while the node runs).
pub fn rosout_filter() -> Targets {
    DDS_TARGETS.iter().fold(
        Targets::new().with_default(ROSOUT_MIN_LEVEL),
        |targets, target| targets.with_target(*target, LevelFilter::OFF),
    )
}

/// rcl's logger name of node `name` in `namespace`: the namespace's parts and the name joined
/// by dots (`/robot/front`, `mode360` -> `robot.front.mode360`; `/` -> `mode360`).
pub fn logger_name(namespace: &str, name: &str) -> String {
    namespace
        .split('/')
        .filter(|part| !part.is_empty())
        .chain(std::iter::once(name))
        .collect::<Vec<_>>()
        .join(".")
}

/// ROS 2's severity byte of a tracing level (`rcl_interfaces/msg/Log`'s constants).
pub fn ros_level(level: &Level) -> u8 {
    match *level {
        Level::ERROR => Log::ERROR,
        Level::WARN => Log::WARN,
        Level::INFO => Log::INFO,
        Level::DEBUG | Level::TRACE => Log::DEBUG,
    }
}

/// The `tracing` layer that forwards events to the attached node's `/rosout`.
#[derive(Clone, Copy, Debug, Default)]
pub struct RosoutLayer;

/// The event's message and its other fields as `key=value`.
#[derive(Default)]
struct MessageText {
    message: String,
    fields: String,
}

impl Visit for MessageText {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.message.push_str(value);
        } else {
            let _ = write!(self.fields, " {}={value}", field.name());
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.message, "{value:?}");
        } else {
            let _ = write!(self.fields, " {}={value:?}", field.name());
        }
    }
}

impl<S: Subscriber> Layer<S> for RosoutLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        if *meta.level() > ROSOUT_MIN_LEVEL
            || DDS_TARGETS.iter().any(|t| meta.target().starts_with(t))
            || PUBLISHING.with(Cell::get)
        {
            return;
        }
        let Some(attached) = ATTACHED.lock().ok().and_then(|slot| slot.clone()) else {
            return;
        };
        let writer = attached.handle.rosout_writer();
        let Some(writer) = writer.as_ref() else {
            return;
        };
        let mut text = MessageText::default();
        event.record(&mut text);
        let record = Log {
            stamp: Time::now(),
            level: ros_level(meta.level()),
            name: attached.name.clone(),
            msg: text.message + &text.fields,
            file: meta.file().unwrap_or_default().to_string(),
            function: meta.module_path().unwrap_or(meta.target()).to_string(),
            line: meta.line().unwrap_or(0),
        };
        PUBLISHING.with(|p| p.set(true));
        // A record that cannot be sent is dropped: logging must never stop the node.
        let _ = writer.publish(record);
        PUBLISHING.with(|p| p.set(false));
        if let Ok(mut last) = LAST_PUBLISHED.lock() {
            *last = Some(Instant::now());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logger_names_follow_rcl() {
        assert_eq!(logger_name("/", "mode360"), "mode360");
        assert_eq!(logger_name("", "mode360"), "mode360");
        assert_eq!(logger_name("/robot/front", "depth"), "robot.front.depth");
    }

    #[test]
    fn levels_map_to_the_log_message_constants() {
        assert_eq!(ros_level(&Level::ERROR), 40);
        assert_eq!(ros_level(&Level::WARN), 30);
        assert_eq!(ros_level(&Level::INFO), 20);
        assert_eq!(ros_level(&Level::DEBUG), 10);
        assert_eq!(ros_level(&Level::TRACE), 10);
    }
}
