//! The node's error type, shared by every room of the live node; the lowest of them, it
//! imports none of the others but their error types (`dds`, `shutdown`, `worker`, `receive`, `run`).

use super::live_view::LiveViewError;
use super::params::ParamsError;
use super::pipeline::PipelineError;
use super::ROS_DOMAIN_ID_ENV;
use mode360_core::geometry::RigError;
use mode360_estimator::EstimatorError;

/// Why the node could not start, run or stop cleanly.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Params(#[from] ParamsError),
    #[error(transparent)]
    Rig(#[from] RigError),
    #[error(transparent)]
    Estimator(#[from] EstimatorError),
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error(transparent)]
    LiveView(#[from] LiveViewError),
    #[error("environment variable {ROS_DOMAIN_ID_ENV}='{value}' is not a domain id (0..=232)")]
    DomainId { value: String },
    #[error("environment variable {variable}='{value}' is not valid (expected {expected})")]
    Environment {
        variable: String,
        value: String,
        expected: String,
    },
    #[error("topic '{topic}': not a valid ROS 2 name: {problem}")]
    TopicName { topic: String, problem: String },
    #[error("DDS: {what}: {problem}")]
    Dds { what: String, problem: String },
    #[error("node thread '{thread}' panicked")]
    ThreadPanic { thread: String },
    #[error("tokio: {what}: {problem}")]
    Runtime { what: String, problem: String },
    #[error("{problem}")]
    Extrinsics { problem: String },
}

/// A [`NodeError::Dds`] maker for `map_err` on a `String` problem.
pub(super) fn dds_err(what: impl Into<String>) -> impl FnOnce(String) -> NodeError {
    let what = what.into();
    move |problem| NodeError::Dds { what, problem }
}
