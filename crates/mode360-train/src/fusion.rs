//! Training PSMODE's fusion network (stage 2, `mode360 train --stage fusion`), separately from
//! stage 1 as the paper does.
//!
//! * Data: sample `k` is the training stream's rendered sample `k` (the same [`DataConfig`]
//!   as SSMODE's runs; fisheye images as panoramas), run through stage 1 (the stage-1 weights
//!   given, every pair of the rig, [`PsmodeEstimator::pairwise_on`]) on the fusion grid. With
//!   a `pair_width` wider than the fusion grid the stream renders at that width, stage 1 runs
//!   there and its pairs are splatted onto the fusion grid; the ground truth is brought there
//!   by the nearest range of each block of pixels (as the splat keeps the nearest). The
//!   first `samples` of the stream are the training set: stage 1's output for each is cached
//!   in `out_dir/stage1_cache/` on first use, so later epochs cost only the fusion network.
//!   Step `s` uses sample `perm(s)`, a seeded shuffle per epoch.
//! * Loss ([`FusionLoss`]): the mean absolute error of log range, or the paper's SILog (Eq. 6,
//!   `lambda = 0.5`), over the pixels with ground truth, plus [`CONFIDENCE_LOSS_WEIGHT`] times
//!   the binary cross-entropy of the confidence against "within δ1 of the truth".
//! * Held out: `val_samples` frames of [`validation_specs`] (never trained on), also cached;
//!   `val.csv` has the fused δ1 and the line printed beside it the most confident pair's
//!   (the gain of fusion over pairwise).
//! * Checkpoint: `out_dir/checkpoint/` holds `model.safetensors` (fusion config in the header),
//!   `optimizer.safetensors` and `state.json`, written into `checkpoint.tmp/` and renamed;
//!   final weights go to `out_dir/psmode_fusion.safetensors`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;

use super::data::{
    render_panoramas, sample_rig, training_spec, validation_specs, DataConfig, SampleSpec,
};
use super::init::{named_vars, seeded_var_builder};
use super::log::{self, TrainRecord, ValRecord};
use super::optim::{AdamW, AdamWParams, LrSchedule};
use super::options::{io_err, TrainError};
use mode360_core::geometry::panorama::panorama_rig;
use mode360_core::geometry::{CameraPair, ErpGrid, PairView};
use mode360_core::metrics::{depth_metrics, FrameAverage};
use mode360_core::progress::frames_bar;
use mode360_estimator::psmode::{fusion_tensors, PairChoice, PsmodeEstimator, TRAINED_PAIR_WIDTH};
use mode360_model::model::{save_fusion_weights, ComputeDevice, Fusion, FusionConfig, FusionHead};

/// The fusion's range loss.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum FusionLoss {
    /// The paper's SILog on log range, `lambda = SILOG_LAMBDA`: squared, so where the pairs
    /// disagree between a near surface and the sky it settles between them.
    Silog,
    /// The mean absolute error of log range: settles on one of the pairs' answers.
    #[default]
    LogL1,
}

/// SILog's `lambda` (paper: 0.5, half scale-invariant, half absolute).
pub const SILOG_LAMBDA: f64 = 0.5;
/// Weight of the confidence's cross-entropy beside SILog.
pub const CONFIDENCE_LOSS_WEIGHT: f64 = 0.1;
/// `ln 1.25`: a pixel within δ1 of the truth is a confident one.
const DELTA1_LOG: f64 = 0.223_143_551_314_209_7;
/// Where stage 1's outputs are cached, under the run directory.
pub const STAGE1_CACHE_DIR: &str = "stage1_cache";
/// The final weights, under the run directory.
pub const FUSION_WEIGHTS_FILE: &str = "psmode_fusion.safetensors";
/// Domain separation of the epoch shuffles.
const SHUFFLE_TAG: u64 = 0x7A41_F001;

