//! `mode360 rig import`: a Kalibr camchain or a Basalt `calibration.json` into the project's
//! rig YAML ([`mode360_core::geometry::import`] does the work; this is the command around it).
//! `mode360 rig refine` is in [`refine`].

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use mode360_core::geometry::import::{
    rig_from_basalt_json, rig_from_kalibr_camchain, ImportOptions,
};
use mode360_core::geometry::rig::DEFAULT_RIG_FRAME;
use mode360_core::geometry::Rig;
use std::path::{Path, PathBuf};

pub mod refine;

#[derive(Args)]
pub struct RigArgs {
    #[command(subcommand)]
    pub command: RigCommand,
}

#[derive(Subcommand)]
pub enum RigCommand {
    /// Convert a Kalibr camchain or a Basalt calibration.json into a rig YAML.
    Import(RigImportArgs),
    /// Refine the cameras' rotations from a bag's images and write the corrected rig YAML.
    Refine(refine::RigRefineArgs),
    /// Write one camera pair as PSMODE's stage 1 sees it: two 360° cameras turned into the
    /// pair's GEER frame, the depth frame the left camera's (so `synth` renders its ground truth
    /// and `eval` scores stage 1 on its own, with GEER disparity metrics).
    Pair(RigPairArgs),
}

#[derive(Args)]
pub struct RigPairArgs {
    /// The rig YAML.
    #[arg(long)]
    pub rig: PathBuf,
    /// The pair, `left-right` camera names (e.g. cam1-cam2).
    #[arg(long)]
    pub pair: String,
    /// Rig YAML to write.
    #[arg(long)]
    pub out: PathBuf,
}

/// Writes the pair rig of `a.pair`.
pub fn run_pair(a: RigPairArgs) -> Result<()> {
    use mode360_core::geometry::{CameraPair, PairView};
    let rig = Rig::from_file(&a.rig)?;
    let (left, right) = a
        .pair
        .split_once('-')
        .with_context(|| format!("--pair '{}': write two camera names as left-right", a.pair))?;
    let index = |name: &str| {
        rig.cameras
            .iter()
            .position(|c| c.name == name)
            .with_context(|| format!("{}: no camera '{name}'", a.rig.display()))
    };
    let pair = CameraPair {
        left: index(left)?,
        right: index(right)?,
    };
    let view = PairView::new(&rig, pair)
        .with_context(|| format!("{}: pair {}", a.rig.display(), a.pair))?;
    write_rig(view.pair_rig(), &a.out)?;
    println!(
        "wrote {} (pair {}, baseline {:.3} m)",
        a.out.display(),
        a.pair,
        view.baseline_m()
    );
    Ok(())
}

#[derive(Args)]
#[command(group = clap::ArgGroup::new("source").required(true).args(["kalibr", "basalt"]))]
pub struct RigImportArgs {
    /// Kalibr camchain YAML (camera 0 becomes the rig frame).
    #[arg(long)]
    pub kalibr: Option<PathBuf>,
    /// Basalt calibration.json (the IMU becomes the rig frame).
    #[arg(long)]
    pub basalt: Option<PathBuf>,
    /// Rig YAML to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Name of the rig frame.
    #[arg(long, default_value = DEFAULT_RIG_FRAME)]
    pub rig_frame: String,
    /// Camera topics become PREFIX/<camera>/image_raw (default: Kalibr's rostopic, else
    /// /<camera>/image_raw).
    #[arg(long)]
    pub topic_prefix: Option<String>,
}

/// `mode360 rig ...`.
pub fn run(a: RigArgs) -> Result<()> {
    match a.command {
        RigCommand::Import(i) => run_import(i),
        RigCommand::Refine(r) => refine::run_refine(r),
        RigCommand::Pair(p) => run_pair(p),
    }
}

/// Reads the calibration, writes the rig YAML, and says what it wrote.
pub fn run_import(a: RigImportArgs) -> Result<()> {
    let opts = ImportOptions {
        rig_frame: a.rig_frame,
        topic_prefix: a.topic_prefix,
    };
    let rig = match (&a.kalibr, &a.basalt) {
        (Some(k), _) => rig_from_kalibr_camchain(k, &opts)?,
        (None, Some(b)) => rig_from_basalt_json(b, &opts)?,
        (None, None) => anyhow::bail!("give --kalibr or --basalt"),
    };
    write_rig(&rig, &a.out)?;
    println!("wrote {} cameras to {}", rig.cameras.len(), a.out.display());
    for c in &rig.cameras {
        println!("  {}: {} on {}", c.name, c.projection.name(), c.topic);
    }
    Ok(())
}

/// Writes `rig` as YAML with a header naming how to read it.
pub fn write_rig(rig: &Rig, out: &Path) -> Result<()> {
    let text = format!(
        "# mode360 rig calibration (mode360 rig import). Fisheye cameras' frames are their\n\
         # optical frames (z forward, x right, y down); see README, \"Rig calibration\".\n{}",
        rig.to_yaml()
    );
    mode360_core::atomic_file::write_atomic(out, text)
        .with_context(|| format!("writing {}", out.display()))
}
