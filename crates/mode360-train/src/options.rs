//! What a training run is given and what it returns: [`TrainOptions`] (the options of
//! `mode360 train`, checked by `resolve_config`), [`TrainSummary`], [`StepReport`] and
//! [`TrainError`].

use super::data::{DataError, StreamOptions};
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

/// Default of [`TrainOptions::steps`].
pub const DEFAULT_STEPS: usize = 10_000;
/// Default of [`TrainOptions::lr`].
pub const DEFAULT_LR: f64 = 1e-3;
/// Default of [`TrainOptions::warmup_steps`].
pub const DEFAULT_WARMUP_STEPS: usize = 200;
/// Default of [`TrainOptions::val_every`] and [`TrainOptions::checkpoint_every_steps`].
pub const DEFAULT_EVERY_STEPS: usize = 250;

/// Options of a training run; under the `cli` feature they are `mode360 train`'s options
/// themselves (the fields without a flag keep their defaults there).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct TrainOptions {
    /// Network preset (the shipped weights are parallax_zncc_log).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = Preset::Parallax))]
    pub preset: Preset,
    /// Override the preset's input width (height = width / 2).
    #[cfg_attr(feature = "cli", arg(long))]
    pub width: Option<usize>,
    /// Total optimizer steps (a resumed run continues up to this).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_STEPS))]
    pub steps: usize,
    /// Run folder: checkpoint/, train.csv, val.csv, curves.png, final weights.
    #[cfg_attr(feature = "cli", arg(long = "out", value_name = "DIR"))]
    pub out_dir: PathBuf,
    /// Continue from <out>/checkpoint.
    #[cfg_attr(feature = "cli", arg(long))]
    pub resume: bool,
    /// Samples per step (gradient accumulation).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub batch_size: usize,
    /// Peak learning rate (linear warmup, then cosine decay).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_LR))]
    pub lr: f64,
    /// Steps of the linear learning-rate warmup.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_WARMUP_STEPS))]
    pub warmup_steps: usize,
    #[cfg_attr(feature = "cli", arg(skip = DEFAULT_WEIGHT_DECAY))]
    pub weight_decay: f64,
    /// Validate on the held-out set every this many steps.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_EVERY_STEPS))]
    pub val_every: usize,
    /// Held-out validation frames (Deep360 rig, alternating clean/soiled).
    #[cfg_attr(feature = "cli", arg(skip = DEFAULT_VAL_SAMPLES))]
    pub val_samples: usize,
    /// Checkpoint every this many steps (also every 5 minutes; 0: only by time and at the
    /// end).
    #[cfg_attr(
        feature = "cli",
        arg(long = "checkpoint-every", value_name = "STEPS", default_value_t = DEFAULT_EVERY_STEPS)
    )]
    pub checkpoint_every_steps: usize,
    /// Checkpoint when this many seconds passed since the last one.
    #[cfg_attr(feature = "cli", arg(skip = DEFAULT_CHECKPOINT_EVERY_S))]
    pub checkpoint_every_s: f64,
    /// The sample stream: seed, soiling, rigs, scene mix (saved in the checkpoint, compared on
    /// resume).
    #[cfg_attr(feature = "cli", command(flatten))]
    pub stream: StreamOptions,
    /// Mix training frames of the paper's Deep360 dataset at this root into the samples.
    #[cfg_attr(feature = "cli", arg(long = "deep360", value_name = "DIR"))]
    pub deep360_disk: Option<PathBuf>,
    /// Fraction of samples taken from --deep360 (the rest are rendered).
    #[cfg_attr(
        feature = "cli",
        arg(
            long = "deep360-fraction",
            value_name = "FRACTION",
            default_value_t = 1.0,
            requires = "deep360_disk"
        )
    )]
    pub deep360_disk_fraction: f64,
    /// Clip the global gradient norm to this (off when absent).
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_grad_norm: Option<f64>,
    /// Learning-rate multiplier of the fine head's variables (`fine_head.*`): a head added to
    /// fine-tuned start weights starts at zero and learns at a fine-tuning rate far too slowly
    /// (its output weights moved 0.003 in 800 steps at 2e-5), so it can learn at a fresh run's.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "FACTOR", default_value_t = DEFAULT_FINE_HEAD_LR_SCALE)
    )]
    pub fine_head_lr_scale: f64,
    /// Train the fine head alone (`fine_head.*`, preset `parallax_zncc_log_fine`), the rest
    /// of the network frozen at its start weights: the head's inputs are detached, so a step
    /// costs about a third of a full one, and what the start weights read without the head
    /// stays as it was. The loss reads only the final stage.
    #[cfg_attr(feature = "cli", arg(long))]
    pub fine_head_only: bool,
    /// The loss's extra weights (near pixels, too far, obstacles).
    #[cfg_attr(feature = "cli", command(flatten))]
    pub loss_weighting: LossWeighting,
    /// Fine-tune: start a new run from these weights (e.g. models/ssmode_compact.safetensors)
    /// instead of a random initialisation. Ignored when --resume finds a checkpoint. The
    /// file's network must have the preset's layer sizes.
    #[cfg_attr(feature = "cli", arg(long))]
    pub init_weights: Option<PathBuf>,
    /// Start a new run from another run's folder (or its checkpoint/): its weights, optimizer
    /// moments, step and sample position, with this run's seed and data options (an ablation
    /// of the data mix at equal steps). Ignored when --resume finds a checkpoint. Only the
    /// network (preset, width) and the batch size must match.
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "init_weights"))]
    pub fork_from: Option<PathBuf>,
    /// Stop after this step; the learning-rate schedule still runs over --steps (the arms of
    /// an ablation stop at the same step).
    #[cfg_attr(feature = "cli", arg(long))]
    pub until_step: Option<usize>,
    /// Where the network trains: cpu, or cuda:N for the N-th NVIDIA GPU (needs a build with
    /// the `cuda` feature).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = ComputeDevice::Cpu))]
    pub device: ComputeDevice,
    #[cfg_attr(feature = "cli", arg(skip = true))]
    pub show_progress: bool,
}

