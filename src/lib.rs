//! mode360: multi-camera 360° depth perception.
//!
//! The domain library: rig calibration and projections ([`geometry`]), frames ([`frame`]),
//! ROS 2 messages ([`msgs`]) and MCAP rig bags ([`bag`], [`deep360`] for the paper's
//! dataset), synthetic scenes ([`synth`]), depth estimators ([`estimator`]: the photometric
//! sweep and SSMODE, whose network is [`model`] and whose training is [`train`]), metrics
//! ([`metrics`]), camera synchronization ([`sync`]), the ROS 2 node ([`node`]), pictures
//! ([`viz`]) and process memory ([`memory`]). The `mode360` commands sit on top in [`cli`].

pub mod bag;
pub mod cli;
pub mod deep360;
pub mod estimator;
pub mod frame;
pub mod geometry;
pub mod matching;
pub mod memory;
pub mod metrics;
pub mod model;
pub mod msgs;
pub mod node;
pub mod sync;
pub mod synth;
pub mod train;
pub mod viz;
