//! Helpers of `mode360-model`'s integration tests.
#![allow(dead_code)] // each binary uses its own subset

mod numeric;
pub use numeric::*;

use mode360_core::geometry::Rig;
use std::path::PathBuf;

/// `rel` inside the repository (two folders above this crate).
pub fn repo_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(rel)
}

/// The bundled Deep360 rig (`launch_configs/rig_deep360.yaml`).
pub fn deep360_rig() -> Rig {
    Rig::from_file(repo_path("launch_configs/rig_deep360.yaml"))
        .expect("launch_configs/rig_deep360.yaml")
}
