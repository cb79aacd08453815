//! The training loop behind [`run_training`] (see the module docs of [`crate::train`]).

use super::data::{
    render_sample, validation_specs, DataConfig, DataError, Deep360Mix, SampleStream, TrainSample,
};
use super::log::{TrainRecord, ValRecord};
use super::loss::{LossConfig, LossError, PSMNET_STAGE_WEIGHTS};
use super::optim::{AdamW, AdamWParams, LrSchedule};
use crate::metrics::{depth_metrics, FrameAverage};
use crate::model::{save_weights, ModelError, Preset, Ssmode, SsmodeConfig, SweepSampling};
use crate::synth::StreetStyle;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Checkpoint directory name inside `out_dir`.
pub const CHECKPOINT_DIR: &str = "checkpoint";
/// Files inside a checkpoint directory.
pub const MODEL_FILE: &str = "model.safetensors";
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
pub const STATE_FILE: &str = "state.json";
/// Log files inside `out_dir`.
pub const TRAIN_CSV: &str = "train.csv";
pub const VAL_CSV: &str = "val.csv";
pub const CURVES_PNG: &str = "curves.png";
/// Samples the data thread may render ahead of training.
pub const PREFETCH_SAMPLES: usize = 2;
/// The cosine schedule decays to this fraction of the base learning rate.
pub const MIN_LR_FRACTION: f64 = 0.05;
/// Version of the `state.json` layout.
const STATE_VERSION: u32 = 1;
/// Suffixes of the temporary and previous checkpoint directories.
const TMP_SUFFIX: &str = "tmp";
const OLD_SUFFIX: &str = "old";

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

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
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
    pub checkpoint_every_secs: f64,
    /// Data stream seed.
    pub seed: u64,
    pub soiled_fraction: f64,
    pub deep360_fraction: f64,
    /// Root of the paper's Deep360 dataset: its training frames are mixed into the stream.
    pub deep360_disk: Option<PathBuf>,
    /// Fraction of training samples read from `deep360_disk` (when set).
    pub deep360_disk_fraction: f64,
    /// Fraction of rendered samples that are random-objects scenes (1 to pretrain matching).
    pub objects_fraction: f64,
    /// Layout variation of the training streets.
    pub street: StreetStyle,
    /// Clip the global gradient norm to this (`None`: no clipping).
    pub max_grad_norm: Option<f64>,
    /// Start a new run (not a resumed one) from these weights instead of the random
    /// initialisation: fine-tuning. The file's network must have the preset's layer sizes.
    pub init_weights: Option<PathBuf>,
    pub show_progress: bool,
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
            checkpoint_every_secs: 300.0,
            seed: 1,
            soiled_fraction: 0.3,
            deep360_fraction: 0.25,
            deep360_disk: None,
            deep360_disk_fraction: 1.0,
            objects_fraction: 0.0,
            street: StreetStyle::Regular,
            max_grad_norm: None,
            init_weights: None,
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
    pub mean_secs_per_step: f64,
    /// Peak resident memory, MiB.
    pub peak_rss_mb: f64,
    pub last_validation: Option<ValRecord>,
    /// Final weights (`out_dir/ssmode_<preset>.safetensors`).
    pub weights_path: PathBuf,
}

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
    pub train_secs: f64,
    /// The Deep360-on-disk part of the stream (absent in older checkpoints: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deep360_disk: Option<Deep360DiskState>,
    /// Random-objects share of the stream (older checkpoints: none).
    #[serde(default)]
    pub objects_fraction: f64,
    /// Street style of the stream (older checkpoints: regular).
    #[serde(default)]
    pub street: StreetStyle,
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
    fn of(mix: &Deep360Mix) -> Self {
        Self {
            root: mix.root.display().to_string(),
            fraction: mix.fraction,
            frames: mix.frames.len(),
        }
    }
}

