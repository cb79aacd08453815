//! End-to-end training on the tiny preset (64x32): resume exactness, CSV logs and the plot.

use mode360_train::{run_training, TrainOptions, CHECKPOINT_DIR, CURVES_PNG, TRAIN_CSV, VAL_CSV};
use std::collections::HashMap;
use std::path::Path;

fn opts(out: &Path, steps: usize) -> TrainOptions {
    TrainOptions {
        preset: mode360_model::model::Preset::Tiny,
        width: None,
        steps,
        out_dir: out.to_path_buf(),
        resume: false,
        batch_size: 1,
        lr: 2e-3,
        warmup_steps: 1,
        weight_decay: 1e-4,
        val_every: 2,
        val_samples: 2,
        checkpoint_every_steps: 1,
        checkpoint_every_s: 1e9,
        stream: mode360_train::data::StreamOptions {
            seed: 5,
            soiled_fraction: 0.5,
            deep360_fraction: 0.3,
            camera_effects: false,
            mix: mode360_train::data::SceneMix {
                objects_fraction: 0.5,
                street: mode360_synth::StreetStyle::Varied,
                fisheye_fraction: 0.25,
                ..Default::default()
            },
        },
        deep360_disk: None,
        deep360_disk_fraction: 1.0,
        init_weights: None,
        fork_from: None,
        until_step: None,
        max_grad_norm: Some(5.0),
        fine_head_lr_scale: 1.0,
        fine_head_only: false,
        loss_weighting: Default::default(),
        device: mode360_model::model::ComputeDevice::Cpu,
        show_progress: false,
    }
}

/// Training on a GPU that this binary or machine lacks is an error naming CUDA and what was
/// found, before the run folder is made (on a GPU host with the `cuda` feature it trains).
#[test]
fn training_on_a_missing_gpu_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let on_gpu = TrainOptions {
        device: mode360_model::model::ComputeDevice::Cuda { ordinal: 0 },
        ..opts(&out, 1)
    };
    if let Err(e) = run_training(&on_gpu) {
        let e = e.to_string();
        assert!(
            e.contains("CUDA device cuda:0") && e.contains("found"),
            "{e}"
        );
        assert!(
            !out.exists(),
            "{} made before the device failed",
            out.display()
        );
    }
}

#[test]
fn a_fine_head_rate_scale_that_is_not_positive_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    for scale in [0.0, -2.0, f64::NAN] {
        let bad = TrainOptions {
            fine_head_lr_scale: scale,
            ..opts(&out, 1)
        };
        let Err(e) = run_training(&bad) else {
            panic!("fine_head_lr_scale {scale} was accepted");
        };
        let e = e.to_string();
        assert!(
            e.contains("fine_head_lr_scale") && e.contains("positive"),
            "{e}"
        );
    }
    assert!(!out.exists(), "{} made for refused options", out.display());
}

/// `fine_head_only`: two steps leave every variable outside `fine_head.*` exactly at its start
/// value and move the head; the optimizer's checkpoint holds the head's moments alone; a
/// resume that drops the flag, and the flag on a preset without a head, are refused by name.
#[test]
fn training_the_fine_head_alone_moves_only_the_head() {
    let dir = tempfile::tempdir().unwrap();
    let fine = |out: &Path, steps: usize| TrainOptions {
        preset: mode360_model::model::Preset::ParallaxZnccLogFine,
        width: Some(64),
        fine_head_only: true,
        lr: 1e-2,
        val_every: 0,
        ..opts(out, steps)
    };
    let start = run_training(&fine(&dir.path().join("start"), 0)).unwrap();
    let trained = run_training(&fine(&dir.path().join("head"), 2)).unwrap();
    assert_eq!(trained.final_step, 2);
    let (before, after) = (weights(&start.weights_path), weights(&trained.weights_path));
    assert_eq!(before.len(), after.len());
    let mut head_moved = 0;
    for (name, b) in &before {
        if name.starts_with("fine_head.") {
            head_moved += usize::from(after[name] != *b);
        } else {
            assert!(after[name] == *b, "{name} moved; only the head learns");
        }
    }
    assert!(
        head_moved >= 2,
        "{head_moved} of the head's variables moved"
    );
    let moments = weights(
        &dir.path()
            .join("head")
            .join(CHECKPOINT_DIR)
            .join(mode360_train::OPTIMIZER_FILE),
    );
    assert_eq!(moments.len(), 8, "m and v of the head's 4 variables");
    assert!(
        moments.keys().all(|k| k.contains("fine_head.")),
        "{moments:?}"
    );

    let resumed_in_full = TrainOptions {
        fine_head_only: false,
        resume: true,
        ..fine(&dir.path().join("head"), 4)
    };
    let e = run_training(&resumed_in_full).unwrap_err().to_string();
    assert!(e.contains("fine_head_only"), "{e}");
    let no_head = TrainOptions {
        fine_head_only: true,
        ..opts(&dir.path().join("plain"), 1)
    };
    let e = run_training(&no_head).unwrap_err().to_string();
    assert!(
        e.contains("fine_head_only") && e.contains("no fine head"),
        "{e}"
    );
}

