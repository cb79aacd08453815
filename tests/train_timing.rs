//! Timing run (ignored by default): `cargo test --test train_timing -- --ignored --nocapture`.
//! Trains the compact preset at batch 1 for a few steps and prints seconds per step and peak
//! memory. `MODE360_TIMING_STEPS` sets the step count (default 6), `MODE360_TIMING_PRESET`
//! the preset (default compact), `MODE360_TIMING_VAL_EVERY` the validation interval (default:
//! once at the end), `MODE360_TIMING_OUT` keeps the run directory.

use mode360::train::{run_training, TrainOptions};

#[test]
#[ignore]
fn compact_seconds_per_step() {
    let steps: usize = std::env::var("MODE360_TIMING_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6);
    let preset = std::env::var("MODE360_TIMING_PRESET").unwrap_or_else(|_| "compact".into());
    let val_every: usize = std::env::var("MODE360_TIMING_VAL_EVERY")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(steps);
    let keep = std::env::var("MODE360_TIMING_OUT").ok();
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = keep
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| tmp.path().to_path_buf());
    let dir = &out_dir;
    let summary = run_training(&TrainOptions {
        preset: preset
            .parse()
            .expect("MODE360_TIMING_PRESET names a preset"),
        steps,
        out_dir: out_dir.clone(),
        val_every,
        val_samples: 2,
        warmup_steps: 2,
        show_progress: false,
        ..TrainOptions::default()
    })
    .unwrap();
    let csv = std::fs::read_to_string(dir.join("train.csv")).unwrap();
    let secs: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(3).unwrap().parse().unwrap())
        .collect();
    // The first step includes the first sample's render and sweep-table setup.
    let steady = &secs[1.min(secs.len() - 1)..];
    let mean = steady.iter().sum::<f64>() / steady.len() as f64;
    println!(
        "{preset}: {steps} steps, mean {:.2} s/step (wall incl. validation {:.2}), step secs {secs:?}, \
         losses last {:.4}, peak RSS {:.0} MiB, val {:?}",
        mean, summary.mean_secs_per_step, summary.last_loss, summary.peak_rss_mb,
        summary.last_validation.map(|v| (v.loss, v.metrics.delta1_pct, v.metrics.abs_rel))
    );
    assert!(summary.peak_rss_mb < 8192.0);
}
