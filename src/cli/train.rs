//! `mode360 train`: the training command over [`mode360_train`].

use anyhow::Result;
use clap::Args;
use mode360_model::model::{ComputeDevice, Preset};
use mode360_train::data::SceneMix;
use mode360_train::{run_training, TrainOptions};
use std::path::PathBuf;

/// Which network `mode360 train` trains.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum TrainStage {
    /// SSMODE, also PSMODE's stage 1 with --camera-pairs.
    #[default]
    Ssmode,
    /// PSMODE's fusion network (stage 2) on stage 1's pairwise output (--stage1-weights).
    Fusion,
}

#[derive(Args)]
pub struct TrainArgs {
    /// The network to train: ssmode (also PSMODE's stage 1, with --camera-pairs) or fusion
    /// (PSMODE's stage 2: --stage1-weights, --fusion-samples, --width; the data options apply).
    #[arg(long, value_enum, default_value_t = TrainStage::Ssmode)]
    pub stage: TrainStage,
    /// Fusion: the stage-1 weights whose pairwise output it learns to fuse (default: PSMODE's
    /// shipped stage 1, models/psmode_stage1.safetensors).
    #[arg(long)]
    pub stage1_weights: Option<PathBuf>,
    /// Fusion: training set size (the stream's first samples; stage 1's output for each is
    /// cached in <out>/stage1_cache/).
    #[arg(long, default_value_t = 400)]
    pub fusion_samples: usize,
    /// Fusion: the range loss, log-l1 (absolute error of log range) or silog (the paper's,
    /// lambda 0.5).
    #[arg(long, value_enum, default_value_t = mode360_train::fusion::FusionLoss::LogL1)]
    pub fusion_loss: mode360_train::fusion::FusionLoss,
    /// Fusion: held-out validation frames.
    #[arg(long, default_value_t = 8)]
    pub fusion_val_samples: usize,
    /// Network preset (the shipped weights are parallax_zncc_log).
    #[arg(long, value_enum, default_value_t = Preset::Parallax)]
    pub preset: Preset,
    /// Override the preset's input width (height = width / 2).
    #[arg(long)]
    pub width: Option<usize>,
    /// Total optimizer steps (a resumed run continues up to this).
    #[arg(long, default_value_t = 10_000)]
    pub steps: usize,
    /// Run folder: checkpoint/, train.csv, val.csv, curves.png, final weights.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from <out>/checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Samples per step (gradient accumulation).
    #[arg(long, default_value_t = 1)]
    pub batch_size: usize,
    /// Peak learning rate (linear warmup, then cosine decay).
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Steps of the linear learning-rate warmup.
    #[arg(long, default_value_t = 200)]
    pub warmup_steps: usize,
    /// Validate on the held-out set every this many steps.
    #[arg(long, default_value_t = 250)]
    pub val_every: usize,
    /// Checkpoint every this many steps (also every 5 minutes).
    #[arg(long, default_value_t = 250)]
    pub checkpoint_every: usize,
    /// Data seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Mix training frames of the paper's Deep360 dataset at this root into the samples.
    #[arg(long)]
    pub deep360: Option<PathBuf>,
    /// Fraction of samples taken from --deep360 (the rest are rendered).
    #[arg(long, default_value_t = 1.0, requires = "deep360")]
    pub deep360_fraction: f64,
    /// Fine-tune: start a new run from these weights (e.g. models/ssmode_compact.safetensors)
    /// instead of a random initialisation. Ignored when --resume finds a checkpoint.
    #[arg(long)]
    pub init_weights: Option<PathBuf>,
    /// Start a new run from another run's folder (or its checkpoint/): its weights, optimizer
    /// moments, step and sample position, with this run's seed and data options (an ablation of
    /// the data mix at equal steps). Ignored when --resume finds a checkpoint.
    #[arg(long, conflicts_with = "init_weights")]
    pub fork_from: Option<PathBuf>,
    /// Stop after this step; the learning-rate schedule still runs over --steps (the arms of
    /// an ablation stop at the same step).
    #[arg(long)]
    pub until_step: Option<usize>,
    /// Fraction of samples with lens soiling.
    #[arg(long, default_value_t = 0.3)]
    pub soiled_fraction: f64,
    /// Fraction of rendered street and object samples on the Deep360 rig (the rest on random
    /// roof racks of 2 to 5 cameras).
    #[arg(long, default_value_t = 0.25)]
    pub deep360_rig_fraction: f64,
    /// Clip the global gradient norm to this (off when absent).
    #[arg(long)]
    pub max_grad_norm: Option<f64>,
    /// Give every rendered camera image a real camera's effects: exposure, white balance,
    /// vignetting, blur, sensor noise and JPEG compression, drawn per camera.
    #[arg(long)]
    pub camera_effects: bool,
    /// What the rendered samples hold.
    #[command(flatten)]
    pub mix: SceneMix,
    /// The loss's extra weights (near pixels, too far, obstacles).
    #[command(flatten)]
    pub loss_weighting: mode360_train::loss::LossWeighting,
    /// Where the network trains: cpu, or cuda:N for the N-th NVIDIA GPU (needs a build with the
    /// `cuda` feature).
    #[arg(long, default_value_t = ComputeDevice::Cpu)]
    pub device: ComputeDevice,
}

