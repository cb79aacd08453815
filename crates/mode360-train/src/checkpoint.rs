//! Exact checkpoint/resume: `out_dir/checkpoint/` holds `model.safetensors` (the model's
//! `save_weights`, config in the header), `optimizer.safetensors` (AdamW moments) and
//! `state.json` ([`CheckpointState`]: step, next sample index = the data RNG position, options
//! that must match on resume). [`write_checkpoint`] writes into `checkpoint.tmp/` and renames
//! it into place, so a crash never leaves a torn checkpoint; [`find_checkpoint`] also accepts
//! the `checkpoint.old/` a crash between the two renames can leave.

use super::data::{Deep360Mix, SceneMix};
use super::loss::LossWeighting;
use super::optim::AdamW;
use super::options::{io_err, TrainError};
use candle_core::Device;
use candle_nn::VarMap;
use mode360_model::model::{save_weights, SsmodeConfig};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Checkpoint directory name inside `out_dir`.
pub const CHECKPOINT_DIR: &str = "checkpoint";
/// Files inside a checkpoint directory.
pub const MODEL_FILE: &str = "model.safetensors";
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
pub const STATE_FILE: &str = "state.json";
/// Version of the `state.json` layout.
pub(super) const STATE_VERSION: u32 = 1;
/// Suffixes of the temporary and previous checkpoint directories.
const TMP_SUFFIX: &str = "tmp";
const OLD_SUFFIX: &str = "old";

/// Bookkeeping saved with a checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    pub version: u32,
    /// Steps completed.
    pub step: usize,
    /// Index of the next training sample (the data RNG position).
    pub next_sample_index: u64,
    pub preset: String,
    pub width: usize,
    pub seed: u64,
    pub batch_size: usize,
    /// Training wall time so far, seconds.
    #[serde(alias = "train_secs")]
    pub train_s: f64,
    /// The Deep360-on-disk part of the stream (absent in older checkpoints: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deep360_disk: Option<Deep360DiskState>,
    /// What the stream's samples hold (its fields at the top level of `state.json`).
    #[serde(flatten)]
    pub mix: SceneMix,
    /// The loss's extra weights the run trains with now (a record, not compared on resume:
    /// the arms of an ablation fork one checkpoint with other weights; absent in older
    /// checkpoints).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loss_weighting: Option<LossWeighting>,
    /// Whether only the fine head learns (`TrainOptions::fine_head_only`; absent in older
    /// checkpoints and in full runs). A resume must match; a fork may change it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fine_head_only: bool,
}

/// What a resume must find again to read the same Deep360 frames for the same samples.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Deep360DiskState {
    pub root: String,
    pub fraction: f64,
    /// Frame and image-set count of the training split (the picks are indices into it).
    pub frames: usize,
}

impl Deep360DiskState {
    pub(super) fn of(mix: &Deep360Mix) -> Self {
        Self {
            root: mix.root.display().to_string(),
            fraction: mix.fraction,
            frames: mix.frames.len(),
        }
    }
}

/// Writes a checkpoint atomically (temp directory, then rename).
pub(super) fn write_checkpoint(
    out_dir: &Path,
    varmap: &VarMap,
    cfg: &SsmodeConfig,
    opt: &AdamW,
    state: &CheckpointState,
) -> Result<(), TrainError> {
    let final_dir = out_dir.join(CHECKPOINT_DIR);
    let tmp = out_dir.join(format!("{CHECKPOINT_DIR}.{TMP_SUFFIX}"));
    let old = out_dir.join(format!("{CHECKPOINT_DIR}.{OLD_SUFFIX}"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io_err(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io_err(&tmp))?;
    save_weights(varmap, cfg, tmp.join(MODEL_FILE))?;
    let opt_path = tmp.join(OPTIMIZER_FILE);
    candle_core::safetensors::save(&opt.state_tensors(), &opt_path)?;
    let state_path = tmp.join(STATE_FILE);
    let json = serde_json::to_string_pretty(state)
        .map_err(|e| TrainError::Other(format!("serializing checkpoint state: {e}")))?;
    std::fs::write(&state_path, json).map_err(io_err(&state_path))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(io_err(&old))?;
    }
    if final_dir.exists() {
        std::fs::rename(&final_dir, &old).map_err(io_err(&final_dir))?;
    }
    std::fs::rename(&tmp, &final_dir).map_err(io_err(&tmp))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(io_err(&old))?;
    }
    Ok(())
}

/// The newest complete checkpoint directory, if any (`checkpoint/`, else `checkpoint.old/`
/// left by a crash between the two renames).
pub(super) fn find_checkpoint(out_dir: &Path) -> Option<PathBuf> {
    [
        out_dir.join(CHECKPOINT_DIR),
        out_dir.join(format!("{CHECKPOINT_DIR}.{OLD_SUFFIX}")),
    ]
    .into_iter()
    .find(|d| d.join(STATE_FILE).is_file())
}

