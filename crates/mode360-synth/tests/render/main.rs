//! The renderer on its own (`cargo test -p mode360-synth`): determinism, analytic ground
//! truth, multi-view consistency, soiling, blocked lenses and fisheye rigs.

mod common {
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
}

mod synth_blockers;
mod synth_fisheye;
mod synth_render;
