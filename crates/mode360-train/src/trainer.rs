//! The training loop as a [`Trainer`]: [`Trainer::new`] sets a run up (fresh, fine-tuned or
//! resumed), [`Trainer::step`] runs one optimizer step, [`Trainer::validate`] one pass over the
//! held-out set, [`Trainer::checkpoint`] writes the checkpoint, and [`Trainer::run`] loops
//! them to the last step (see the module docs of [`crate::train`]). [`run_training`] is
//! `Trainer::new(opts)?.run()`.

use super::checkpoint::{
    find_checkpoint, load_checkpoint, write_checkpoint, CheckpointState, Deep360DiskState, Restore,
    STATE_FILE, STATE_VERSION,
};
use super::data::{
    render_sample, validation_specs, DataConfig, Deep360Mix, SampleSpec, SampleStream, TrainSample,
};
use super::forward::{
    accumulate_grads, forward_sample, validation_pass, Pass, SamplingCache, MIN_SAMPLING_CACHE_RIGS,
};
use super::init::{load_init_weights, named_vars, seeded_var_builder};
use super::log::{TrainRecord, ValRecord};
use super::loss::{LossConfig, PSMNET_STAGE_WEIGHTS};
use super::optim::{AdamW, AdamWParams, LrSchedule};
use super::options::{io_err, resolve_config, StepReport, TrainError, TrainOptions, TrainSummary};
use candle_core::{DType, Device};
use candle_nn::VarMap;
use mode360_model::model::fine_head::FINE_HEAD_PREFIX;
use mode360_model::model::{save_weights, ModelError, Ssmode, SsmodeConfig};
use std::path::PathBuf;
use std::time::Instant;

/// Log files inside `out_dir`.
pub const TRAIN_CSV: &str = "train.csv";
pub const VAL_CSV: &str = "val.csv";
pub const CURVES_PNG: &str = "curves.png";
/// Samples the data thread may render ahead of training.
pub const PREFETCH_SAMPLES: usize = 2;
/// The cosine schedule decays to this fraction of the base learning rate.
pub const MIN_LR_FRACTION: f64 = 0.05;

/// A training run in progress: model, optimizer, data stream, logs and bookkeeping.
pub struct Trainer {
    opts: TrainOptions,
    cfg: SsmodeConfig,
    device: Device,
    varmap: VarMap,
    model: Ssmode,
    opt: AdamW,
    /// Steps completed, data position and the options a resume must match.
    state: CheckpointState,
    start_step: usize,
    data_cfg: DataConfig,
    loss_cfg: LossConfig,
    schedule: LrSchedule,
    cache: SamplingCache,
    /// Started when steps remain; `None` otherwise.
    stream: Option<SampleStream>,
    /// Rendered on the first validation.
    val_set: Option<Vec<TrainSample>>,
    last_validation: Option<ValRecord>,
    last_loss: f64,
    train_csv: PathBuf,
    val_csv: PathBuf,
    curves: PathBuf,
    bar: indicatif::ProgressBar,
    run_start: Instant,
    last_checkpoint: Instant,
}

