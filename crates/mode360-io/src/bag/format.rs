//! The MCAP layout of ROS 2 bags: profile, encodings, and rosbag2's QoS channel metadata.

/// MCAP profile of ROS 2 bags.
pub const PROFILE: &str = "ros2";
/// MCAP schema encoding of `.msg` text.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// MCAP message encoding of ROS 2 messages.
pub const MESSAGE_ENCODING: &str = "cdr";
/// Channel metadata key rosbag2 uses for the publisher QoS.
pub(super) const QOS_METADATA_KEY: &str = "offered_qos_profiles";
/// rosbag2's QoS durability code of a latched (transient local) publisher.
pub(super) const DURABILITY_TRANSIENT_LOCAL: u8 = 1;
/// rosbag2's QoS durability code of an ordinary (volatile) publisher.
pub(super) const DURABILITY_VOLATILE: u8 = 2;

/// rosbag2 (Humble) QoS YAML: keep-last history, reliable, with the given durability,
/// infinite deadline, lifespan and lease.
pub(super) fn qos_yaml(durability: u8) -> String {
    const INFINITE: &str = "\n    sec: 2147483647\n    nsec: 4294967295";
    format!(
        "- history: 1\n  depth: 1\n  reliability: 1\n  durability: {durability}\n  \
         deadline:{INFINITE}\n  lifespan:{INFINITE}\n  liveliness: 1\n  \
         liveliness_lease_duration:{INFINITE}\n  avoid_ros_namespace_conventions: false"
    )
}

/// Topic of static transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
