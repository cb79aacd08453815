//! ROS 2 bags as MCAP files: profile `ros2`, schema encoding `ros2msg` (see
//! [`crate::msgs::schema_text`]), message encoding `cdr`.
//!
//! [`BagWriter`] writes one schema per message type and one channel per topic.
//! [`BagReader`] reads a whole file into memory, tolerating damage: every message before a
//! truncation is kept, a chunk whose CRC fails is dropped whole while the chunks after it
//! are kept, and the damage is reported as an error naming the file after the good
//! messages.
//!
//! Files: `format` (profile, encodings, QoS metadata), `error`, `writer`, `reader`;
//! [`rig_bag`] lays rig frames out on top, [`same_image`] rewrites a rig bag for the geometry
//! check.

pub mod rig_bag;
pub mod same_image;

mod error;
mod format;
mod reader;
mod writer;

pub use error::BagError;
pub use format::{MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING};
pub use reader::{BagMessage, BagReader, TopicInfo};
pub use writer::{BagCompression, BagWriteOptions, BagWriter};

pub use rig_bag::{
    rig_tf_static, rig_tf_static_at, RigBagReader, RigBagWriter, DEFAULT_MAX_DEPTH_M,
    GROUND_TRUTH_CLASSES_TOPIC, GROUND_TRUTH_INSTANCES_TOPIC, GROUND_TRUTH_TOPIC, MAX_DEPTH_KEY,
    RIG_METADATA, RIG_YAML_KEY, SOILED_KEY, SYNTH_METADATA, TF_STATIC_TOPIC,
};
pub use same_image::{write_same_image_bag, SameImageSummary, SAME_IMAGE_METADATA};
