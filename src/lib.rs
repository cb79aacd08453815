//! mode360: multi-camera 360° depth perception.
//!
//! The top of the workspace: the `mode360` commands ([`cli`]) and the pictures they write
//! ([`viz`]). The domain lives in the layer crates below, re-exported here under their module
//! names so that `mode360::geometry::rig::Rig` reads the same from every test and example
//! (ARCHITECTURE.md has the picture):
//!
//! - `mode360-core`: [`geometry`], [`frame`], [`metrics`], [`sync`], [`memory`];
//! - `mode360-io`: [`msgs`], [`bag`], [`deep360`];
//! - `mode360-synth`: [`synth`];
//! - `mode360-estimator`: [`matching`], [`model`], [`estimator`];
//! - `mode360-train`: [`train`];
//! - `mode360-node`: [`node`].

pub mod cli;
pub mod viz;

pub use mode360_core::{frame, geometry, memory, metrics, obstacles, sync};
pub use mode360_estimator::estimator;
pub use mode360_io::{bag, deep360, msgs};
pub use mode360_model::{cpu, matching, model};
pub use mode360_node::node;
pub use mode360_synth::synth;
pub use mode360_train::train;
