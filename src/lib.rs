//! mode360: multi-camera 360° depth perception.
//!
//! The top of the workspace: the `mode360` commands ([`cli`]) and the pictures they write
//! ([`viz`]). The domain lives in the layer crates below, re-exported here under short names
//! so that `mode360::geometry::rig::Rig` reads the same from every test and example
//! (ARCHITECTURE.md has the picture):
//!
//! - `mode360-core`: [`geometry`], [`frame`], [`metrics`], [`obstacles`], [`sync`], [`memory`];
//! - `mode360-io`: [`msgs`], [`bag`], [`deep360`];
//! - `mode360-synth`: [`synth`];
//! - `mode360-model`: [`matching`], [`model`], [`cpu`];
//! - `mode360-estimator`: [`estimator`];
//! - `mode360-health`: [`health`];
//! - `mode360-train`: [`train`];
//! - `mode360-node`: [`node`].

pub mod cli;
pub mod viz;

pub use mode360_core::{frame, geometry, memory, metrics, obstacles, sync};
pub use mode360_estimator as estimator;
pub use mode360_health as health;
pub use mode360_io::{bag, deep360, msgs};
pub use mode360_model::{cpu, matching, model};
pub use mode360_node as node;
pub use mode360_synth as synth;
pub use mode360_train as train;