/// Options of a fusion run.
#[derive(Clone, Debug, PartialEq)]
pub struct FusionTrainOptions {
    pub out_dir: PathBuf,
    /// Stage-1 (SSMODE-architecture) weights whose pairwise output the fusion learns to fuse.
    pub stage1_weights: PathBuf,
    /// Stage 1's input width (as the estimator's `pair_width`; [`TRAINED_PAIR_WIDTH`]: the
    /// width its network was trained at). Wider than the fusion grid, the stream renders at
    /// this width ([`FusionTrainOptions::render_width`]).
    pub pair_width: usize,
    pub config: FusionConfig,
    pub loss: FusionLoss,
    /// Training set size (the stream's first samples).
    pub samples: usize,
    pub steps: usize,
    pub until_step: Option<usize>,
    pub lr: f64,
    pub warmup_steps: usize,
    pub val_samples: usize,
    pub val_every: usize,
    pub checkpoint_every: usize,
    pub resume: bool,
    /// The sample stream (its width is the fusion config's).
    pub data: DataConfig,
    pub show_progress: bool,
}

/// What must match to resume a run.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct FusionState {
    step: usize,
    samples: usize,
    seed: u64,
    width: usize,
    stage1_weights: String,
    #[serde(default = "silog")]
    loss: FusionLoss,
    #[serde(default)]
    pair_width: usize,
    #[serde(default)]
    head: FusionHead,
    #[serde(default)]
    support_input: bool,
}

impl FusionTrainOptions {
    /// The width the stream must render at: the fusion grid's, or stage 1's where wider.
    pub fn render_width(&self) -> usize {
        self.config.width.max(self.pair_width)
    }
}

/// The loss of checkpoints written before the choice existed.
fn silog() -> FusionLoss {
    FusionLoss::Silog
}

/// One cached stage-1 result.
struct CachedSample {
    pairs: Tensor,
    base: Tensor,
    rgb: Tensor,
    gt: Tensor,
}

/// What a fusion run did.
#[derive(Clone, Debug, PartialEq)]
pub struct FusionSummary {
    pub start_step: usize,
    pub final_step: usize,
    pub weights: PathBuf,
    /// The last validation: fused δ1 and the most confident pair's, percent.
    pub last_val_delta1_pct: Option<(f64, f64)>,
}

fn other(e: impl std::fmt::Display) -> TrainError {
    TrainError::Other(e.to_string())
}

/// The seeded shuffle of epoch `epoch` over `n` samples (Fisher-Yates).
fn epoch_order(seed: u64, epoch: u64, n: usize) -> Vec<usize> {
    let mut rng = mode360_synth::noise::Rng::new(&[seed, epoch, SHUFFLE_TAG]);
    let mut order: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        order.swap(i, rng.index(i + 1));
    }
    order
}

/// The range loss (`kind`) plus the confidence's cross-entropy, over pixels with ground truth
/// (`gt > 0`).
pub fn fusion_loss(
    kind: FusionLoss,
    net: &Fusion,
    out: &mode360_model::model::FusionOutput,
    gt: &Tensor,
) -> Result<Tensor, TrainError> {
    let cfg = net.config();
    // (B, H, W)
    let valid = gt.gt(0.0)?.to_dtype(DType::F32)?;
    let n = (valid.sum_all()?.to_scalar::<f32>()? as f64).max(1.0);
    let log_gt = gt.clamp(cfg.min_depth_m, cfg.max_depth_m)?.log()?;
    // log y_hat = ln max - t ln(max / min)
    let log_pred = ((&out.index * (-cfg.log_span()))? + cfg.max_depth_m.ln())?;
    let d = ((log_pred - log_gt)? * &valid)?;
    let range_loss = match kind {
        FusionLoss::Silog => {
            let mean_d = (d.sum_all()? / n)?;
            ((d.sqr()?.sum_all()? / n)? - (mean_d.sqr()? * SILOG_LAMBDA)?)?
        }
        FusionLoss::LogL1 => (d.abs()?.sum_all()? / n)?,
    };
    // BCE(sigmoid(z), y) = softplus(z) - y z, softplus(z) = relu(z) + ln(1 + exp(-|z|))
    let z = &out.confidence_logit;
    let hit = d.abs()?.lt(DELTA1_LOG)?.to_dtype(DType::F32)?.detach();
    let softplus = (z.relu()? + (z.abs()?.neg()?.exp()? + 1.0)?.log()?)?;
    let bce = ((softplus - (hit * z)?)? * &valid)?.sum_all()?;
    Ok((range_loss + ((bce / n)? * CONFIDENCE_LOSS_WEIGHT)?)?)
}

