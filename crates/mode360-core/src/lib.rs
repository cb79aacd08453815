//! mode360's geometry layer: everything the other crates agree on, free of tensors and ROS.
//!
//! Rig calibration, camera models and projections ([`geometry`]), images with their frames
//! ([`frame`]), depth metrics ([`metrics`]) and obstacle metrics ([`obstacles`]), camera synchronization ([`sync`]) and process
//! memory ([`memory`]) and progress bars of long work ([`progress`]).

pub mod atomic_file;
pub mod frame;
pub mod geometry;
pub mod glyphs;
pub mod memory;
pub mod metrics;
pub mod obstacles;
pub mod progress;
pub mod shipped;
pub mod sync;