impl Trainer {
    /// Sets a run up: checks the options, builds the seeded network (or resumes it from
    /// `out_dir/checkpoint` with `resume`, or starts it from `init_weights`), prepares the logs
    /// (a resumed run drops rows past its checkpoint, a new one starts them afresh) and starts
    /// the data stream at the run's sample index.
    pub fn new(opts: &TrainOptions) -> Result<Self, TrainError> {
        let opts = opts.clone();
        let cfg = resolve_config(&opts)?;
        // Listed once, before anything is written: the picks are indices into this list.
        let deep360_disk = opts
            .deep360_disk
            .as_ref()
            .map(|root| Deep360Mix::open(root, opts.deep360_disk_fraction))
            .transpose()?;
        let device = opts.device.open().map_err(ModelError::from)?;
        std::fs::create_dir_all(&opts.out_dir).map_err(io_err(&opts.out_dir))?;
        let mut varmap = VarMap::new();
        let model = Ssmode::new(&cfg, seeded_var_builder(&varmap, opts.stream.seed, &device))?;
        // with `fine_head_only`, the optimizer holds (and a checkpoint's moments name) the
        // head's variables alone
        let learned = named_vars(&varmap)?
            .into_iter()
            .filter(|(name, _)| !opts.fine_head_only || name.starts_with(FINE_HEAD_PREFIX))
            .collect();
        let mut opt = AdamW::new(
            learned,
            AdamWParams {
                weight_decay: opts.weight_decay,
                max_grad_norm: opts.max_grad_norm,
                ..AdamWParams::default()
            },
        )?;
        let head_vars = opt.scale_lr_of(FINE_HEAD_PREFIX, opts.fine_head_lr_scale);
        if opts.fine_head_only {
            tracing::info!(
                "only the fine head's {head_vars} variables learn; the rest of the network stays at its start weights"
            );
        } else if head_vars > 0 && opts.fine_head_lr_scale != 1.0 {
            tracing::info!(
                "the fine head's {head_vars} variables learn at {} times the rate",
                opts.fine_head_lr_scale
            );
        }
        let state = CheckpointState {
            version: STATE_VERSION,
            step: 0,
            next_sample_index: 0,
            preset: opts.preset.to_string(),
            width: cfg.width,
            seed: opts.stream.seed,
            batch_size: opts.batch_size,
            train_s: 0.0,
            deep360_disk: deep360_disk.as_ref().map(Deep360DiskState::of),
            mix: opts.stream.mix,
            loss_weighting: Some(opts.loss_weighting),
            fine_head_only: opts.fine_head_only,
        };
        let state = restore(&opts, &cfg, &mut varmap, &mut opt, state, &device)?;
        let (train_csv, val_csv, curves) = prepare_logs(&opts, state.step)?;
        let data_cfg = DataConfig {
            stream: opts.stream,
            width: cfg.width,
            max_depth_m: cfg.max_depth_m,
            deep360_disk,
        };
        let loss_cfg = LossConfig {
            min_depth_m: cfg.min_depth_m,
            max_depth_m: cfg.max_depth_m,
            hypotheses: cfg.hypotheses,
            spacing: cfg.hypothesis_spacing,
            stage_weights: PSMNET_STAGE_WEIGHTS.to_vec(),
            weighting: opts.loss_weighting,
        };
        let schedule = LrSchedule {
            base_lr: opts.lr,
            warmup_steps: opts.warmup_steps,
            total_steps: opts.steps,
            min_lr_fraction: MIN_LR_FRACTION,
        };
        let start_step = state.step;
        let bar = progress_bar(&opts, start_step);
        let run_start = Instant::now();
        let last_checkpoint = Instant::now();
        let stream = if start_step < opts.last_step() {
            Some(SampleStream::start(
                data_cfg.clone(),
                state.next_sample_index,
                PREFETCH_SAMPLES,
            )?)
        } else {
            None
        };
        // The pool's rigs, the Deep360 rig and the current sample's.
        let cache =
            SamplingCache::with_capacity(opts.stream.mix.rig_pool + MIN_SAMPLING_CACHE_RIGS);
        Ok(Self {
            opts,
            cfg,
            device,
            varmap,
            model,
            opt,
            state,
            start_step,
            data_cfg,
            loss_cfg,
            schedule,
            cache,
            stream,
            val_set: None,
            last_validation: None,
            last_loss: f64::NAN,
            train_csv,
            val_csv,
            curves,
            bar,
            run_start,
            last_checkpoint,
        })
    }

    /// Bookkeeping of the run so far (what the next checkpoint saves).
    pub fn state(&self) -> &CheckpointState {
        &self.state
    }

    /// Step the run started from (non-zero after resume).
    pub fn start_step(&self) -> usize {
        self.start_step
    }

    /// Whether all `opts.steps` steps are done, or the run reached `opts.until_step`.
    pub fn is_finished(&self) -> bool {
        self.state.step >= self.opts.last_step()
    }

