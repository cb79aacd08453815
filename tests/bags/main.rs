//! Bags and the commands over them: MCAP round trips, third-party readers (Python mcap,
//! rosbags, Foxglove's decoders), the Deep360 reader with independently written fixtures,
//! replay, and the `mode360` binary (synth, eval, errors, README option tables).

#[path = "../common/mod.rs"]
mod common;

mod bag_interop;
mod bag_roundtrip;
mod calibration_replay;
mod cli;
mod cli_device;
mod deep360_bag;
mod deep360_fixture;
mod deep360_train;
mod deep360_writer;
mod fisheye_bag;
mod lens_replay;
mod obstacle_labels;
mod replay_bag;
