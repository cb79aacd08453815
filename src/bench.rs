//! `mode360 bench-model`: wall time per network stage, GFLOP/s and peak resident memory of
//! SSMODE forward passes (inference, CPU), plus the estimator's end-to-end time per frame
//! (panorama resize in, network, resize out).
//!
//! One [`ModelBenchCase`] per preset and width. Peak memory is the process's high-water mark
//! (`VmHWM`), reset at the start of the case where the kernel allows it; run each case in its
//! own process (the binary does) so that one case's freed heap does not count in the next.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use serde::{Deserialize, Serialize};

use crate::estimator::ssmode::SsmodeEstimator;
use crate::estimator::{DepthEstimator, EstimatorError};
use crate::geometry::{ErpGrid, Rig};
use crate::model::{
    load_weights, ModelError, Preset, Ssmode, SsmodeConfig, StageProfiler, SweepSampling,
};
use crate::synth::{SynthConfig, SynthRenderer};
use crate::train::data::image_tensor;

/// Bytes per mebibyte.
const BYTES_PER_MB: f64 = 1024.0 * 1024.0;
/// Value written to `/proc/self/clear_refs` to reset the peak resident set size.
const CLEAR_REFS_RESET_PEAK: &str = "5";

/// Errors of the benchmark.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("{0}")]
    Model(#[from] ModelError),
    #[error("{0}")]
    Estimator(#[from] EstimatorError),
    #[error("rendering the benchmark frame: {0}")]
    Synth(#[from] crate::synth::SynthError),
    #[error("{0}")]
    Geometry(#[from] crate::geometry::GeometryError),
    #[error("bench option '{field}': {problem}")]
    BadOption { field: String, problem: String },
}

impl From<candle_core::Error> for BenchError {
    fn from(e: candle_core::Error) -> Self {
        BenchError::Model(ModelError::Candle(e))
    }
}

/// What one case measures.
#[derive(Clone, Debug)]
pub struct ModelBenchOptions {
    /// Network preset; ignored for the config when `weights` is given.
    pub preset: Preset,
    /// Network input width (height = width / 2); `None`: the preset's (or the weights') width.
    pub width: Option<usize>,
    /// Trained weights; `None`: random weights of the preset (same cost).
    pub weights: Option<PathBuf>,
    pub rig: Rig,
    /// Timed forward passes (after one untimed warm-up pass).
    pub runs: usize,
    /// Scene seed of the rendered input frame.
    pub seed: u64,
}

/// One stage over the timed runs.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StageSummary {
    pub stage: String,
    /// Median wall time over the runs.
    pub median_s: f64,
    /// Convolution and matrix-product work per pass.
    pub gflop: f64,
    pub gflops_per_s: f64,
}

/// Result of one preset at one width.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ModelBenchCase {
    pub preset: String,
    pub width: usize,
    pub height: usize,
    pub cameras: usize,
    pub parameters: usize,
    pub spheres: usize,
    pub hypotheses: usize,
    pub trained_weights: bool,
    pub runs: usize,
    pub threads: usize,
    pub stages: Vec<StageSummary>,
    /// Median of the network's forward pass (sum of the stages).
    pub network_median_s: f64,
    pub network_min_s: f64,
    /// Median of the estimator per frame: resize in, network, resize out (panoramas at `width`).
    pub end_to_end_median_s: f64,
    /// Resident memory before the model was built.
    pub rss_start_mb: f64,
    /// Peak resident memory of the case (model, tables, passes).
    pub peak_rss_mb: f64,
    /// Whether the peak could be reset at the start (else it includes earlier work).
    pub peak_reset: bool,
}

/// Current resident set size (`VmRSS`) in MB, when `/proc` has it.
pub fn resident_mb() -> Option<f64> {
    proc_status_kb("VmRSS:").map(|kb| kb * 1024.0 / BYTES_PER_MB)
}

/// Peak resident set size (`VmHWM`) in MB, when `/proc` has it.
pub fn peak_resident_mb() -> Option<f64> {
    proc_status_kb("VmHWM:").map(|kb| kb * 1024.0 / BYTES_PER_MB)
}

/// Resets the peak resident set size (Linux 4.0+); false where that is not possible.
pub fn reset_peak_resident() -> bool {
    std::fs::write("/proc/self/clear_refs", CLEAR_REFS_RESET_PEAK).is_ok()
}

/// The value in kB of the field `key` (e.g. `"VmRSS:"`) in the text of `/proc/<pid>/status`.
pub fn status_field_kb(status: &str, key: &str) -> Option<f64> {
    status
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
}

fn proc_status_kb(key: &str) -> Option<f64> {
    status_field_kb(&std::fs::read_to_string("/proc/self/status").ok()?, key)
}

/// The network with untracked weights: from `weights` (config from its metadata) or random
/// (the preset's initialisation), `width` overriding the config's input width.
fn build_network(
    preset: Preset,
    width: Option<usize>,
    weights: Option<&Path>,
    device: &Device,
) -> Result<(Ssmode, usize), BenchError> {
    let (mut cfg, vb) = match weights {
        Some(path) => load_weights(path, device)?,
        None => {
            let cfg = preset.config();
            // Initialise through a VarMap, then rebuild over plain (untracked) copies so that
            // the timed passes build no autograd graph.
            let varmap = VarMap::new();
            Ssmode::new(&cfg, VarBuilder::from_varmap(&varmap, DType::F32, device))?;
            let plain: HashMap<String, Tensor> = {
                let data = varmap.data().lock().map_err(|_| BenchError::BadOption {
                    field: "weights".into(),
                    problem: "variable map lock poisoned".into(),
                })?;
                data.iter()
                    .map(|(k, v)| (k.clone(), v.as_tensor().detach()))
                    .collect()
            };
            (cfg, VarBuilder::from_tensors(plain, DType::F32, device))
        }
    };
    let parameters = count_parameters(&cfg, device)?;
    if let Some(w) = width {
        cfg.width = w;
        cfg.validate()?;
    }
    Ok((Ssmode::new(&cfg, vb)?, parameters))
}

/// Parameters of the network `cfg` describes (counted on a fresh VarMap).
fn count_parameters(cfg: &SsmodeConfig, device: &Device) -> Result<usize, BenchError> {
    let varmap = VarMap::new();
    Ssmode::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, device))?;
    Ok(varmap.all_vars().iter().map(|v| v.elem_count()).sum())
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => 0.0,
        n if n % 2 == 1 => values[n / 2],
        n => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// Runs one case. See the module docs.
