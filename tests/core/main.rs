//! The library's pure parts across crates (each crate's own tests live in its `tests/`:
//! geometry in mode360-core, ops and layers in mode360-model, messages in mode360-io, the
//! renderer in mode360-synth, training in mode360-train): rig validation of generated rigs,
//! random-object scenes against the trainer's labels, the fuzz suite of foreign inputs and
//! the import-circle check.

#[path = "../common/mod.rs"]
mod common;

mod fuzz_inputs;
mod import_circles;
mod rig_strict;
mod synth_objects;
