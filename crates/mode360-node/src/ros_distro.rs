//! Which ROS 2 distribution the node says it works with. ros2-client checks `ROS_DISTRO`
//! against the one it was built for (Jazzy) and logs an ERROR on any other, Kilted included,
//! although the node passes every check with Kilted's rclpy too. mode360 silences that check
//! (`ros2_client::distributions=off` in the default log filter) and says this instead, once at
//! start.

use tracing::Level;

/// Distributions whose rclpy the node was tested against (discovery, types, every output,
/// parameters, /tf_static).
pub const TESTED_DISTROS: [&str; 2] = ["jazzy", "kilted"];

/// What to log for `ROS_DISTRO` = `value`: at which level, and the line.
pub fn distro_note(value: Option<&str>) -> (Level, String) {
    let tested = TESTED_DISTROS.join(" and ");
    match value.map(str::trim) {
        None | Some("") => (
            Level::DEBUG,
            format!("ROS_DISTRO is not set; mode360 speaks ROS 2 as {tested} do"),
        ),
        Some(d) if TESTED_DISTROS.contains(&d.to_ascii_lowercase().as_str()) => (
            Level::DEBUG,
            format!("ROS_DISTRO {d}: tested with this distribution's rclpy"),
        ),
        Some(d) => (
            Level::WARN,
            format!(
                "ROS_DISTRO {d}: mode360 was tested with {tested}; older distributions may not \
                 match its endpoints (type names and QoS are the same, type hashes are not sent)"
            ),
        ),
    }
}

/// Logs [`distro_note`] for the environment's `ROS_DISTRO`.
pub fn log_ros_distro() {
    let value = std::env::var("ROS_DISTRO").ok();
    let (level, line) = distro_note(value.as_deref());
    if level == Level::WARN {
        tracing::warn!("{line}");
    } else {
        tracing::debug!("{line}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jazzy_and_kilted_are_fine_others_warn() {
        assert_eq!(distro_note(Some("kilted")).0, Level::DEBUG);
        assert_eq!(distro_note(Some("Jazzy")).0, Level::DEBUG);
        assert_eq!(distro_note(None).0, Level::DEBUG);
        let (level, line) = distro_note(Some("humble"));
        assert_eq!(level, Level::WARN);
        assert!(
            line.contains("humble") && line.contains("jazzy and kilted"),
            "{line}"
        );
    }
}
