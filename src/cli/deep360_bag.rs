//! `mode360 deep360-bag`: converts frames of the paper's Deep360 dataset on disk into this
//! project's rig-bag layout, so that `eval`, `replay` and `play` work on Deep360 unchanged.
//!
//! Per frame: the four cameras' Cassini PNGs (`12_rgb1`, `12_rgb2`, `34_rgb3`, `34_rgb4`, from
//! `rgb/` or, with `soiled`, `rgb_soiled/`) resampled to ERP at the requested width, and the
//! range of camera 1 resampled to the same grid (nearest neighbour) with values beyond
//! [`DEEP360_MAX_DEPTH_M`] set to it (sky) and invalid values NaN. The rig is
//! [`deep360_rig`]; stamps are [`Deep360FrameId::stamp_ns`] (episode and frame number can be
//! read back from them). The `mode360.synth` metadata record carries `soiled` and
//! `max_depth_m` (read by `eval`) and where the frames came from.

use anyhow::{bail, Context, Result};
use clap::Args;
use mode360_core::geometry::ErpGrid;
use mode360_core::memory::BYTES_PER_MIB;
use mode360_core::progress::frames_bar;
use mode360_io::bag::RigBagWriter;
use mode360_io::bag::{MAX_DEPTH_KEY, SOILED_KEY};
use mode360_io::deep360::{
    clamp_range_to_max, deep360_rig, Deep360Dataset, Deep360FrameId, Deep360Split,
    DEEP360_MAX_DEPTH_M, EPISODES, EPISODE_FRAME_SLOTS,
};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

/// Metadata `source` value of converted bags.
pub const DEEP360_SOURCE: &str = "deep360";

/// What to convert.
#[derive(Clone, Debug)]
pub struct Deep360BagOptions {
    /// Directory holding the `ep*_500frames` folders.
    pub root: PathBuf,
    pub split: Deep360Split,
    /// Read `rgb_soiled/` instead of `rgb/`.
    pub soiled: bool,
    /// ERP width of images and ground truth (height = width / 2).
    pub width: usize,
    /// Convert at most this many frames (in episode, frame order).
    pub max_frames: Option<usize>,
    /// Only this episode (1..=6).
    pub episode: Option<u32>,
    pub out: PathBuf,
    pub show_progress: bool,
}

/// What was written.
#[derive(Clone, Debug)]
pub struct Deep360BagSummary {
    pub frames: usize,
    pub first: Deep360FrameId,
    pub last: Deep360FrameId,
    pub elapsed_s: f64,
    pub bytes: u64,
}

/// Converts the selected frames into a rig bag at `opts.out` (see the module docs). All
/// frames' files are checked before anything is written; a bag left half-written by a
/// failure during conversion is removed.
pub fn convert_deep360_to_bag(opts: &Deep360BagOptions) -> Result<Deep360BagSummary> {
    if let Some(e) = opts.episode.filter(|e| !(1..=EPISODES).contains(e)) {
        bail!("episode must be 1 to {EPISODES}, got {e}");
    }
    let grid = ErpGrid::new(opts.width).context("output --width")?;
    let split = opts.split.dir_name();
    let ds = Deep360Dataset::open(&opts.root)?;
    let mut ids: Vec<Deep360FrameId> = ds
        .frame_ids(opts.split)?
        .into_iter()
        .filter(|id| opts.episode.is_none_or(|e| id.episode == e))
        .collect();
    ids.truncate(opts.max_frames.unwrap_or(usize::MAX));
    let (Some(&first), Some(&last)) = (ids.first(), ids.last()) else {
        bail!(
            "no Deep360 frames under {} for split '{split}'{} (looked for ep*_500frames/{split}/depth/*_depth.npz)",
            opts.root.display(),
            opts.episode
                .map_or_else(String::new, |e| format!(" in episode {e}"))
        );
    };
    for &id in &ids {
        if u64::from(id.frame) >= EPISODE_FRAME_SLOTS {
            bail!(
                "Deep360 {id}: frame number must be below {EPISODE_FRAME_SLOTS} for unique stamps"
            );
        }
        if let Some(path) = ds.missing_file(id, opts.split, opts.soiled) {
            bail!("Deep360 {id} ({split}): missing file {}", path.display());
        }
    }
    let t0 = Instant::now();
    let result = write_bag(opts, &ds, &ids, grid);
    if result.is_err() {
        // Best effort: a half-written bag is worse than none.
        let _ = std::fs::remove_file(&opts.out);
    }
    result?;
    Ok(Deep360BagSummary {
        frames: ids.len(),
        first,
        last,
        elapsed_s: t0.elapsed().as_secs_f64(),
        bytes: std::fs::metadata(&opts.out).map(|m| m.len()).unwrap_or(0),
    })
}