/// Layer sizes of `cfg` (what weights depend on; not the width, name or readout).
fn architecture(cfg: &SsmodeConfig) -> String {
    format!(
        "features {:?} x {:?} -> {}, fine branch {} at 1/{}, {:?} cost over {} spheres, \
         entry stride {}, {} hourglasses of {} channels",
        cfg.feature_channels,
        cfg.feature_blocks,
        cfg.feature_out_channels,
        cfg.fine_channels,
        cfg.cost_downsample,
        cfg.cost,
        cfg.spheres,
        cfg.aggregation_stride,
        cfg.hourglasses,
        cfg.hourglass_channels
    )
}

/// Loads fine-tuning start weights into `varmap` after checking their architecture.
fn load_init_weights(
    path: &Path,
    cfg: &SsmodeConfig,
    varmap: &mut VarMap,
) -> Result<(), TrainError> {
    let file_cfg = crate::model::read_config(path)?;
    if architecture(&file_cfg) != architecture(cfg) {
        return Err(TrainError::Option {
            option: "init_weights",
            problem: format!(
                "{} holds a '{}' network ({}), the run trains '{}' ({})",
                path.display(),
                file_cfg.name,
                architecture(&file_cfg),
                cfg.name,
                architecture(cfg)
            ),
        });
    }
    varmap.load(path).map_err(|e| {
        TrainError::Model(ModelError::Weights {
            path: path.display().to_string(),
            problem: format!("loading the start weights: {e}"),
        })
    })
}

