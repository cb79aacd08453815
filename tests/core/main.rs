//! The library's pure parts beyond geometry (whose tests live in `crates/mode360-core/tests`):
//! custom tensor ops against f64 references, ROS message encoding, synthetic scenes, rig
//! validation of generated rigs, the fuzz suite of foreign inputs and the import-circle check.

#[path = "../common/mod.rs"]
mod common;

mod fuzz_inputs;
mod import_circles;
mod msgs_cdr;
mod ops_composite;
mod ops_conv3d;
mod ops_sample;
mod rig_strict;
mod synth_blockers;
mod synth_fisheye;
mod synth_objects;
mod synth_render;