/// The cache's key of the base estimate a head reads (the most confident pair, or the pairs'
/// consensus), so that a cache written for one head is refused by the other.
fn base_key(head: FusionHead) -> &'static str {
    match head {
        FusionHead::Correction => "base",
        FusionHead::Select => "consensus",
    }
}

/// Ground truth on `fine` brought onto `coarse` (`fine` a whole multiple of it): per coarse
/// pixel the nearest positive range of its block (the sky's `+Inf` where that is all there
/// is; 0, no ground truth, where the block has none).
fn nearest_in_blocks(range_m: &[f32], fine: ErpGrid, coarse: ErpGrid) -> Vec<f32> {
    let f = fine.width() / coarse.width();
    if f <= 1 {
        return range_m.to_vec();
    }
    let mut out = vec![0.0f32; coarse.len()];
    for (v, row) in out.chunks_mut(coarse.width()).enumerate() {
        for (u, px) in row.iter_mut().enumerate() {
            *px = (0..f * f)
                .map(|k| range_m[(v * f + k / f) * fine.width() + u * f + k % f])
                .filter(|r| *r > 0.0)
                .min_by(f32::total_cmp)
                .unwrap_or(0.0);
        }
    }
    out
}

/// A fusion run.
pub struct FusionTrainer {
    opts: FusionTrainOptions,
    varmap: VarMap,
    net: Fusion,
    opt: AdamW,
    schedule: LrSchedule,
    stage1: PsmodeEstimator,
    state: FusionState,
    device: Device,
}

impl FusionTrainer {
    pub fn new(opts: &FusionTrainOptions) -> Result<Self, TrainError> {
        opts.config.validate().map_err(|e| TrainError::Option {
            option: "fusion config",
            problem: e.to_string(),
        })?;
        if opts.samples == 0 || opts.steps == 0 {
            return Err(TrainError::Option {
                option: "fusion_samples",
                problem: "need at least one sample and one step".into(),
            });
        }
        let render = opts.render_width();
        if opts.data.width != render || !render.is_multiple_of(opts.config.width) {
            return Err(TrainError::Option {
                option: "width",
                problem: format!(
                    "the stream renders {} wide, the fusion network is {} wide and stage 1 \
                     runs at {} (the stream must render at {render}, a multiple of the \
                     network's width)",
                    opts.data.width, opts.config.width, opts.pair_width
                ),
            });
        }
        std::fs::create_dir_all(opts.out_dir.join(STAGE1_CACHE_DIR))
            .map_err(io_err(&opts.out_dir))?;
        let device = Device::Cpu;
        let stage1 = PsmodeEstimator::load_on(
            &opts.stage1_weights,
            None,
            ComputeDevice::Cpu,
            PairChoice::All,
            // stage 1 runs at `pair_width` where the stream renders that wide, else at its
            // trained width
            if opts.pair_width > opts.config.width {
                opts.pair_width
            } else {
                TRAINED_PAIR_WIDTH
            },
        )
        .map_err(other)?;
        let mut varmap = VarMap::new();
        // seeded, so that a resumed run equals a straight one
        let net = Fusion::new(
            &opts.config,
            seeded_var_builder(&varmap, opts.data.stream.seed, &device),
        )?;
        let mut opt = AdamW::new(named_vars(&varmap)?, AdamWParams::default())?;
        let mut state = FusionState {
            step: 0,
            samples: opts.samples,
            seed: opts.data.stream.seed,
            width: opts.config.width,
            stage1_weights: opts.stage1_weights.display().to_string(),
            loss: opts.loss,
            pair_width: opts.pair_width,
            head: opts.config.head,
            support_input: opts.config.support_input,
        };
        let ckpt = opts.out_dir.join(super::CHECKPOINT_DIR);
        if opts.resume && ckpt.join(super::STATE_FILE).is_file() {
            state = resume(&ckpt, &state, &mut varmap, &mut opt, &device)?;
        }
        Ok(Self {
            opts: opts.clone(),
            schedule: LrSchedule {
                base_lr: opts.lr,
                warmup_steps: opts.warmup_steps,
                total_steps: opts.steps,
                min_lr_fraction: 0.1,
            },
            varmap,
            net,
            opt,
            stage1,
            state,
            device,
        })
    }