fn weights(path: &Path) -> HashMap<String, Vec<f32>> {
    candle_core::safetensors::load(path, &candle_core::Device::Cpu)
        .unwrap()
        .into_iter()
        .map(|(k, t)| (k, t.flatten_all().unwrap().to_vec1::<f32>().unwrap()))
        .collect()
}

/// Bit-exact comparison needs a fixed reduction order: the CPU kernels' multi-threaded
/// reductions differ run to run in the last bit, so this test runs in a one-thread pool.
#[test]
fn resume_is_exact_and_logs_are_written() {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(resume_is_exact_body);
}

fn resume_is_exact_body() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let full = run_training(&opts(a.path(), 4)).unwrap();
    assert_eq!(full.final_step, 4);
    assert!(full.last_loss.is_finite() && full.last_loss > 0.0);

    let first = run_training(&opts(b.path(), 2)).unwrap();
    assert_eq!(first.final_step, 2);
    let after_two = weights(&first.weights_path);
    let mut resumed_opts = opts(b.path(), 4);
    resumed_opts.resume = true;
    let resumed = run_training(&resumed_opts).unwrap();
    assert_eq!(resumed.start_step, 2);
    assert_eq!(resumed.final_step, 4);

    let wa = weights(&full.weights_path);
    let wb = weights(&resumed.weights_path);
    assert!(!wa.is_empty());
    assert_eq!(wa.len(), wb.len());
    let mut moved = 0usize;
    for (k, va) in &wa {
        let vb = &wb[k];
        let max_diff = va
            .iter()
            .zip(vb)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(
            va == vb,
            "tensor {k} differs after resume by up to {max_diff}"
        );
        if after_two[k] != *va {
            moved += 1;
        }
    }
    assert!(moved > 0, "steps 3-4 changed no weights");
    assert!(b.path().join(CHECKPOINT_DIR).join("state.json").is_file());

    // train.csv: header + 4 rows, steps 1..4 once each (resume truncated nothing extra).
    for dir in [a.path(), b.path()] {
        let train = Csv::read(&dir.join(TRAIN_CSV));
        let steps: Vec<f64> = train.column("step");
        assert_eq!(steps, vec![1.0, 2.0, 3.0, 4.0]);
        let val = Csv::read(&dir.join(VAL_CSV));
        assert_eq!(val.column("step"), vec![2.0, 4.0]);
        for loss in val.column("loss") {
            assert!(loss.is_finite() && loss > 0.0, "val loss {loss}");
        }
        for delta1 in val.column("delta1_pct") {
            assert!((0.0..=100.0).contains(&delta1), "delta1 {delta1}");
        }
        for rss in val.column("peak_rss_mib") {
            assert!(rss > 0.0 && rss < 8192.0, "peak rss {rss} MiB");
        }
        let png = image::open(dir.join(CURVES_PNG)).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (800, 600));
        let coloured = png.pixels().filter(|p| p.0 == [40, 90, 200]).count();
        assert!(coloured > 50, "train curve drew {coloured} pixels");
    }
    // Identical validation numbers at step 4 for both runs (every column but the memory).
    let (va, vb) = (
        Csv::read(&a.path().join(VAL_CSV)),
        Csv::read(&b.path().join(VAL_CSV)),
    );
    assert_eq!(va.header, vb.header);
    for name in va.header.iter().filter(|h| *h != "peak_rss_mib") {
        assert_eq!(va.column(name), vb.column(name), "val.csv column {name}");
    }
}

/// Fine-tuning: a new run started from a weights file holds exactly those weights before its
/// first step, and weights of another architecture are refused with both sizes named.
#[test]
fn init_weights_start_a_run_from_a_weights_file() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let trained = run_training(&opts(a.path(), 2)).unwrap();
    let mut start = opts(b.path(), 0);
    start.stream.seed = 6; // a different random initialisation, replaced by the file
    start.init_weights = Some(trained.weights_path.clone());
    let started = run_training(&start).unwrap();
    assert_eq!(started.final_step, 0);
    assert_eq!(
        weights(&started.weights_path),
        weights(&trained.weights_path)
    );

    let mut fresh = opts(b.path(), 0);
    fresh.stream.seed = 6;
    let random = run_training(&fresh).unwrap();
    assert_ne!(
        weights(&random.weights_path),
        weights(&trained.weights_path)
    );

    let c = tempfile::tempdir().unwrap();
    let mut wrong = opts(c.path(), 0);
    wrong.preset = mode360_model::model::Preset::Compact;
    wrong.init_weights = Some(trained.weights_path);
    let err = run_training(&wrong).unwrap_err().to_string();
    assert!(
        err.contains("init_weights") && err.contains("'tiny'"),
        "{err}"
    );
}

