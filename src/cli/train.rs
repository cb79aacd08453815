//! `mode360 train`: the training command over [`mode360_train`].

use anyhow::Result;
use clap::Args;
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
    /// Fusion: the head, correction (of the most confident pair's range) or select (weights
    /// over the pairs, blending their ranges; its base input is the pairs' consensus).
    #[arg(long, value_enum, default_value_t = mode360_model::model::FusionHead::Correction)]
    pub fusion_head: mode360_model::model::FusionHead,
    /// Fusion, select head: the pair encoder also sees each pair's support (the
    /// confidence-weighted share of the pairs within one δ1 interval of its range).
    #[arg(long)]
    pub fusion_support: bool,
    /// Fusion: stage 1's input width (0: the width it was trained at, 256); wider than
    /// --width, the stream renders at this width, stage 1 runs there and its pairs and the
    /// ground truth are brought onto the fusion's grid.
    #[arg(long, default_value_t = 0)]
    pub fusion_pair_width: usize,
    /// Fusion: held-out validation frames.
    #[arg(long, default_value_t = 8)]
    pub fusion_val_samples: usize,
    /// The run: network, schedule, data stream, loss.
    #[command(flatten)]
    pub train: TrainOptions,
}

/// `mode360 train`: trains (or resumes) and prints where the weights went.
pub fn run(a: TrainArgs) -> Result<()> {
    if a.stage == TrainStage::Fusion {
        return run_fusion(a);
    }
    let s = run_training(&a.train)?;
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
    let t = a.train;
    let preset = match a.fusion_head {
        mode360_model::model::FusionHead::Correction => FusionConfig::small(),
        mode360_model::model::FusionHead::Select => FusionConfig::select(),
    };
    if a.fusion_support && preset.head != mode360_model::model::FusionHead::Select {
        anyhow::bail!("--fusion-support needs --fusion-head select");
    }
    let config = FusionConfig {
        width: t.width.unwrap_or(preset.width),
        support_input: a.fusion_support,
        ..preset
    };
    // the fusion trains on whole rigs: stage 1 makes the pairs
    let mut stream = t.stream;
    stream.mix.camera_pairs = false;
    let stage1_weights = a
        .stage1_weights
        .unwrap_or_else(|| mode360_estimator::EstimatorKind::Psmode.default_weights_path());
    let opts = FusionTrainOptions {
        out_dir: t.out_dir,
        stage1_weights,
        pair_width: a.fusion_pair_width,
        samples: a.fusion_samples,
        steps: t.steps,
        until_step: t.until_step,
        lr: t.lr,
        warmup_steps: t.warmup_steps,
        val_samples: a.fusion_val_samples,
        val_every: t.val_every,
        checkpoint_every: t.checkpoint_every_steps,
        resume: t.resume,
        data: DataConfig {
            stream,
            width: config.width.max(a.fusion_pair_width),
            max_depth_m: config.max_depth_m,
            deep360_disk: None,
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