    /// Stage 1's output for `spec` (cached under `name`), as the fusion network's inputs.
    fn sample(&mut self, name: &str, spec: &SampleSpec) -> Result<CachedSample, TrainError> {
        let path = self
            .opts
            .out_dir
            .join(STAGE1_CACHE_DIR)
            .join(format!("{name}.safetensors"));
        if path.is_file() {
            let mut t = candle_core::safetensors::load(&path, &self.device)?;
            let mut take = |k: &str| {
                t.remove(k).ok_or_else(|| TrainError::Checkpoint {
                    path: path.display().to_string(),
                    problem: format!("no tensor '{k}'"),
                })
            };
            let pairs = take("pairs")?;
            let cached = CachedSample {
                pairs: self.with_parallax(pairs, spec)?,
                base: take(base_key(self.opts.config.head))?,
                rgb: take("rgb")?,
                gt: take("gt")?,
            };
            return Ok(cached);
        }
        let r = render_panoramas(&self.opts.data, spec)?;
        let grid = ErpGrid::new(self.opts.config.width).map_err(other)?;
        let render = ErpGrid::new(r.range_m.width).map_err(other)?;
        let rig = panorama_rig(&r.rig);
        // the render grid too where it is wider, so that stage 1 runs at its width
        let grids = if render == grid {
            vec![grid]
        } else {
            vec![grid, render]
        };
        let pairwise = self
            .stage1
            .pairwise_on(&rig, &r.panoramas, &grids, Some(grid))
            .map_err(other)?
            .into_iter()
            .next()
            .ok_or_else(|| other("stage 1 returned nothing"))?;
        let (pairs, base, rgb) =
            fusion_tensors(&self.opts.config, &pairwise, &self.device).map_err(other)?;
        let gt = nearest_in_blocks(&r.range_m.data, render, grid);
        let gt = Tensor::from_vec(gt, (1, grid.height(), grid.width()), &self.device)?;
        let tensors = HashMap::from([
            ("pairs".to_string(), pairs.clone()),
            (base_key(self.opts.config.head).to_string(), base.clone()),
            ("rgb".to_string(), rgb.clone()),
            ("gt".to_string(), gt.clone()),
        ]);
        let tmp = path.with_extension("tmp");
        candle_core::safetensors::save(&tensors, &tmp)?;
        std::fs::rename(&tmp, &path).map_err(io_err(&path))?;
        Ok(CachedSample {
            pairs,
            base,
            rgb,
            gt,
        })
    }

    /// Cached pairs written before the parallax channel existed, `(1, P, H, W, 2)`, with it
    /// appended (from the sample's rig: every pair, as stage 1 ran them on 360° rigs); newer
    /// ones as they are.
    fn with_parallax(&self, pairs: Tensor, spec: &SampleSpec) -> Result<Tensor, TrainError> {
        let (_, p, h, w, c) = pairs.dims5()?;
        if c != 2 {
            return Ok(pairs);
        }
        let rig = panorama_rig(&sample_rig(&self.opts.data, spec)?);
        let all = CameraPair::all(rig.cameras.len());
        if all.len() != p {
            return Err(other(format!(
                "a cached sample has {p} pairs, its rig {} (cached by another stage 1?)",
                all.len()
            )));
        }
        let grid = ErpGrid::new(w).map_err(other)?;
        let mut maps = Vec::with_capacity(p * h * w);
        for pair in all {
            let view = PairView::new(&rig, pair).map_err(other)?;
            maps.extend(view.parallax_on(grid, &rig.rig_from_output));
        }
        let parallax = Tensor::from_vec(maps, (1, p, h, w, 1), &self.device)?;
        Ok(Tensor::cat(&[&pairs, &parallax], 4)?)
    }

