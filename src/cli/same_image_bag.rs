//! `mode360 same-image-bag`: a copy of a rig bag with the reference camera's image on every
//! camera topic, for the geometry check on the node's path (replay, play, demo).

use anyhow::{Context, Result};
use clap::Args;
use mode360_io::bag::write_same_image_bag;
use std::path::PathBuf;

#[derive(Args)]
pub struct SameImageBagArgs {
    /// Input rig bag.
    #[arg(long)]
    pub bag: PathBuf,
    /// Output bag: every camera topic carries the reference camera's image of the same stamp.
    #[arg(long)]
    pub out: PathBuf,
}

/// Writes the same-image copy and says how many frames it holds.
pub fn run(a: SameImageBagArgs) -> Result<()> {
    let s = write_same_image_bag(&a.bag, &a.out)
        .with_context(|| format!("writing {} from {}", a.out.display(), a.bag.display()))?;
    println!(
        "wrote {} frames to {}, every camera carrying camera '{}'",
        s.frames,
        a.out.display(),
        s.reference_camera
    );
    Ok(())
}
