//! The library's pure parts: geometry, custom tensor ops against f64 references, ROS message
//! encoding, and synthetic scenes.

#[path = "../common/mod.rs"]
mod common;

mod calib_import;
mod calib_strict;
mod camera_models;
mod fuzz_inputs;
mod geometry;
mod import_circles;
mod msgs_cdr;
mod ops_composite;
mod ops_conv3d;
mod ops_sample;
mod rig_models;
mod rig_strict;
mod synth_blockers;
mod synth_fisheye;
mod synth_objects;
mod synth_render;