    /// One optimizer step: `batch_size` forward/backward passes on the next samples of the
    /// stream, gradients accumulated (each loss scaled by `1 / batch_size`), one AdamW update
    /// (clipping the global norm to `max_grad_norm` if set) at the schedule's learning rate,
    /// then a `train.csv` row and the progress bar.
    pub fn step(&mut self) -> Result<StepReport, TrainError> {
        if self.is_finished() {
            return Err(TrainError::Other(format!(
                "all {} steps are done",
                self.opts.steps
            )));
        }
        let step = self.state.step;
        let step_start = Instant::now();
        let lr = self.schedule.lr(step);
        let mut grads = None;
        let mut step_loss = 0.0;
        for _ in 0..self.opts.batch_size {
            let next = self
                .stream
                .as_mut()
                .ok_or_else(|| TrainError::Other("data stream not started".into()))?
                .next_sample()?;
            if next.index != self.state.next_sample_index {
                return Err(TrainError::Other(format!(
                    "data stream out of order: got sample {}, expected {}",
                    next.index, self.state.next_sample_index
                )));
            }
            let sample = next.sample?;
            let sampling = self.cache.get(&sample.rig, &self.cfg)?;
            let r = forward_sample(
                &self.model,
                sampling,
                &sample,
                &self.loss_cfg,
                &self.device,
                if self.opts.fine_head_only {
                    Pass::TrainFineHead
                } else {
                    Pass::Train
                },
            )?;
            let scaled = (r.loss / self.opts.batch_size as f64)?;
            step_loss += f64::from(scaled.to_dtype(DType::F32)?.to_scalar::<f32>()?);
            let g = scaled.backward()?;
            grads = Some(accumulate_grads(grads, g, &self.varmap)?);
            self.state.next_sample_index += 1;
        }
        let grad_norm = match &grads {
            Some(g) => self.opt.step(g, lr)?,
            None => f64::NAN,
        };
        self.state.step = step + 1;
        let step_s = step_start.elapsed().as_secs_f64();
        self.state.train_s += step_s;
        self.last_loss = step_loss;
        super::log::append_train(
            &self.train_csv,
            &TrainRecord {
                step: self.state.step,
                loss: step_loss,
                lr,
                step_s,
                peak_rss_mib: super::log::peak_rss_mib(),
            },
        )
        .map_err(io_err(&self.train_csv))?;
        self.bar.set_message(format!(
            "loss {step_loss:.4} |g| {grad_norm:.3} lr {lr:.2e} {step_s:.2} s/step"
        ));
        self.bar.set_position(self.state.step as u64);
        Ok(StepReport {
            step: self.state.step,
            loss: step_loss,
            lr,
            grad_norm,
            step_s,
        })
    }

    /// Mean loss and frame-averaged metrics of the current weights over the `val_samples`
    /// held-out frames (rendered on the first call), appended to `val.csv`; `curves.png` is
    /// redrawn.
    pub fn validate(&mut self) -> Result<ValRecord, TrainError> {
        if self.opts.val_samples == 0 {
            return Err(TrainError::Option {
                option: "val_samples",
                problem: "no validation frames to validate on".into(),
            });
        }
        if self.val_set.is_none() {
            // PSMODE stage 1 validates on one pair of each held-out frame, pairs in turn
            let pairs = self.opts.stream.mix.camera_pairs;
            let set = validation_specs(self.opts.val_samples)
                .into_iter()
                .enumerate()
                .map(|(k, spec)| SampleSpec {
                    pair_pick: pairs.then_some(k as u64),
                    ..spec
                })
                .map(|spec| render_sample(&self.data_cfg, &spec))
                .collect::<Result<Vec<_>, _>>()?;
            self.val_set = Some(set);
        }
        let set = self.val_set.as_deref().unwrap_or_default();
        let rec = validation_pass(
            &self.model,
            &self.cfg,
            set,
            &mut self.cache,
            &self.loss_cfg,
            &self.device,
            self.state.step,
        )?;
        super::log::append_val(&self.val_csv, &rec).map_err(io_err(&self.val_csv))?;
        super::log::plot_curves(&self.train_csv, &self.val_csv, &self.curves)
            .map_err(TrainError::Other)?;
        mode360_core::progress::println(
            &self.bar,
            format!(
                "step {}: val loss {:.4} delta1 {:.1}% abs_rel {:.3}",
                rec.step, rec.loss, rec.metrics.delta1_pct, rec.metrics.abs_rel
            ),
        );
        self.last_validation = Some(rec.clone());
        Ok(rec)
    }

    /// Writes `out_dir/checkpoint/` (weights, optimizer moments, [`CheckpointState`])
    /// atomically.
    pub fn checkpoint(&self) -> Result<(), TrainError> {
        write_checkpoint(
            &self.opts.out_dir,
            &self.varmap,
            &self.cfg,
            &self.opt,
            &self.state,
        )
    }

    /// Whether the step just completed is a validation step.
    fn validation_due(&self) -> bool {
        self.opts.val_every > 0
            && self.opts.val_samples > 0
            && self.state.step.is_multiple_of(self.opts.val_every)
    }

    /// Whether to checkpoint after the step just completed: every `checkpoint_every_steps`
    /// steps, when `checkpoint_every_s` have passed since the last one, and at the end.
    fn checkpoint_due(&self) -> bool {
        let by_steps = self.opts.checkpoint_every_steps > 0
            && self
                .state
                .step
                .is_multiple_of(self.opts.checkpoint_every_steps);
        let by_time = self.last_checkpoint.elapsed().as_secs_f64() >= self.opts.checkpoint_every_s;
        by_steps || by_time || self.state.step == self.opts.steps
    }

