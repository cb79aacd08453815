//! The geometry layer on its own (`cargo test -p mode360-core`, no tensors, DDS or renderer):
//! ERP and GEER projections, camera models, rigs and their YAML, and calibration import from
//! Kalibr's and Basalt's formats against the Python-written fixtures of `tests/fixtures/calib`.

mod calib_import;
mod calib_strict;
mod camera_models;
mod geometry;
mod rig_models;