fn resolve_config(opts: &TrainOptions) -> Result<SsmodeConfig, TrainError> {
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

/// Sorted named variables of a var map.
fn named_vars(varmap: &VarMap) -> Result<Vec<(String, Var)>, TrainError> {
    let data = varmap
        .data()
        .lock()
        .map_err(|_| TrainError::Other("variable map lock poisoned".into()))?;
    let mut v: Vec<(String, Var)> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(v)
}

/// Domain-separation word of the weight-initialization stream.
const INIT_TAG: u64 = 0x1417;

/// A [`VarMap`] backend whose random initializations are a function of a seed (candle's CPU
/// RNG cannot be seeded, and resume exactness is checked against a fresh run). Variable
/// `name` draws from `Rng::new(&[seed, hash(name), INIT_TAG])`: uniform inits directly,
/// normal ones by Box-Muller `mean + stdev sqrt(-2 ln u1) cos(2 pi u2)`, Kaiming with
/// `std = gain / sqrt(fan)` as candle does.
struct SeededVarMap {
    varmap: VarMap,
    seed: u64,
}

impl SeededVarMap {
    fn draw(&self, shape: &candle_core::Shape, name: &str, init: candle_nn::Init) -> Vec<f32> {
        use crate::synth::noise::{hash_words, Rng};
        use candle_nn::init::NormalOrUniform;
        let n = shape.elem_count();
        let name_hash = hash_words(&name.bytes().map(u64::from).collect::<Vec<_>>());
        let mut rng = Rng::new(&[self.seed, name_hash, INIT_TAG]);
        let mut normal = |mean: f64, stdev: f64| -> Vec<f32> {
            (0..n)
                .map(|_| {
                    let u1 = rng.unit().max(f64::MIN_POSITIVE);
                    let u2 = rng.unit();
                    let z = (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos();
                    (mean + stdev * z) as f32
                })
                .collect()
        };
        match init {
            candle_nn::Init::Const(c) => vec![c as f32; n],
            candle_nn::Init::Randn { mean, stdev } => normal(mean, stdev),
            candle_nn::Init::Uniform { lo, up } => {
                let mut rng = Rng::new(&[self.seed, name_hash, INIT_TAG]);
                (0..n).map(|_| rng.range(lo, up) as f32).collect()
            }
            candle_nn::Init::Kaiming {
                dist,
                fan,
                non_linearity,
            } => {
                let std = non_linearity.gain() / (fan.for_shape(shape).max(1) as f64).sqrt();
                match dist {
                    NormalOrUniform::Uniform => {
                        let bound = 3f64.sqrt() * std;
                        let mut rng = Rng::new(&[self.seed, name_hash, INIT_TAG]);
                        (0..n).map(|_| rng.range(-bound, bound) as f32).collect()
                    }
                    NormalOrUniform::Normal => normal(0.0, std),
                }
            }
        }
    }
}

impl candle_nn::var_builder::SimpleBackend for SeededVarMap {
    fn get(
        &self,
        s: candle_core::Shape,
        name: &str,
        h: candle_nn::Init,
        dtype: DType,
        dev: &Device,
    ) -> candle_core::Result<Tensor> {
        let mut data = self
            .varmap
            .data()
            .lock()
            .map_err(|_| candle_core::Error::Msg("variable map lock poisoned".into()))?;
        if let Some(v) = data.get(name) {
            if v.shape() != &s {
                candle_core::bail!("shape mismatch on {name}: {s:?} <> {:?}", v.shape());
            }
            return Ok(v.as_tensor().clone());
        }
        let values = self.draw(&s, name, h);
        let t = Tensor::from_vec(values, s, dev)?.to_dtype(dtype)?;
        let var = Var::from_tensor(&t)?;
        let out = var.as_tensor().clone();
        data.insert(name.to_string(), var);
        Ok(out)
    }

    fn get_unchecked(
        &self,
        name: &str,
        _dtype: DType,
        _dev: &Device,
    ) -> candle_core::Result<Tensor> {
        candle_core::bail!("variable '{name}' must be created with a shape")
    }

    fn contains_tensor(&self, name: &str) -> bool {
        self.varmap
            .data()
            .lock()
            .map(|d| d.contains_key(name))
            .unwrap_or(false)
    }
}

/// Writes a checkpoint atomically (temp directory, then rename).
fn write_checkpoint(
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
fn find_checkpoint(out_dir: &Path) -> Option<PathBuf> {
    [
        out_dir.join(CHECKPOINT_DIR),
        out_dir.join(format!("{CHECKPOINT_DIR}.{OLD_SUFFIX}")),
    ]
    .into_iter()
    .find(|d| d.join(STATE_FILE).is_file())
}

/// Restores weights, optimizer moments and bookkeeping from `dir`, checking that the run's
/// options match.
fn load_checkpoint(
    dir: &Path,
    varmap: &mut VarMap,
    opt: &mut AdamW,
    expected: &CheckpointState,
    device: &Device,
) -> Result<CheckpointState, TrainError> {
    let state_path = dir.join(STATE_FILE);
    let text = std::fs::read_to_string(&state_path).map_err(io_err(&state_path))?;
    let state: CheckpointState =
        serde_json::from_str(&text).map_err(|e| TrainError::Checkpoint {
            path: state_path.display().to_string(),
            problem: format!("malformed: {e}"),
        })?;
    let mismatch = |field: &str, saved: String, now: String| TrainError::Checkpoint {
        path: state_path.display().to_string(),
        problem: format!("'{field}' was {saved} but this run uses {now}; use a new out_dir"),
    };
    if state.version != STATE_VERSION {
        return Err(mismatch(
            "version",
            state.version.to_string(),
            STATE_VERSION.to_string(),
        ));
    }
    if state.preset != expected.preset {
        return Err(mismatch(
            "preset",
            state.preset.clone(),
            expected.preset.clone(),
        ));
    }
    if state.width != expected.width {
        return Err(mismatch(
            "width",
            state.width.to_string(),
            expected.width.to_string(),
        ));
    }
    if state.seed != expected.seed {
        return Err(mismatch(
            "seed",
            state.seed.to_string(),
            expected.seed.to_string(),
        ));
    }
    if state.batch_size != expected.batch_size {
        return Err(mismatch(
            "batch_size",
            state.batch_size.to_string(),
            expected.batch_size.to_string(),
        ));
    }
    if state.objects_fraction != expected.objects_fraction {
        return Err(mismatch(
            "objects_fraction",
            state.objects_fraction.to_string(),
            expected.objects_fraction.to_string(),
        ));
    }
    if state.street != expected.street {
        return Err(mismatch(
            "street",
            state.street.as_str().to_string(),
            expected.street.as_str().to_string(),
        ));
    }
    if state.deep360_disk != expected.deep360_disk {
        return Err(mismatch(
            "deep360_disk",
            format!("{:?}", state.deep360_disk),
            format!("{:?}", expected.deep360_disk),
        ));
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
    Ok(state)
}

/// Sweep tables per rig; the Deep360 rig (validation and part of training) is cached.
struct SamplingCache {
    cached: Vec<(crate::geometry::Rig, SweepSampling)>,
}

/// Rigs kept in the sampling cache.
const SAMPLING_CACHE_RIGS: usize = 2;

impl SamplingCache {
    fn get(
        &mut self,
        rig: &crate::geometry::Rig,
        cfg: &SsmodeConfig,
    ) -> Result<&SweepSampling, TrainError> {
        if let Some(pos) = self.cached.iter().position(|(r, _)| r == rig) {
            return Ok(&self.cached[pos].1);
        }
        let s = SweepSampling::new(rig, cfg)?;
        if self.cached.len() >= SAMPLING_CACHE_RIGS {
            self.cached.remove(0);
        }
        self.cached.push((rig.clone(), s));
        let last = self.cached.len() - 1;
        Ok(&self.cached[last].1)
    }
}

/// Forward pass and loss of one sample.
struct SampleResult {
    loss: Tensor,
    range_m: Tensor,
}

fn forward_sample(
    model: &Ssmode,
    sampling: &SweepSampling,
    sample: &TrainSample,
    loss_cfg: &LossConfig,
    device: &Device,
    train: bool,
) -> Result<SampleResult, TrainError> {
    let images = sample
        .images
        .iter()
        .map(|t| t.to_device(device))
        .collect::<Result<Vec<_>, _>>()?;
    let out = model.forward(&images, sampling, train)?;
    let target = loss_cfg.target(&[&sample.range_m], device)?;
    let loss = loss_cfg.loss(&out.inverse_depth_stages, &target)?;
    let range_m = out
        .stages
        .last()
        .cloned()
        .ok_or_else(|| TrainError::Other("network returned no stages".into()))?;
    Ok(SampleResult { loss, range_m })
}

/// Mean loss and frame-averaged metrics over the validation set.
fn validate(
    model: &Ssmode,
    cfg: &SsmodeConfig,
    samples: &[TrainSample],
    cache: &mut SamplingCache,
    loss_cfg: &LossConfig,
    device: &Device,
    step: usize,
) -> Result<ValRecord, TrainError> {
    let mut avg = FrameAverage::default();
    let mut loss_sum = 0.0;
    for s in samples {
        let sampling = cache.get(&s.rig, cfg)?;
        let r = forward_sample(model, sampling, s, loss_cfg, device, false)?;
        loss_sum += f64::from(r.loss.to_dtype(DType::F32)?.to_scalar::<f32>()?);
        let pred: Vec<f32> = r.range_m.flatten_all()?.to_vec1()?;
        let m = depth_metrics(&pred, &s.range_m.data, cfg.max_depth_m)
            .map_err(|e| TrainError::Other(format!("validation metrics: {e}")))?;
        avg.push(m, None);
    }
    Ok(ValRecord {
        step,
        loss: loss_sum / samples.len().max(1) as f64,
        metrics: avg.depth(),
        peak_rss_mb: super::log::peak_rss_mb(),
    })
}

/// Runs (or resumes) a training run; see the module docs.
pub fn run_training(opts: &TrainOptions) -> Result<TrainSummary, TrainError> {
    let cfg = resolve_config(opts)?;
    // Listed once, before anything is written: the picks are indices into this list.
    let deep360_disk = opts
        .deep360_disk
        .as_ref()
        .map(|root| Deep360Mix::open(root, opts.deep360_disk_fraction))
        .transpose()?;
    let device = Device::Cpu;
    std::fs::create_dir_all(&opts.out_dir).map_err(io_err(&opts.out_dir))?;
    let mut varmap = VarMap::new();
    let vb = VarBuilder::from_backend(
        Box::new(SeededVarMap {
            varmap: varmap.clone(),
            seed: opts.seed,
        }),
        DType::F32,
        device.clone(),
    );
    let model = Ssmode::new(&cfg, vb)?;
    let mut opt = AdamW::new(
        named_vars(&varmap)?,
        AdamWParams {
            weight_decay: opts.weight_decay,
            max_grad_norm: opts.max_grad_norm,
            ..AdamWParams::default()
        },
    )?;
    let mut state = CheckpointState {
        version: STATE_VERSION,
        step: 0,
        next_sample_index: 0,
        preset: opts.preset.to_string(),
        width: cfg.width,
        seed: opts.seed,
        batch_size: opts.batch_size,
        train_secs: 0.0,
        deep360_disk: deep360_disk.as_ref().map(Deep360DiskState::of),
        objects_fraction: opts.objects_fraction,
        street: opts.street,
    };
    let mut resumed = false;
    if opts.resume {
        if let Some(dir) = find_checkpoint(&opts.out_dir) {
            state = load_checkpoint(&dir, &mut varmap, &mut opt, &state, &device)?;
            resumed = true;
        }
    }
    if let (false, Some(init)) = (resumed, &opts.init_weights) {
        load_init_weights(init, &cfg, &mut varmap)?;
    }
    let train_csv = opts.out_dir.join(TRAIN_CSV);
    let val_csv = opts.out_dir.join(VAL_CSV);
    let curves = opts.out_dir.join(CURVES_PNG);
    if opts.resume {
        super::log::truncate_after_step(&train_csv, state.step).map_err(io_err(&train_csv))?;
        super::log::truncate_after_step(&val_csv, state.step).map_err(io_err(&val_csv))?;
    } else {
        for p in [&train_csv, &val_csv] {
            if p.exists() {
                std::fs::remove_file(p).map_err(io_err(p))?;
            }
        }
    }
    let data_cfg = DataConfig {
        seed: opts.seed,
        width: cfg.width,
        max_depth_m: cfg.max_depth_m,
        soiled_fraction: opts.soiled_fraction,
        deep360_fraction: opts.deep360_fraction,
        deep360_disk,
        objects_fraction: opts.objects_fraction,
        street: opts.street,
    };
    let loss_cfg = LossConfig {
        min_depth_m: cfg.min_depth_m,
        max_depth_m: cfg.max_depth_m,
        hypotheses: cfg.hypotheses,
        stage_weights: PSMNET_STAGE_WEIGHTS.to_vec(),
    };
    let schedule = LrSchedule {
        base_lr: opts.lr,
        warmup_steps: opts.warmup_steps,
        total_steps: opts.steps,
        min_lr_fraction: MIN_LR_FRACTION,
    };
    let start_step = state.step;
    let mut cache = SamplingCache { cached: Vec::new() };
    let mut val_set: Option<Vec<TrainSample>> = None;
    let mut last_validation = None;
    let mut last_loss = f64::NAN;
    let bar = if opts.show_progress {
        indicatif::ProgressBar::new(opts.steps as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{elapsed_precise} [{bar:30}] {pos}/{len} {msg} ETA {eta_precise}",
    ) {
        bar.set_style(style);
    }
    bar.set_position(start_step as u64);
    let run_start = Instant::now();
    let mut last_checkpoint = Instant::now();
    let mut stream = if start_step < opts.steps {
        Some(SampleStream::start(
            data_cfg.clone(),
            state.next_sample_index,
            PREFETCH_SAMPLES,
        )?)
    } else {
        None
    };
    for step in start_step..opts.steps {
        let step_start = Instant::now();
        let lr = schedule.lr(step);
        let mut grads: Option<candle_core::backprop::GradStore> = None;
        let mut step_loss = 0.0;
        for _ in 0..opts.batch_size {
            let next = stream
                .as_mut()
                .ok_or_else(|| TrainError::Other("data stream not started".into()))?
                .next_sample()?;
            if next.index != state.next_sample_index {
                return Err(TrainError::Other(format!(
                    "data stream out of order: got sample {}, expected {}",
                    next.index, state.next_sample_index
                )));
            }
            let sample = next.sample?;
            let sampling = cache.get(&sample.rig, &cfg)?;
            let r = forward_sample(&model, sampling, &sample, &loss_cfg, &device, true)?;
            let scaled = (r.loss / opts.batch_size as f64)?;
            step_loss += f64::from(scaled.to_dtype(DType::F32)?.to_scalar::<f32>()?);
            let g = scaled.backward()?;
            grads = Some(match grads {
                None => g,
                Some(mut acc) => {
                    for (_, var) in named_vars(&varmap)? {
                        if let Some(new) = g.get(var.as_tensor()) {
                            let sum = match acc.get(var.as_tensor()) {
                                Some(old) => (old + new)?,
                                None => new.clone(),
                            };
                            acc.insert(var.as_tensor(), sum);
                        }
                    }
                    acc
                }
            });
            state.next_sample_index += 1;
        }
        let grad_norm = match &grads {
            Some(g) => opt.step(g, lr)?,
            None => f64::NAN,
        };
        state.step = step + 1;
        let step_secs = step_start.elapsed().as_secs_f64();
        state.train_secs += step_secs;
        last_loss = step_loss;
        super::log::append_train(
            &train_csv,
            &TrainRecord {
                step: state.step,
                loss: step_loss,
                lr,
                secs: step_secs,
                peak_rss_mb: super::log::peak_rss_mb(),
            },
        )
        .map_err(io_err(&train_csv))?;
        bar.set_message(format!(
            "loss {step_loss:.4} |g| {grad_norm:.3} lr {lr:.2e} {step_secs:.2}s/step"
        ));
        bar.set_position(state.step as u64);
        if opts.val_every > 0 && opts.val_samples > 0 && state.step.is_multiple_of(opts.val_every) {
            if val_set.is_none() {
                let set = validation_specs(opts.val_samples)
                    .iter()
                    .map(|spec| render_sample(&data_cfg, spec))
                    .collect::<Result<Vec<_>, _>>()?;
                val_set = Some(set);
            }
            if let Some(set) = &val_set {
                let rec = validate(
                    &model, &cfg, set, &mut cache, &loss_cfg, &device, state.step,
                )?;
                super::log::append_val(&val_csv, &rec).map_err(io_err(&val_csv))?;
                super::log::plot_curves(&train_csv, &val_csv, &curves)
                    .map_err(TrainError::Other)?;
                bar.println(format!(
                    "step {}: val loss {:.4} delta1 {:.1}% abs_rel {:.3}",
                    rec.step, rec.loss, rec.metrics.delta1_pct, rec.metrics.abs_rel
                ));
                last_validation = Some(rec);
            }
        }
        let by_steps = opts.checkpoint_every_steps > 0
            && state.step.is_multiple_of(opts.checkpoint_every_steps);
        let by_time = last_checkpoint.elapsed().as_secs_f64() >= opts.checkpoint_every_secs;
        if by_steps || by_time || state.step == opts.steps {
            write_checkpoint(&opts.out_dir, &varmap, &cfg, &opt, &state)?;
            last_checkpoint = Instant::now();
        }
    }
    drop(stream);
    bar.finish_and_clear();
    if train_csv.exists() {
        super::log::plot_curves(&train_csv, &val_csv, &curves).map_err(TrainError::Other)?;
    }
    let weights_path = opts
        .out_dir
        .join(format!("ssmode_{}.safetensors", opts.preset));
    save_weights(&varmap, &cfg, &weights_path)?;
    let steps_run = state.step - start_step;
    Ok(TrainSummary {
        start_step,
        final_step: state.step,
        last_loss,
        mean_secs_per_step: if steps_run > 0 {
            run_start.elapsed().as_secs_f64() / steps_run as f64
        } else {
            0.0
        },
        peak_rss_mb: super::log::peak_rss_mb(),
        last_validation,
        weights_path,
    })
}
