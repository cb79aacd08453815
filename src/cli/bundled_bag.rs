//! The demo bag, `bags/demo_deep360.mcap`: found where the source tree or an install has it
//! ([`mode360_core::shipped`]), else rendered once into the data directory by the recipe of
//! bags/README.md (the same command writes the same messages), so `mode360 demo` works from any
//! folder, also for a binary installed or copied without its source tree.

use anyhow::{Context, Result};
use mode360_core::geometry::Rig;
use mode360_core::shipped::{self, Origin};
use mode360_node::params::DEFAULT_RIG_FILE;
use mode360_synth::record::{record_synthetic_bag, RecordOptions};
use mode360_synth::SynthConfig;
use std::path::{Path, PathBuf};

/// The bag `demo` plays and `bench-node` measures by default.
pub const BUNDLED_BAG: &str = "bags/demo_deep360.mcap";
/// The recipe of the bundled bag (bags/README.md): seed, frames and width.
pub const BUNDLED_SEED: u64 = 2026;
pub const BUNDLED_FRAMES: usize = 4;
pub const BUNDLED_WIDTH: usize = 512;

/// `path` located as [`mode360_core::shipped`] says; the bundled bag, where nothing has it,
/// rendered into the data directory first. Any other path that is nowhere comes back as
/// given, so opening it names what is missing.
pub fn locate_bag(path: &Path) -> Result<PathBuf> {
    let located = shipped::locate(path, &[]);
    let bundled = path.components().eq(Path::new(BUNDLED_BAG).components());
    if located.origin != Origin::NotFound || !bundled {
        return Ok(located.path);
    }
    let out = shipped::data_dir().join(BUNDLED_BAG);
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    tracing::info!(
        "{BUNDLED_BAG} is not here: rendering it ({BUNDLED_FRAMES} frames at {BUNDLED_WIDTH} px, \
         seed {BUNDLED_SEED}) into {}",
        out.display()
    );
    record_synthetic_bag(&RecordOptions {
        rig: Rig::from_file_or_shipped(DEFAULT_RIG_FILE)?,
        config: SynthConfig {
            seed: BUNDLED_SEED,
            width: BUNDLED_WIDTH,
            ..SynthConfig::default()
        },
        frames: BUNDLED_FRAMES,
        first_frame: 0,
        out: out.clone(),
        show_progress: false,
    })
    .with_context(|| format!("rendering the demo bag into {}", out.display()))?;
    Ok(out)
}