/// Default of [`TrainOptions::fine_head_lr_scale`]: the head learns at the network's rate.
pub const DEFAULT_FINE_HEAD_LR_SCALE: f64 = 1.0;
/// Default of [`TrainOptions::weight_decay`].
pub const DEFAULT_WEIGHT_DECAY: f64 = 1e-4;
/// Default of [`TrainOptions::val_samples`].
pub const DEFAULT_VAL_SAMPLES: usize = 8;
/// Default of [`TrainOptions::checkpoint_every_s`].
pub const DEFAULT_CHECKPOINT_EVERY_S: f64 = 300.0;

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
            steps: DEFAULT_STEPS,
            out_dir: PathBuf::from("runs/train"),
            resume: false,
            batch_size: 1,
            lr: DEFAULT_LR,
            warmup_steps: DEFAULT_WARMUP_STEPS,
            weight_decay: DEFAULT_WEIGHT_DECAY,
            val_every: DEFAULT_EVERY_STEPS,
            val_samples: DEFAULT_VAL_SAMPLES,
            checkpoint_every_steps: DEFAULT_EVERY_STEPS,
            checkpoint_every_s: DEFAULT_CHECKPOINT_EVERY_S,
            stream: StreamOptions::default(),
            deep360_disk: None,
            deep360_disk_fraction: 1.0,
            max_grad_norm: None,
            fine_head_lr_scale: DEFAULT_FINE_HEAD_LR_SCALE,
            fine_head_only: false,
            loss_weighting: LossWeighting::default(),
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
    if !(opts.fine_head_lr_scale.is_finite() && opts.fine_head_lr_scale > 0.0) {
        return Err(TrainError::Option {
            option: "fine_head_lr_scale",
            problem: format!("must be a positive number, got {}", opts.fine_head_lr_scale),
        });
    }
    if opts.fine_head_only && cfg.fine_head_channels == 0 {
        return Err(TrainError::Option {
            option: "fine_head_only",
            problem: format!(
                "preset {} has no fine head to train (use parallax_zncc_log_fine)",
                opts.preset
            ),
        });
    }
    Ok(cfg)
}