fn write_bag(
    opts: &Deep360BagOptions,
    ds: &Deep360Dataset,
    ids: &[Deep360FrameId],
    grid: ErpGrid,
) -> Result<()> {
    let split = opts.split.dir_name();
    let info = BTreeMap::from([
        ("source".to_string(), DEEP360_SOURCE.to_string()),
        ("root".into(), opts.root.display().to_string()),
        ("split".into(), split.to_string()),
        (
            "episode".into(),
            opts.episode.map_or_else(|| "all".into(), |e| e.to_string()),
        ),
        ("frames".into(), ids.len().to_string()),
        ("width".into(), grid.width().to_string()),
        (SOILED_KEY.into(), opts.soiled.to_string()),
        (MAX_DEPTH_KEY.into(), DEEP360_MAX_DEPTH_M.to_string()),
    ]);
    let rig = deep360_rig()?;
    let mut writer = RigBagWriter::create(&opts.out, &rig, &info)?;
    let progress = frames_bar("converting Deep360", ids.len(), opts.show_progress);
    for &id in ids {
        let mut frame = ds
            .load_frame(id, opts.split, opts.soiled, grid.width())
            .with_context(|| format!("Deep360 {id} ({split})"))?;
        if let Some(gt) = frame.ground_truth.as_mut() {
            clamp_range_to_max(gt, DEEP360_MAX_DEPTH_M);
        }
        writer.write_frame(&frame)?;
        progress.inc(1);
    }
    writer.finish()?;
    progress.finish_and_clear();
    Ok(())
}

#[derive(Args)]
pub struct Deep360BagArgs {
    /// Dataset root: the directory holding ep1_500frames ... ep6_500frames.
    pub root: PathBuf,
    /// Split: train, val or test.
    #[arg(long)]
    pub split: Deep360Split,
    /// Use the soiled images (rgb_soiled/) instead of the clean ones (rgb/).
    #[arg(long)]
    pub soiled: bool,
    /// Panorama width in pixels (height = width / 2).
    #[arg(long, default_value_t = 512)]
    pub width: usize,
    /// Convert at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Only this episode (1 to 6).
    #[arg(long)]
    pub episode: Option<u32>,
    /// Output bag.
    #[arg(long)]
    pub out: PathBuf,
}

/// `mode360 deep360-bag`: converts the frames and prints what was written.
pub fn run(a: Deep360BagArgs) -> Result<()> {
    let s = convert_deep360_to_bag(&Deep360BagOptions {
        root: a.root,
        split: a.split,
        soiled: a.soiled,
        width: a.width,
        max_frames: a.max_frames,
        episode: a.episode,
        out: a.out.clone(),
        show_progress: true,
    })
    .with_context(|| format!("converting Deep360 into {}", a.out.display()))?;
    println!(
        "wrote {} Deep360 frames ({} .. {}) to {} ({:.1} MiB) in {:.1} s",
        s.frames,
        s.first,
        s.last,
        a.out.display(),
        s.bytes as f64 / BYTES_PER_MIB,
        s.elapsed_s
    );
    Ok(())
}
