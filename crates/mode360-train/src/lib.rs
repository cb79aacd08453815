//! mode360's SSMODE and PSMODE training: rendered or Deep360 samples, the loss, the optimizer,
//! checkpoints and logs.
//!
//! SSMODE training (`mode360 train`): on-the-fly synthetic data on randomized rigs, the
//! multi-stage inverse-depth loss, AdamW with warmup + cosine decay, exact checkpoint/resume,
//! held-out validation, CSV logs and a curve plot.
//!
//! * Data ([`data`]): sample `k` is a pure function of `(seed, k)`, rendered in a background
//!   thread. Step `s` uses samples `s B .. (s + 1) B` (`B = batch_size`). With
//!   `deep360_disk`, a fraction of them are Deep360 training frames read from disk. Random
//!   rigs are roof racks or, with `rig_layouts` `any`, of every layout family
//!   ([`rig_layouts`]); `blocked_fraction` of the samples have one lens partly blocked.
//! * Batching: random rigs differ per sample (camera count, sweep tables), so a batch is
//!   gradient accumulation over `B` single-sample forward/backward passes, each loss scaled by
//!   `1 / B`; memory stays that of one sample.
//! * Loss ([`loss`]): `sum_s w_s SmoothL1` on the inverse-depth index, masked to valid pixels.
//! * Checkpoint (`checkpoint.rs`): `out_dir/checkpoint/` holds `model.safetensors` (the
//!   model's `save_weights`, config in the header), `optimizer.safetensors` (AdamW moments)
//!   and `state.json` (step, next sample index = the data RNG position, options that must
//!   match on resume). It is written into `checkpoint.tmp/` and renamed into place, so a crash
//!   never leaves a torn checkpoint; written every `checkpoint_every_steps` steps, when
//!   `checkpoint_every_s` have passed since the last one, and at the end.
//! * Logs: `train.csv` every step, `val.csv` and `curves.png` every `val_every` steps (see
//!   [`log`]), peak RSS from `/proc/self/status` in both CSVs. Final weights are copied to
//!   `out_dir/ssmode_<preset>.safetensors`.
//!
//! The run itself is a [`Trainer`] (`trainer.rs`): [`Trainer::new`] sets it up (fresh, from
//! `init_weights`, or resumed), [`Trainer::step`], [`Trainer::validate`] and
//! [`Trainer::checkpoint`] are its parts, [`Trainer::run`] the loop; [`run_training`] is
//! `Trainer::new(opts)?.run()`. Beside it: `options.rs` (options, summary, errors), `init.rs`
//! (seeded initialisation, fine-tuning start weights) and `forward.rs` (one sample through the
//! network, the validation pass).
//!
//! PSMODE's fusion network (stage 2) trains apart from it, on stage 1's cached output:
//! [`fusion`] (`mode360 train --stage fusion`).

pub mod camera_effects;
pub mod data;
pub mod fisheye_rigs;
pub mod fusion;
pub mod log;
pub mod loss;
pub mod optim;
pub mod rack;
pub mod rig_layouts;
pub mod rig_pool;

mod checkpoint;
mod forward;
mod init;
mod options;
mod trainer;

pub use checkpoint::{
    CheckpointState, Deep360DiskState, CHECKPOINT_DIR, MODEL_FILE, OPTIMIZER_FILE, STATE_FILE,
};
pub use options::{StepReport, TrainError, TrainOptions, TrainSummary};
pub use trainer::{run_training, Trainer, CURVES_PNG, TRAIN_CSV, VAL_CSV};