    /// One step on the next training sample; its loss.
    fn step(&mut self) -> Result<f64, TrainError> {
        let step = self.state.step;
        let n = self.opts.samples;
        let index = epoch_order(self.opts.data.stream.seed, (step / n) as u64, n)[step % n];
        let spec = training_spec(&self.opts.data, index as u64);
        let s = self.sample(&format!("train_{index:05}"), &spec)?;
        let out = self.net.forward(&s.pairs, &s.base, &s.rgb)?;
        let loss = fusion_loss(self.opts.loss, &self.net, &out, &s.gt)?;
        let grads = loss.backward()?;
        self.opt.step(&grads, self.schedule.lr(step))?;
        self.state.step += 1;
        Ok(f64::from(loss.to_scalar::<f32>()?))
    }

    /// Fused and most-confident-pair metrics over the held-out frames.
    fn validate(&mut self) -> Result<(ValRecord, f64), TrainError> {
        let (mut fused, mut base) = (FrameAverage::default(), FrameAverage::default());
        let mut loss_sum = 0.0;
        let specs = validation_specs(self.opts.val_samples);
        let max = self.opts.data.max_depth_m;
        for (k, spec) in specs.iter().enumerate() {
            let s = self.sample(&format!("val_{k:03}"), spec)?;
            let out = self.net.forward(&s.pairs, &s.base, &s.rgb)?;
            loss_sum +=
                f64::from(fusion_loss(self.opts.loss, &self.net, &out, &s.gt)?.to_scalar::<f32>()?);
            let gt: Vec<f32> = s.gt.flatten_all()?.to_vec1()?;
            let pred: Vec<f32> = self.net.range_m(&out)?.flatten_all()?.to_vec1()?;
            let base_index: Vec<f32> = s.base.narrow(3, 0, 1)?.flatten_all()?.to_vec1()?;
            let base_range: Vec<f32> = base_index
                .iter()
                .map(|&t| self.opts.config.range_of_index(f64::from(t)) as f32)
                .collect();
            fused.push(depth_metrics(&pred, &gt, max).map_err(other)?, None);
            base.push(depth_metrics(&base_range, &gt, max).map_err(other)?, None);
        }
        let rec = ValRecord {
            step: self.state.step,
            loss: loss_sum / specs.len().max(1) as f64,
            metrics: fused.depth(),
            peak_rss_mib: log::peak_rss_mib(),
        };
        Ok((rec, base.depth().delta1_pct))
    }

    fn checkpoint(&self) -> Result<(), TrainError> {
        let dir = self.opts.out_dir.join(super::CHECKPOINT_DIR);
        let tmp = self.opts.out_dir.join("checkpoint.tmp");
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(io_err(&tmp))?;
        save_fusion_weights(&self.varmap, &self.opts.config, tmp.join(super::MODEL_FILE))?;
        candle_core::safetensors::save(&self.opt.state_tensors(), tmp.join(super::OPTIMIZER_FILE))?;
        let json = serde_json::to_string_pretty(&self.state).map_err(other)?;
        std::fs::write(tmp.join(super::STATE_FILE), json).map_err(io_err(&tmp))?;
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::rename(&tmp, &dir).map_err(io_err(&dir))
    }