pub fn bench_model_case(opts: &ModelBenchOptions) -> Result<ModelBenchCase, BenchError> {
    if opts.runs == 0 {
        return Err(BenchError::BadOption {
            field: "runs".into(),
            problem: "must be at least 1".into(),
        });
    }
    let peak_reset = reset_peak_resident();
    let rss_start_mb = resident_mb().unwrap_or(0.0);
    let device = Device::Cpu;
    let (model, parameters) =
        build_network(opts.preset, opts.width, opts.weights.as_deref(), &device)?;
    let cfg = model.config().clone();
    let sampling = SweepSampling::new(&opts.rig, &cfg)?;
    let renderer = SynthRenderer::new(SynthConfig {
        seed: opts.seed,
        width: cfg.width,
        ..Default::default()
    })?;
    let frame = renderer.render_frame(&opts.rig, 0);
    let images = frame
        .images
        .iter()
        .map(image_tensor)
        .collect::<Result<Vec<_>, _>>()?;

    // Warm-up (page faults, thread pools), untimed.
    model.forward(&images, &sampling, false)?;
    let mut stage_times: Vec<(String, Vec<f64>, u64)> = Vec::new();
    let mut network = Vec::with_capacity(opts.runs);
    for _ in 0..opts.runs {
        let mut profiler = StageProfiler::new();
        let start = Instant::now();
        let out = model.forward_profiled(&images, &sampling, false, Some(&mut profiler))?;
        network.push(start.elapsed().as_secs_f64());
        drop(out);
        for t in profiler.stages() {
            match stage_times.iter_mut().find(|(s, _, _)| s == t.stage) {
                Some((_, times, _)) => times.push(t.elapsed.as_secs_f64()),
                None => {
                    stage_times.push((t.stage.to_string(), vec![t.elapsed.as_secs_f64()], t.flops))
                }
            }
        }
    }
    let stages = stage_times
        .into_iter()
        .map(|(stage, mut times, flops)| {
            let median_s = median(&mut times);
            let gflop = flops as f64 / 1e9;
            StageSummary {
                stage,
                median_s,
                gflop,
                gflops_per_s: if median_s > 0.0 {
                    gflop / median_s
                } else {
                    0.0
                },
            }
        })
        .collect();

    let label = opts
        .weights
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("<random {}>", opts.preset)));
    let mut estimator = SsmodeEstimator::from_model(model, label);
    let grid = ErpGrid::new(cfg.width)?;
    let mut end_to_end = Vec::with_capacity(opts.runs);
    for _ in 0..opts.runs {
        let start = Instant::now();
        estimator.estimate(&opts.rig, &frame.images, grid)?;
        end_to_end.push(start.elapsed().as_secs_f64());
    }
    let network_min_s = network.iter().copied().fold(f64::INFINITY, f64::min);
    Ok(ModelBenchCase {
        preset: cfg_preset_name(opts.preset, opts.weights.as_deref()),
        width: cfg.width,
        height: cfg.height(),
        cameras: opts.rig.cameras.len(),
        parameters,
        spheres: cfg.sphere_hypotheses()?.count(),
        hypotheses: cfg.output_hypotheses()?.count(),
        trained_weights: opts.weights.is_some(),
        runs: opts.runs,
        threads: rayon::current_num_threads(),
        stages,
        network_median_s: median(&mut network),
        network_min_s,
        end_to_end_median_s: median(&mut end_to_end),
        rss_start_mb,
        peak_rss_mb: peak_resident_mb().unwrap_or(0.0),
        peak_reset,
    })
}