/// The arms of a data-mix ablation: `until_step` stops a run where a resumed one then goes on
/// exactly (the schedule follows `steps`), and a fork of a checkpoint with the same options
/// continues it exactly too, while one with another data mix is accepted where a resume is
/// refused, and one of another network is refused naming the field. One-thread pool, as above.
#[test]
fn forks_and_until_step_continue_a_run_exactly() {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(forks_and_until_step_body);
}

fn forks_and_until_step_body() {
    let full_dir = tempfile::tempdir().unwrap();
    let full = run_training(&opts(full_dir.path(), 4)).unwrap();

    // until_step 2 of a 4-step schedule, then resumed to the end
    let stop_dir = tempfile::tempdir().unwrap();
    let stopped = run_training(&TrainOptions {
        until_step: Some(2),
        ..opts(stop_dir.path(), 4)
    })
    .unwrap();
    assert_eq!((stopped.start_step, stopped.final_step), (0, 2));
    let resumed = run_training(&TrainOptions {
        resume: true,
        ..opts(stop_dir.path(), 4)
    })
    .unwrap();
    assert_eq!((resumed.start_step, resumed.final_step), (2, 4));
    assert_eq!(
        weights(&resumed.weights_path),
        weights(&full.weights_path),
        "until_step 2 + resume differs from 4 steps at once"
    );

    // a fork of a step-2 checkpoint with the same options
    let again = tempfile::tempdir().unwrap();
    run_training(&TrainOptions {
        until_step: Some(2),
        ..opts(again.path(), 4)
    })
    .unwrap();
    let fork_dir = tempfile::tempdir().unwrap();
    let forked = run_training(&TrainOptions {
        fork_from: Some(again.path().to_path_buf()),
        ..opts(fork_dir.path(), 4)
    })
    .unwrap();
    assert_eq!((forked.start_step, forked.final_step), (2, 4));
    assert_eq!(
        weights(&forked.weights_path),
        weights(&full.weights_path),
        "a same-options fork differs from the run it forked"
    );
    let train = Csv::read(&fork_dir.path().join(TRAIN_CSV));
    assert_eq!(train.column("step"), vec![3.0, 4.0]);

    // another data mix: a resume refuses it, a fork takes it and trains on other samples
    let other_mix = |mut o: TrainOptions| {
        o.stream.mix.objects_fraction = 0.0;
        o.stream.mix.street = mode360_synth::StreetStyle::Regular;
        o
    };
    let err = run_training(&other_mix(TrainOptions {
        resume: true,
        ..opts(again.path(), 4)
    }))
    .unwrap_err()
    .to_string();
    assert!(err.contains("objects_fraction"), "{err}");
    let mix_dir = tempfile::tempdir().unwrap();
    let mixed = run_training(&other_mix(TrainOptions {
        fork_from: Some(again.path().join(CHECKPOINT_DIR)),
        ..opts(mix_dir.path(), 4)
    }))
    .unwrap();
    assert_eq!((mixed.start_step, mixed.final_step), (2, 4));
    assert_ne!(weights(&mixed.weights_path), weights(&full.weights_path));

    // another network: refused naming the preset; no checkpoint at all: refused naming the folder
    let wrong_dir = tempfile::tempdir().unwrap();
    let err = run_training(&TrainOptions {
        preset: mode360_model::model::Preset::Compact,
        fork_from: Some(again.path().to_path_buf()),
        ..opts(wrong_dir.path(), 4)
    })
    .unwrap_err()
    .to_string();
    assert!(err.contains("'preset' was tiny"), "{err}");
    let empty = tempfile::tempdir().unwrap();
    let err = run_training(&TrainOptions {
        fork_from: Some(empty.path().to_path_buf()),
        ..opts(wrong_dir.path(), 4)
    })
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("fork_from") && err.contains("no checkpoint"),
        "{err}"
    );
}

/// A numeric CSV file with a header row, read by column name.
struct Csv {
    header: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Csv {
    fn read(path: &std::path::Path) -> Self {
        let text = std::fs::read_to_string(path).unwrap();
        let mut lines = text.lines();
        let header = lines
            .next()
            .unwrap_or_default()
            .split(',')
            .map(str::to_string)
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(|f| f.parse().unwrap()).collect())
            .collect();
        Self { header, rows }
    }

    /// Every row's value in column `name` (panics naming the column if there is none).
    fn column(&self, name: &str) -> Vec<f64> {
        let k = self
            .header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name} in {:?}", self.header));
        self.rows.iter().map(|r| r[k]).collect()
    }
}