/// `mode360 train`: trains (or resumes) and prints where the weights went.
pub fn run(a: TrainArgs) -> Result<()> {
    if a.stage == TrainStage::Fusion {
        return run_fusion(a);
    }
    let opts = TrainOptions {
        preset: a.preset,
        width: a.width,
        steps: a.steps,
        out_dir: a.out,
        resume: a.resume,
        batch_size: a.batch_size,
        lr: a.lr,
        warmup_steps: a.warmup_steps,
        val_every: a.val_every,
        checkpoint_every_steps: a.checkpoint_every,
        seed: a.seed,
        deep360_disk: a.deep360,
        deep360_disk_fraction: a.deep360_fraction,
        init_weights: a.init_weights,
        fork_from: a.fork_from,
        until_step: a.until_step,
        mix: a.mix,
        soiled_fraction: a.soiled_fraction,
        deep360_fraction: a.deep360_rig_fraction,
        max_grad_norm: a.max_grad_norm,
        loss_weighting: a.loss_weighting,
        camera_effects: a.camera_effects,
        device: a.device,
        ..TrainOptions::default()
    };
    let s = run_training(&opts)?;
    println!(
        "trained steps {}..{} ({:.2} s/step, peak RSS {:.0} MiB); weights: {}",
        s.start_step,
        s.final_step,
        s.mean_s_per_step,
        s.peak_rss_mib,
        s.weights_path.display()
    );
    if let Some(v) = s.last_validation {
        println!("last validation: {v:?}");
    }
    Ok(())
}

/// `mode360 train --stage fusion`.
fn run_fusion(a: TrainArgs) -> Result<()> {
    use anyhow::Context;
    use mode360_model::model::FusionConfig;
    use mode360_train::data::DataConfig;
    use mode360_train::fusion::{run_fusion_training, FusionTrainOptions};
    let config = FusionConfig {
        width: a.width.unwrap_or(FusionConfig::small().width),
        ..FusionConfig::small()
    };
    // the fusion trains on whole rigs: stage 1 makes the pairs
    let mix = SceneMix {
        camera_pairs: false,
        ..a.mix
    };
    let stage1_weights = a
        .stage1_weights
        .unwrap_or_else(|| mode360_estimator::EstimatorKind::Psmode.default_weights_path());
    let opts = FusionTrainOptions {
        out_dir: a.out,
        stage1_weights,
        samples: a.fusion_samples,
        steps: a.steps,
        until_step: a.until_step,
        lr: a.lr,
        warmup_steps: a.warmup_steps,
        val_samples: a.fusion_val_samples,
        val_every: a.val_every,
        checkpoint_every: a.checkpoint_every,
        resume: a.resume,
        data: DataConfig {
            seed: a.seed,
            width: config.width,
            max_depth_m: config.max_depth_m,
            soiled_fraction: a.soiled_fraction,
            deep360_fraction: a.deep360_rig_fraction,
            deep360_disk: None,
            mix,
            camera_effects: a.camera_effects,
        },
        config,
        loss: a.fusion_loss,
        show_progress: true,
    };
    let s = run_fusion_training(&opts).context("training PSMODE's fusion network")?;
    println!(
        "trained fusion steps {}..{}; weights: {}",
        s.start_step,
        s.final_step,
        s.weights.display()
    );
    if let Some((fused, pair)) = s.last_val_delta1_pct {
        println!("last validation: δ1 fused {fused:.2} %, most confident pair {pair:.2} %");
    }
    Ok(())
}