    /// Runs to `until_step` (or `steps`), validating and checkpointing as configured.
    pub fn run(mut self) -> Result<FusionSummary, TrainError> {
        let start = self.state.step;
        let end = self
            .opts
            .until_step
            .unwrap_or(self.opts.steps)
            .min(self.opts.steps);
        let dir = self.opts.out_dir.clone();
        let (train_csv, val_csv) = (dir.join(super::TRAIN_CSV), dir.join(super::VAL_CSV));
        log::truncate_after_step(&train_csv, log::TRAIN_CSV_HEADER, start)
            .map_err(io_err(&train_csv))?;
        log::truncate_after_step(&val_csv, log::VAL_CSV_HEADER, start).map_err(io_err(&val_csv))?;
        let bar = frames_bar(
            "fusion steps",
            end.saturating_sub(start),
            self.opts.show_progress,
        );
        let mut last_val = None;
        while self.state.step < end {
            let t0 = Instant::now();
            let loss = self.step()?;
            log::append_train(
                &train_csv,
                &TrainRecord {
                    step: self.state.step,
                    loss,
                    lr: self.schedule.lr(self.state.step - 1),
                    step_s: t0.elapsed().as_secs_f64(),
                    peak_rss_mib: log::peak_rss_mib(),
                },
            )
            .map_err(io_err(&train_csv))?;
            bar.inc(1);
            let step = self.state.step;
            if self.opts.val_every > 0
                && self.opts.val_samples > 0
                && (step.is_multiple_of(self.opts.val_every) || step == end)
            {
                let (rec, base_delta1) = self.validate()?;
                log::append_val(&val_csv, &rec).map_err(io_err(&val_csv))?;
                mode360_core::progress::println(
                    &bar,
                    format!(
                    "step {step}: val loss {:.4}, δ1 fused {:.2} % (most confident pair {:.2} %)",
                    rec.loss, rec.metrics.delta1_pct, base_delta1
                    ),
                );
                last_val = Some((rec.metrics.delta1_pct, base_delta1));
                log::plot_curves(&train_csv, &val_csv, &dir.join(super::CURVES_PNG))
                    .map_err(TrainError::Other)?;
            }
            if (self.opts.checkpoint_every > 0 && step.is_multiple_of(self.opts.checkpoint_every))
                || step == end
            {
                self.checkpoint()?;
            }
        }
        bar.finish_and_clear();
        let weights = dir.join(FUSION_WEIGHTS_FILE);
        save_fusion_weights(&self.varmap, &self.opts.config, &weights)?;
        Ok(FusionSummary {
            start_step: start,
            final_step: self.state.step,
            weights,
            last_val_delta1_pct: last_val,
        })
    }
}

/// Loads a fusion checkpoint into `varmap` and `opt` after checking it is this run's.
fn resume(
    dir: &Path,
    expected: &FusionState,
    varmap: &mut VarMap,
    opt: &mut AdamW,
    device: &Device,
) -> Result<FusionState, TrainError> {
    let bad = |problem: String| TrainError::Checkpoint {
        path: dir.display().to_string(),
        problem,
    };
    let state_path = dir.join(super::STATE_FILE);
    let text = std::fs::read_to_string(&state_path).map_err(io_err(&state_path))?;
    let state: FusionState =
        serde_json::from_str(&text).map_err(|e| bad(format!("state.json: {e}")))?;
    let differs = FusionState {
        step: expected.step,
        ..state.clone()
    } != *expected;
    if differs {
        return Err(bad(format!(
            "was written by another run ({state:?}); this run is {expected:?}"
        )));
    }
    varmap.load(dir.join(super::MODEL_FILE))?;
    let moments = candle_core::safetensors::load(dir.join(super::OPTIMIZER_FILE), device)?;
    opt.load_state_tensors(moments, state.step, device)
        .map_err(|e| bad(format!("optimizer: {e}")))?;
    Ok(state)
}

/// `FusionTrainer::new(opts)?.run()`.
pub fn run_fusion_training(opts: &FusionTrainOptions) -> Result<FusionSummary, TrainError> {
    FusionTrainer::new(opts)?.run()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ground_truth_blocks_keep_their_nearest_range() {
        let (fine, coarse) = (ErpGrid::new(8).unwrap(), ErpGrid::new(4).unwrap());
        let mut range = vec![10.0f32; fine.len()];
        // block (0, 0): one pixel at 2 m; block (0, 1): all sky; block (1, 3): no ground truth
        range[1] = 2.0;
        for k in [2, 3, 10, 11] {
            range[k] = f32::INFINITY;
        }
        for k in [2 * 8 + 6, 2 * 8 + 7, 3 * 8 + 6, 3 * 8 + 7] {
            range[k] = if k % 2 == 0 { f32::NAN } else { 0.0 };
        }
        let out = nearest_in_blocks(&range, fine, coarse);
        assert_eq!(out.len(), coarse.len());
        assert_eq!(out[0], 2.0);
        assert_eq!(out[1], f32::INFINITY);
        assert_eq!(out[4 + 3], 0.0);
        assert_eq!(out[2], 10.0);
    }
}
