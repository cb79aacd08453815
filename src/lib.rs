//! mode360: multi-camera 360° depth perception.
//!
//! Data flow: rig YAML ([`geometry::rig`]) and synthetic scenes ([`synth`]) are recorded into
//! ROS 2 MCAP bags ([`bag`], [`msgs`]); an estimator ([`estimator`]) turns a frame's N
//! panoramas into an ERP range image, scored against ground truth by [`metrics`] in [`eval`].

pub mod bag;
pub mod bench;
pub mod deep360;
pub mod deep360_bag;
pub mod demo;
pub mod estimator;
pub mod eval;
pub mod frame;
pub mod geometry;
pub mod metrics;
pub mod model;
pub mod msgs;
pub mod node;
pub mod record;
pub mod replay;
pub mod sync;
pub mod synth;
pub mod train;
pub mod viz;