fn cfg_preset_name(preset: Preset, weights: Option<&Path>) -> String {
    match weights {
        Some(p) => format!(
            "{} ({})",
            preset,
            p.file_name()
                .map(|f| f.to_string_lossy())
                .unwrap_or_default()
        ),
        None => preset.to_string(),
    }
}

/// A Markdown table of cases: one row per case and stage.
pub fn format_table(cases: &[ModelBenchCase]) -> String {
    let mut out = String::from(
        "| preset | input | cameras | stage | median s | GFLOP | GFLOP/s |\n|---|---|---|---|---|---|---|\n",
    );
    for c in cases {
        for s in &c.stages {
            out.push_str(&format!(
                "| {} | {}x{} | {} | {} | {:.3} | {:.1} | {:.1} |\n",
                c.preset,
                c.width,
                c.height,
                c.cameras,
                s.stage,
                s.median_s,
                s.gflop,
                s.gflops_per_s
            ));
        }
        let gflop: f64 = c.stages.iter().map(|s| s.gflop).sum();
        out.push_str(&format!(
            "| {} | {}x{} | {} | **network** | {:.3} | {:.1} | {:.1} |\n",
            c.preset,
            c.width,
            c.height,
            c.cameras,
            c.network_median_s,
            gflop,
            if c.network_median_s > 0.0 {
                gflop / c.network_median_s
            } else {
                0.0
            }
        ));
    }
    out.push_str(
        "\n| preset | input | params | spheres / hypotheses | network s (median, min) | end-to-end s | peak RSS MB |\n|---|---|---|---|---|---|---|\n",
    );
    for c in cases {
        out.push_str(&format!(
            "| {} | {}x{} | {} | {} / {} | {:.3}, {:.3} | {:.3} | {:.0}{} |\n",
            c.preset,
            c.width,
            c.height,
            c.parameters,
            c.spheres,
            c.hypotheses,
            c.network_median_s,
            c.network_min_s,
            c.end_to_end_median_s,
            c.peak_rss_mb,
            if c.peak_reset { "" } else { " (not reset)" }
        ));
    }
    out
}