    /// Runs the remaining steps, validating every `val_every` steps and checkpointing when
    /// due, then plots the curves and writes the final weights to
    /// `out_dir/ssmode_<preset>.safetensors`.
    pub fn run(mut self) -> Result<TrainSummary, TrainError> {
        while !self.is_finished() {
            self.step()?;
            if self.validation_due() {
                self.validate()?;
            }
            if self.checkpoint_due() {
                self.checkpoint()?;
                self.last_checkpoint = Instant::now();
            }
        }
        self.finish()
    }

    /// Stops the data stream, plots the curves and saves the final weights.
    fn finish(mut self) -> Result<TrainSummary, TrainError> {
        drop(self.stream.take());
        self.bar.finish_and_clear();
        if self.train_csv.exists() {
            super::log::plot_curves(&self.train_csv, &self.val_csv, &self.curves)
                .map_err(TrainError::Other)?;
        }
        let weights_path = self
            .opts
            .out_dir
            .join(format!("ssmode_{}.safetensors", self.opts.preset));
        save_weights(&self.varmap, &self.cfg, &weights_path)?;
        let steps_run = self.state.step - self.start_step;
        Ok(TrainSummary {
            start_step: self.start_step,
            final_step: self.state.step,
            last_loss: self.last_loss,
            mean_s_per_step: if steps_run > 0 {
                self.run_start.elapsed().as_secs_f64() / steps_run as f64
            } else {
                0.0
            },
            peak_rss_mib: super::log::peak_rss_mib(),
            last_validation: self.last_validation,
            weights_path,
        })
    }
}

/// The run's starting point: its own checkpoint when resuming (and one is there), else the
/// `init_weights` file or a forked run's checkpoint, else the fresh `state`.
fn restore(
    opts: &TrainOptions,
    cfg: &SsmodeConfig,
    varmap: &mut VarMap,
    opt: &mut AdamW,
    state: CheckpointState,
    device: &Device,
) -> Result<CheckpointState, TrainError> {
    if opts.resume {
        if let Some(dir) = find_checkpoint(&opts.out_dir) {
            return load_checkpoint(&dir, varmap, opt, &state, Restore::Resume, device);
        }
    }
    match (&opts.init_weights, &opts.fork_from) {
        (None, None) => Ok(state),
        (Some(init), None) => {
            load_init_weights(init, cfg, varmap)?;
            Ok(state)
        }
        (None, Some(run)) => {
            let dir = find_checkpoint(run)
                .or_else(|| run.join(STATE_FILE).is_file().then(|| run.clone()))
                .ok_or_else(|| TrainError::Option {
                    option: "fork_from",
                    problem: format!("no checkpoint in {}", run.display()),
                })?;
            load_checkpoint(&dir, varmap, opt, &state, Restore::Fork, device)
        }
        (Some(_), Some(_)) => Err(TrainError::Option {
            option: "fork_from",
            problem: "a run starts from init_weights or forks a checkpoint, not both".into(),
        }),
    }
}

/// The run's CSV logs (cut back to `step` when resuming, removed when starting afresh) and
/// where its curves go.
fn prepare_logs(
    opts: &TrainOptions,
    step: usize,
) -> Result<(PathBuf, PathBuf, PathBuf), TrainError> {
    let train_csv = opts.out_dir.join(TRAIN_CSV);
    let val_csv = opts.out_dir.join(VAL_CSV);
    let curves = opts.out_dir.join(CURVES_PNG);
    if opts.resume {
        super::log::truncate_after_step(&train_csv, super::log::TRAIN_CSV_HEADER, step)
            .map_err(io_err(&train_csv))?;
        super::log::truncate_after_step(&val_csv, super::log::VAL_CSV_HEADER, step)
            .map_err(io_err(&val_csv))?;
    } else {
        for p in [&train_csv, &val_csv] {
            if p.exists() {
                std::fs::remove_file(p).map_err(io_err(p))?;
            }
        }
    }
    Ok((train_csv, val_csv, curves))
}

/// The training progress bar (hidden without `show_progress`), at `start_step`.
fn progress_bar(opts: &TrainOptions, start_step: usize) -> indicatif::ProgressBar {
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
    bar
}

/// Runs (or resumes) a training run; see the module docs.
pub fn run_training(opts: &TrainOptions) -> Result<TrainSummary, TrainError> {
    Trainer::new(opts)?.run()
}
