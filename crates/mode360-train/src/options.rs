//! What a training run is given and what it returns: [`TrainOptions`] (the options of
//! `mode360 train`, checked by `resolve_config`), [`TrainSummary`], [`StepReport`] and
//! [`TrainError`].

use super::data::{DataError, SceneMix};
use super::log::ValRecord;
use super::loss::{LossError, LossWeighting};
use mode360_model::model::{ComputeDevice, ModelError, Preset, SsmodeConfig};
use std::path::{Path, PathBuf};

/// Errors of a training run; each names the file or option at fault.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("train: {0}")]
    Model(#[from] ModelError),
    #[error("train: {0}")]
    Data(#[from] DataError),
    #[error("train: {0}")]
    Loss(#[from] LossError),
    #[error("train: tensor: {0}")]
    Tensor(#[from] candle_core::Error),
    #[error("train: {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("train: checkpoint {path}: {problem}")]
    Checkpoint { path: String, problem: String },
    #[error("train: option '{option}': {problem}")]
    Option {
        option: &'static str,
        problem: String,
    },
    #[error("train: {0}")]
    Other(String),
}

pub(super) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Options of `mode360 train`.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainOptions {
    /// Network preset.
    pub preset: Preset,
    /// Overrides the preset's input width (height = width / 2).
    pub width: Option<usize>,
    /// Total optimizer steps (a resumed run continues up to this).
    pub steps: usize,
    pub out_dir: PathBuf,
    /// Continue from `out_dir/checkpoint` if present.
    pub resume: bool,
    /// Samples per step (gradient accumulation).
    pub batch_size: usize,
    /// Peak learning rate.
    pub lr: f64,
    pub warmup_steps: usize,
    pub weight_decay: f64,
    /// Validate every this many steps (0: never).
    pub val_every: usize,
    /// Held-out validation frames (Deep360 rig, alternating clean/soiled).
    pub val_samples: usize,
    /// Checkpoint every this many steps (0: only by time and at the end).
    pub checkpoint_every_steps: usize,
    /// Checkpoint when this many seconds passed since the last one.
    pub checkpoint_every_s: f64,
    /// Data stream seed.
    pub seed: u64,
    pub soiled_fraction: f64,
    pub deep360_fraction: f64,
    /// Root of the paper's Deep360 dataset: its training frames are mixed into the stream.
    pub deep360_disk: Option<PathBuf>,
    /// Fraction of training samples read from `deep360_disk` (when set).
    pub deep360_disk_fraction: f64,
    /// What the rendered samples hold (saved in the checkpoint, compared on resume).
    pub mix: SceneMix,
    /// Clip the global gradient norm to this (`None`: no clipping).
    pub max_grad_norm: Option<f64>,
    /// Extra loss weight of near pixels and too-far predictions (default: none).
    pub loss_weighting: LossWeighting,
    /// Camera effects on every rendered training image ([`super::camera_effects`]).
    pub camera_effects: bool,
    /// Start a new run (not a resumed one) from these weights instead of the random
    /// initialisation: fine-tuning. The file's network must have the preset's layer sizes.
    pub init_weights: Option<PathBuf>,
    /// Start a new run from another run's checkpoint folder (its `checkpoint/` or the folder
    /// itself): its weights, optimizer moments, step and sample position, with this run's data
    /// options. The arms of a data-mix ablation fork one checkpoint and compare at equal steps.
    /// Only the network (preset, width) and the batch size must match.
    pub fork_from: Option<PathBuf>,
    /// Stop after this step although the learning-rate schedule runs over `steps` (an
    /// ablation arm stops where the others do; `None`: run to `steps`).
    pub until_step: Option<usize>,
    /// Where the network trains (the CPU, or a CUDA GPU with the `cuda` feature).
    pub device: ComputeDevice,
    pub show_progress: bool,
}

impl TrainOptions {
    /// The step a run stops after: `steps`, or `until_step` when that comes first.
    pub fn last_step(&self) -> usize {
        self.until_step.map_or(self.steps, |u| u.min(self.steps))
    }
}

impl Default for TrainOptions {
    fn default() -> Self {
        Self {
            preset: Preset::Parallax,
            width: None,
            steps: 10_000,
            out_dir: PathBuf::from("runs/train"),
            resume: false,
            batch_size: 1,
            lr: 1e-3,
            warmup_steps: 200,
            weight_decay: 1e-4,
            val_every: 250,
            val_samples: 8,
            checkpoint_every_steps: 250,
            checkpoint_every_s: 300.0,
            seed: 1,
            soiled_fraction: 0.3,
            deep360_fraction: 0.25,
            deep360_disk: None,
            deep360_disk_fraction: 1.0,
            mix: SceneMix::default(),
            max_grad_norm: None,
            loss_weighting: LossWeighting::default(),
            camera_effects: false,
            init_weights: None,
            fork_from: None,
            until_step: None,
            device: ComputeDevice::Cpu,
            show_progress: true,
        }
    }
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct TrainSummary {
    /// Step the run started from (non-zero after resume).
    pub start_step: usize,
    /// Steps completed in total (including before a resume).
    pub final_step: usize,
    /// Loss of the last step run (NaN if none ran).
    pub last_loss: f64,
    /// Mean wall time per step of this invocation, seconds.
    pub mean_s_per_step: f64,
    /// Peak resident memory, MiB.
    pub peak_rss_mib: f64,
    pub last_validation: Option<ValRecord>,
    /// Final weights (`out_dir/ssmode_<preset>.safetensors`).
    pub weights_path: PathBuf,
}

/// What one optimizer step did (also the row it appended to `train.csv`).
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// Steps completed, this one included.
    pub step: usize,
    /// Batch loss (the sum of the `1 / batch_size`-scaled sample losses).
    pub loss: f64,
    /// Learning rate the step used.
    pub lr: f64,
    /// Global gradient norm before clipping (NaN if the batch had no gradients).
    pub grad_norm: f64,
    /// Wall time of the step, seconds.
    pub step_s: f64,
}

/// The network configuration of `opts` (the preset, with `width` if set), after checking
/// the options the run cannot start without.
pub(super) fn resolve_config(opts: &TrainOptions) -> Result<SsmodeConfig, TrainError> {
    let mut cfg = opts.preset.config();
    if let Some(w) = opts.width {
        cfg.width = w;
    }
    cfg.validate()?;
    if opts.batch_size == 0 {
        return Err(TrainError::Option {
            option: "batch_size",
            problem: "must be at least 1".into(),
        });
    }
    if !(opts.lr.is_finite() && opts.lr > 0.0) {
        return Err(TrainError::Option {
            option: "lr",
            problem: format!("must be a positive number, got {}", opts.lr),
        });
    }
    Ok(cfg)
}
