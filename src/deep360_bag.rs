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

use crate::bag::{BagError, RigBagWriter};
use crate::bag::{MAX_DEPTH_KEY, SOILED_KEY};
use crate::deep360::{
    clamp_range_to_max, deep360_rig, Deep360Dataset, Deep360Error, Deep360FrameId, Deep360Split,
    DEEP360_MAX_DEPTH_M, EPISODES, EPISODE_FRAME_SLOTS,
};
use crate::geometry::{ErpGrid, GeometryError};
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

/// Metadata `source` value of converted bags.
pub const DEEP360_SOURCE: &str = "deep360";

/// Errors of a conversion; each names the root, split, frame or file at fault.
#[derive(Debug, thiserror::Error)]
pub enum Deep360BagError {
    #[error(transparent)]
    Dataset(#[from] Deep360Error),
    #[error("Deep360 {id} ({split}): {source}")]
    Frame {
        id: Deep360FrameId,
        split: &'static str,
        #[source]
        source: Box<Deep360Error>,
    },
    #[error("Deep360 {id} ({split}): missing file {path}")]
    MissingFile {
        id: Deep360FrameId,
        split: &'static str,
        path: String,
    },
    #[error("Deep360 {id}: frame number must be below {EPISODE_FRAME_SLOTS} for unique stamps")]
    FrameNumber { id: Deep360FrameId },
    #[error("no Deep360 frames under {root} for split '{split}'{episode} (looked for ep*_500frames/{split}/depth/*_depth.npz)")]
    NoFrames {
        root: String,
        split: &'static str,
        episode: String,
    },
    #[error("episode must be 1 to {EPISODES}, got {0}")]
    Episode(u32),
    #[error("output --width: {0}")]
    Width(#[from] GeometryError),
    #[error(transparent)]
    Bag(#[from] BagError),
}

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
    pub seconds: f64,
    pub bytes: u64,
}

/// Converts the selected frames into a rig bag at `opts.out` (see the module docs). All
/// frames' files are checked before anything is written; a bag left half-written by a
/// failure during conversion is removed.
pub fn convert_deep360_to_bag(
    opts: &Deep360BagOptions,
) -> Result<Deep360BagSummary, Deep360BagError> {
    if let Some(e) = opts.episode.filter(|e| !(1..=EPISODES).contains(e)) {
        return Err(Deep360BagError::Episode(e));
    }
    let grid = ErpGrid::new(opts.width)?;
    let split = opts.split.dir_name();
    let ds = Deep360Dataset::open(&opts.root)?;
    let mut ids: Vec<Deep360FrameId> = ds
        .frame_ids(opts.split)?
        .into_iter()
        .filter(|id| opts.episode.is_none_or(|e| id.episode == e))
        .collect();
    ids.truncate(opts.max_frames.unwrap_or(usize::MAX));
    let (Some(&first), Some(&last)) = (ids.first(), ids.last()) else {
        return Err(Deep360BagError::NoFrames {
            root: opts.root.display().to_string(),
            split,
            episode: opts
                .episode
                .map_or_else(String::new, |e| format!(" in episode {e}")),
        });
    };
    for &id in &ids {
        if u64::from(id.frame) >= EPISODE_FRAME_SLOTS {
            return Err(Deep360BagError::FrameNumber { id });
        }
        if let Some(path) = ds.missing_file(id, opts.split, opts.soiled) {
            return Err(Deep360BagError::MissingFile {
                id,
                split,
                path: path.display().to_string(),
            });
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
        seconds: t0.elapsed().as_secs_f64(),
        bytes: std::fs::metadata(&opts.out).map(|m| m.len()).unwrap_or(0),
    })
}

fn write_bag(
    opts: &Deep360BagOptions,
    ds: &Deep360Dataset,
    ids: &[Deep360FrameId],
    grid: ErpGrid,
) -> Result<(), Deep360BagError> {
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
    let rig = deep360_rig().map_err(Deep360Error::from)?;
    let mut writer = RigBagWriter::create(&opts.out, &rig, &info)?;
    let progress = if opts.show_progress {
        let pb = ProgressBar::new(ids.len() as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "converting Deep360 [{elapsed_precise}] {bar:30} {pos}/{len} frames ({per_sec}, ETA {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        pb
    } else {
        ProgressBar::hidden()
    };
    for &id in ids {
        let mut frame = ds
            .load_frame(id, opts.split, opts.soiled, grid.width())
            .map_err(|source| Deep360BagError::Frame {
                id,
                split,
                source: Box::new(source),
            })?;
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
