//! Errors of bag writing and reading; every variant names the file.

use crate::geometry::rig::RigError;
use crate::msgs::{ImageMsgError, MsgError};

/// A bag that cannot be written or read. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{file}: {action}: {source}")]
    Io {
        file: String,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: MCAP error while {action}: {source}")]
    Mcap {
        file: String,
        action: &'static str,
        #[source]
        source: mcap::McapError,
    },
    #[error("{file}: damaged bag ({detail}); {good_messages} good messages were kept")]
    Damaged {
        file: String,
        detail: String,
        good_messages: usize,
    },
    #[error("{file}: not a readable MCAP file: {detail}")]
    NotMcap { file: String, detail: String },
    #[error("{file}: topic '{topic}': {source}")]
    Msg {
        file: String,
        topic: String,
        #[source]
        source: MsgError,
    },
    #[error("{file}: topic '{topic}' carries '{found}', not '{expected}'")]
    TypeMismatch {
        file: String,
        topic: String,
        expected: String,
        found: String,
    },
    #[error("{file}: topic '{topic}' has no messages")]
    MissingTopic { file: String, topic: String },
    #[error("{file}: metadata record '{name}' (key '{key}') is missing")]
    MissingMetadata {
        file: String,
        name: String,
        key: String,
    },
    #[error("{file}: rig from metadata: {source}")]
    Rig {
        file: String,
        #[source]
        source: RigError,
    },
    #[error("{file}: topic '{topic}', stamp {stamp_ns} ns: {source}")]
    Image {
        file: String,
        topic: String,
        stamp_ns: u64,
        #[source]
        source: ImageMsgError,
    },
    #[error("{file}: topic '{topic}', stamp {stamp_ns} ns, field '{field}': {problem}")]
    Frame {
        file: String,
        topic: String,
        stamp_ns: u64,
        field: String,
        problem: String,
    },
}
