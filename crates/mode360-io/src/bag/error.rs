//! Errors of bag writing and reading; every variant names the file.

use crate::msgs::{ImageMsgError, MsgError};
use mode360_core::geometry::rig::RigError;

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
    #[error("{file}: metadata key '{key}' = '{value}' is not a {expected}")]
    BadMetadata {
        file: String,
        key: String,
        value: String,
        expected: &'static str,
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

impl BagError {
    /// The file the error is about.
    pub fn file(&self) -> &str {
        match self {
            Self::Io { file, .. }
            | Self::Mcap { file, .. }
            | Self::Damaged { file, .. }
            | Self::NotMcap { file, .. }
            | Self::Msg { file, .. }
            | Self::TypeMismatch { file, .. }
            | Self::MissingTopic { file, .. }
            | Self::MissingMetadata { file, .. }
            | Self::BadMetadata { file, .. }
            | Self::Rig { file, .. }
            | Self::Image { file, .. }
            | Self::Frame { file, .. } => file,
        }
    }

    /// The topic the error is about, if it is about one.
    pub fn topic(&self) -> Option<&str> {
        match self {
            Self::Msg { topic, .. }
            | Self::TypeMismatch { topic, .. }
            | Self::MissingTopic { topic, .. }
            | Self::Image { topic, .. }
            | Self::Frame { topic, .. } => Some(topic),
            _ => None,
        }
    }

    /// What went wrong, without the file, topic and stamp, so that the same problem on many
    /// messages reads the same (for drop summaries).
    pub fn reason(&self) -> String {
        match self {
            Self::Io { action, source, .. } => format!("{action}: {source}"),
            Self::Mcap { action, source, .. } => format!("MCAP error while {action}: {source}"),
            Self::Damaged { detail, .. } => format!("damaged bag ({detail})"),
            Self::NotMcap { detail, .. } => format!("not a readable MCAP file: {detail}"),
            Self::Msg { source, .. } => source.to_string(),
            Self::TypeMismatch {
                expected, found, ..
            } => format!("carries '{found}', not '{expected}'"),
            Self::MissingTopic { .. } => "no messages".into(),
            Self::MissingMetadata { name, key, .. } => {
                format!("metadata record '{name}' (key '{key}') is missing")
            }
            Self::BadMetadata {
                key,
                value,
                expected,
                ..
            } => format!("metadata key '{key}' = '{value}' is not a {expected}"),
            Self::Rig { source, .. } => format!("rig from metadata: {source}"),
            Self::Image { source, .. } => source.to_string(),
            Self::Frame { field, problem, .. } => format!("field '{field}': {problem}"),
        }
    }
}