/// What a run takes over from a saved checkpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Restore {
    /// The same run continues: every option (network, seed, data mix) must match.
    Resume,
    /// A new run continues from another run's checkpoint with its own seed and data mix: only
    /// the network (preset, width) and the batch size must match.
    Fork,
}

/// The first setting of `state` (saved) that differs from this run's (`expected`) as `(field, saved,
/// this run's)`: the network's always, the data's only on resume (a fork may change them).
/// Compared as text: Rust prints a float so that it reads back exactly, so equal text is
/// equal value.
fn first_mismatch(
    state: &CheckpointState,
    expected: &CheckpointState,
    restore: Restore,
) -> Option<(&'static str, String, String)> {
    let network = [
        (
            "version",
            state.version.to_string(),
            STATE_VERSION.to_string(),
        ),
        ("preset", state.preset.clone(), expected.preset.clone()),
        ("width", state.width.to_string(), expected.width.to_string()),
        (
            "batch_size",
            state.batch_size.to_string(),
            expected.batch_size.to_string(),
        ),
    ];
    let data = [
        ("seed", state.seed.to_string(), expected.seed.to_string()),
        (
            "objects_fraction",
            state.mix.objects_fraction.to_string(),
            expected.mix.objects_fraction.to_string(),
        ),
        (
            "fisheye_fraction",
            state.mix.fisheye_fraction.to_string(),
            expected.mix.fisheye_fraction.to_string(),
        ),
        (
            "rig_layouts",
            state.mix.rig_layouts.as_str().to_string(),
            expected.mix.rig_layouts.as_str().to_string(),
        ),
        (
            "rig_pool",
            state.mix.rig_pool.to_string(),
            expected.mix.rig_pool.to_string(),
        ),
        (
            "camera_pairs",
            state.mix.camera_pairs.to_string(),
            expected.mix.camera_pairs.to_string(),
        ),
        (
            "blocked_fraction",
            state.mix.blocked_fraction.to_string(),
            expected.mix.blocked_fraction.to_string(),
        ),
        (
            "street",
            state.mix.street.as_str().to_string(),
            expected.mix.street.as_str().to_string(),
        ),
        (
            "fine_head_only",
            state.fine_head_only.to_string(),
            expected.fine_head_only.to_string(),
        ),
        (
            "deep360_disk",
            format!("{:?}", state.deep360_disk),
            format!("{:?}", expected.deep360_disk),
        ),
    ];
    let data_checked: &[_] = match restore {
        Restore::Resume => &data,
        Restore::Fork => &[],
    };
    network
        .into_iter()
        .chain(data_checked.iter().cloned())
        .find(|(_, saved, now)| saved != now)
}

/// Restores weights, optimizer moments and bookkeeping from `dir`, checking that the run's
/// options match (all of them for [`Restore::Resume`], the network's for [`Restore::Fork`]).
/// A fork keeps `expected`'s options and takes the step, sample position and training time.
pub(super) fn load_checkpoint(
    dir: &Path,
    varmap: &mut VarMap,
    opt: &mut AdamW,
    expected: &CheckpointState,
    restore: Restore,
    device: &Device,
) -> Result<CheckpointState, TrainError> {
    let state_path = dir.join(STATE_FILE);
    let text = std::fs::read_to_string(&state_path).map_err(io_err(&state_path))?;
    let state: CheckpointState =
        serde_json::from_str(&text).map_err(|e| TrainError::Checkpoint {
            path: state_path.display().to_string(),
            problem: format!("malformed: {e}"),
        })?;
    let advice = match restore {
        Restore::Resume => "; use a new out_dir",
        Restore::Fork => "",
    };
    if let Some((field, saved, now)) = first_mismatch(&state, expected, restore) {
        return Err(TrainError::Checkpoint {
            path: state_path.display().to_string(),
            problem: format!("'{field}' was {saved} but this run uses {now}{advice}"),
        });
    }
    let model_path = dir.join(MODEL_FILE);
    varmap
        .load(&model_path)
        .map_err(|e| TrainError::Checkpoint {
            path: model_path.display().to_string(),
            problem: e.to_string(),
        })?;
    let opt_path = dir.join(OPTIMIZER_FILE);
    let tensors =
        candle_core::safetensors::load(&opt_path, device).map_err(|e| TrainError::Checkpoint {
            path: opt_path.display().to_string(),
            problem: e.to_string(),
        })?;
    opt.load_state_tensors(tensors, state.step, device)
        .map_err(|problem| TrainError::Checkpoint {
            path: opt_path.display().to_string(),
            problem,
        })?;
    Ok(match restore {
        Restore::Resume => CheckpointState {
            loss_weighting: expected.loss_weighting,
            ..state
        },
        Restore::Fork => CheckpointState {
            step: state.step,
            next_sample_index: state.next_sample_index,
            train_s: state.train_s,
            ..expected.clone()
        },
    })
}
