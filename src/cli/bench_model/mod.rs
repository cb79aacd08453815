//! `mode360 bench-model`: wall time per network stage, GFLOP/s and peak resident memory of
//! SSMODE forward passes (inference, on the CPU or a CUDA GPU), plus the estimator's end-to-end time per frame
//! (panorama resize in, network, resize out).
//!
//! One [`ModelBenchCase`] per preset and width; PSMODE's cases ([`psmode`]: `psmode`,
//! `psmode_fusion`) time the whole estimator per frame. Peak memory is the process's high-water mark
//! (`VmHWM`), reset at the start of the case where the kernel allows it; run each case in its
//! own process (the binary does) so that one case's freed heap does not count in the next.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use serde::{Deserialize, Serialize};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;

use mode360_core::geometry::{ErpGrid, Rig};
use mode360_core::memory::{peak_resident_mib, reset_peak_resident, resident_mib};
use mode360_estimator::psmode::DEFAULT_PAIR_WIDTH;
use mode360_estimator::ssmode::{shipped_weights_paths, SsmodeEstimator};
use mode360_estimator::DepthEstimator;
use mode360_model::model::ops::with_composites;
use mode360_model::model::{
    input_tensor, load_weights, read_config, ComputeDevice, Preset, Ssmode, SsmodeConfig,
    StageProfiler, SweepSampling,
};
use mode360_synth::{SynthConfig, SynthRenderer};

pub mod psmode;

use psmode::{bench_psmode_case, case_fusion_weights, PsmodeBenchOptions, PSMODE, PSMODE_FUSION};

/// What `--presets` names: an SSMODE preset, or PSMODE without or with its fusion network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchSubject {
    Ssmode(Preset),
    /// `psmode` (`fusion` false: the default, the pairs' consensus) or `psmode_fusion`.
    Psmode {
        fusion: bool,
    },
}

impl BenchSubject {
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Ssmode(p) => p.as_str(),
            Self::Psmode { fusion: false } => PSMODE,
            Self::Psmode { fusion: true } => PSMODE_FUSION,
        }
    }
}

impl std::fmt::Display for BenchSubject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for BenchSubject {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name {
            PSMODE => Ok(Self::Psmode { fusion: false }),
            PSMODE_FUSION => Ok(Self::Psmode { fusion: true }),
            _ => name
                .parse()
                .map(Self::Ssmode)
                .map_err(|e| format!("{e}, or {PSMODE}, {PSMODE_FUSION}")),
        }
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
    /// Where the network runs.
    pub device: ComputeDevice,
    /// On the CPU, run the ops' device-generic composites (a GPU's path) instead of the kernels.
    pub composites: bool,
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

impl StageSummary {
    /// A stage's `times` (seconds, one per run) and `flops` per pass.
    fn of((stage, mut times, flops): (String, Vec<f64>, u64)) -> Self {
        let median_s = median(&mut times);
        let gflop = flops as f64 / 1e9;
        Self {
            stage,
            median_s,
            gflop,
            gflops_per_s: if median_s > 0.0 {
                gflop / median_s
            } else {
                0.0
            },
        }
    }
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
    /// `cpu` or `cuda:N`, with ` (composites)` when the CPU ran the device-generic ops.
    #[serde(default)]
    pub device: String,
    pub runs: usize,
    pub threads: usize,
    pub stages: Vec<StageSummary>,
    /// Median of the network's forward pass (sum of the stages).
    pub network_median_s: f64,
    pub network_min_s: f64,
    /// Median of the estimator per frame: resize in, network, resize out (panoramas at `width`).
    pub end_to_end_median_s: f64,
    /// Resident memory before the model was built.
    pub rss_start_mib: f64,
    /// Peak resident memory of the case (model, tables, passes): the kernel's high-water mark,
    /// or the largest resident size sampled, whichever is larger.
    pub peak_rss_mib: f64,
    /// Whether the peak could be reset at the start (else it includes earlier work).
    pub peak_reset: bool,
}

/// The network with untracked weights: from `weights` (config from its metadata) or random
/// (the preset's initialisation), `width` overriding the config's input width.
fn build_network(
    preset: Preset,
    width: Option<usize>,
    weights: Option<&Path>,
    device: &Device,
) -> Result<(Ssmode, usize)> {
    let (mut cfg, vb) = match weights {
        Some(path) => load_weights(path, device)?,
        None => {
            let cfg = preset.config();
            // Initialise through a VarMap, then rebuild over plain (untracked) copies so that
            // the timed passes build no autograd graph.
            let varmap = VarMap::new();
            Ssmode::new(&cfg, VarBuilder::from_varmap(&varmap, DType::F32, device))?;
            let plain: HashMap<String, Tensor> = {
                let data = varmap
                    .data()
                    .lock()
                    .map_err(|_| anyhow!("the variable map's lock is poisoned"))?;
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
fn count_parameters(cfg: &SsmodeConfig, device: &Device) -> Result<usize> {
    let varmap = VarMap::new();
    Ssmode::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, device))?;
    Ok(varmap.all_vars().iter().map(|v| v.elem_count()).sum())
}

pub(crate) fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => 0.0,
        n if n % 2 == 1 => values[n / 2],
        n => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// Runs one case. See the module docs.
pub fn bench_model_case(opts: &ModelBenchOptions) -> Result<ModelBenchCase> {
    if opts.composites {
        if opts.device.is_cuda() {
            bail!("--composites compares the CPU's two paths; a GPU always runs the composites");
        }
        return with_composites(|| measure_case(opts));
    }
    measure_case(opts)
}

fn measure_case(opts: &ModelBenchOptions) -> Result<ModelBenchCase> {
    if opts.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let peak_reset = reset_peak_resident();
    let rss_start_mib = resident_mib().unwrap_or(0.0);
    let device = opts.device.open()?;
    let (model, parameters) =
        build_network(opts.preset, opts.width, opts.weights.as_deref(), &device)?;
    let cfg = model.config().clone();
    let sampling = SweepSampling::new(&opts.rig, &cfg)?;
    let renderer = SynthRenderer::new(SynthConfig {
        seed: opts.seed,
        width: cfg.width,
        ..Default::default()
    })
    .context("rendering the benchmark frame")?;
    let frame = renderer.render_frame(&opts.rig, 0);
    let images = frame
        .images
        .iter()
        .map(|img| input_tensor(img, img.width() as usize, &device))
        .collect::<Result<Vec<_>, _>>()?;

    // Warm-up (page faults, thread pools), untimed.
    let warm = model.forward(&images, &sampling, false)?;
    let rss_after_warmup_mib = resident_mib().unwrap_or(0.0);
    drop(warm);
    let mut stage_times: Vec<(String, Vec<f64>, u64)> = Vec::new();
    let mut network = Vec::with_capacity(opts.runs);
    for _ in 0..opts.runs {
        let mut profiler = StageProfiler::new();
        let start = Instant::now();
        let out = model.forward_profiled(&images, &sampling, false, Some(&mut profiler))?;
        // a GPU's kernels run asynchronously: wait for them before reading the clock
        device.synchronize()?;
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
    let stages = stage_times.into_iter().map(StageSummary::of).collect();

    let label = opts
        .weights
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("<random {}>", opts.preset)));
    let mut estimator = SsmodeEstimator::from_model_on(model, label, device);
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
        device: if opts.composites {
            format!("{} (composites)", opts.device)
        } else {
            opts.device.to_string()
        },
        runs: opts.runs,
        threads: rayon::current_num_threads(),
        stages,
        network_median_s: median(&mut network),
        network_min_s,
        end_to_end_median_s: median(&mut end_to_end),
        rss_start_mib,
        peak_rss_mib: observed_peak_mib(&[rss_start_mib, rss_after_warmup_mib]),
        peak_reset,
    })
}

/// The peak resident size in MiB: `VmHWM`, raised to the largest of `samples` (`VmRSS` read
/// during the case).
///
/// The kernel updates the high-water mark lazily (when mappings change, not when pages are
/// given back with `madvise`), so in a process where other threads allocate and free, as in a
/// test binary, `VmHWM` can read below a resident size sampled earlier.
pub(crate) fn observed_peak_mib(samples: &[f64]) -> f64 {
    samples
        .iter()
        .copied()
        .fold(peak_resident_mib().unwrap_or(0.0), f64::max)
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
        "\n| preset | input | device | params | spheres / hypotheses | network s (median, min) | end-to-end s | peak RSS MiB |\n|---|---|---|---|---|---|---|---|\n",
    );
    for c in cases {
        out.push_str(&format!(
            "| {} | {}x{} | {} | {} | {} / {} | {:.3}, {:.3} | {:.3} | {:.0}{} |\n",
            c.preset,
            c.width,
            c.height,
            c.device,
            c.parameters,
            c.spheres,
            c.hypotheses,
            c.network_median_s,
            c.network_min_s,
            c.end_to_end_median_s,
            c.peak_rss_mib,
            if c.peak_reset { "" } else { " (not reset)" }
        ));
    }
    out
}

#[derive(Args)]
pub struct BenchModelArgs {
    /// What to measure (comma separated): any SSMODE preset name, also the ones training does
    /// not offer (tiny, tiny_parallax, tiny_zncc), or psmode / psmode_fusion: PSMODE's whole
    /// estimator per frame at the width (stage 1 at `--pair-width` where the width is at least
    /// that, the fusion network at its trained width), without and with the shipped fusion
    /// network.
    #[arg(long, value_parser = <BenchSubject as std::str::FromStr>::from_str, value_delimiter = ',', default_values_t = [BenchSubject::Ssmode(Preset::Parallax), BenchSubject::Ssmode(Preset::Compact)])]
    pub presets: Vec<BenchSubject>,
    /// Input widths (comma separated, height = width / 2).
    #[arg(long, value_delimiter = ',', default_value = "256,512")]
    pub widths: Vec<usize>,
    /// Trained weights, used for the preset they were trained as (default: the shipped weights
    /// of each preset when present; random weights cost the same); PSMODE's stage 1 (default:
    /// the shipped default weights).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Rig calibration YAML (its camera count is the number of views).
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    pub rig: PathBuf,
    /// Timed passes per case (after one warm-up pass).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Write all cases as JSON here.
    #[arg(long, default_value = "bench_model.json")]
    pub json: PathBuf,
    /// Run the cases in this process instead of one child process per case (peak memory then
    /// includes earlier cases where the kernel cannot reset it).
    #[arg(long)]
    pub in_process: bool,
    /// Where the network runs: cpu, or cuda:N for the N-th NVIDIA GPU (needs a build with the
    /// `cuda` feature).
    #[arg(long, default_value_t = ComputeDevice::Cpu)]
    pub device: ComputeDevice,
    /// On the CPU, run every op's device-generic composite (the path a GPU takes) instead of
    /// the CPU kernels, to compare the two.
    #[arg(long)]
    pub composites: bool,
    /// PSMODE: stage 1's input width where the frame is at least that wide (default 512, as
    /// the estimator's; 0: the width its network was trained at).
    #[arg(long, default_value_t = DEFAULT_PAIR_WIDTH)]
    pub pair_width: usize,
}

pub fn run(a: BenchModelArgs) -> Result<()> {
    let rig = Rig::from_file_or_shipped(&a.rig)?;
    // candidate weights, first match per preset: the given file, then the shipped ones
    let mut candidates = Vec::new();
    if let Some(w) = &a.weights {
        let cfg =
            read_config(w).with_context(|| format!("reading the config of {}", w.display()))?;
        candidates.push((cfg.name, w.clone()));
    }
    for shipped in shipped_weights_paths() {
        if let Ok(cfg) = read_config(&shipped) {
            candidates.push((cfg.name, shipped));
        }
    }
    let mut cases: Vec<ModelBenchCase> = Vec::new();
    // the weights of a case: the first candidate of an SSMODE preset, PSMODE's stage 1 as given
    let weights_of = |subject: &BenchSubject| match subject {
        BenchSubject::Ssmode(preset) => candidates
            .iter()
            .find(|(name, _)| name == preset.as_str())
            .map(|(_, path)| path.clone()),
        BenchSubject::Psmode { .. } => a.weights.clone(),
    };
    let in_process = a.in_process || (a.presets.len() == 1 && a.widths.len() == 1);
    for subject in &a.presets {
        for &width in &a.widths {
            eprintln!("bench-model: {subject} at {width}x{} ...", width / 2);
            let weights = weights_of(subject);
            let case = match subject {
                _ if !in_process => bench_model_child(&a, *subject, width, weights.as_deref())?,
                BenchSubject::Ssmode(preset) => bench_model_case(&ModelBenchOptions {
                    preset: *preset,
                    width: Some(width),
                    weights,
                    rig: rig.clone(),
                    runs: a.runs,
                    seed: 1,
                    device: a.device,
                    composites: a.composites,
                })?,
                BenchSubject::Psmode { .. } => bench_psmode_case(&PsmodeBenchOptions {
                    stage1_weights: weights,
                    fusion_weights: case_fusion_weights(subject.as_str()),
                    width,
                    pair_width: a.pair_width,
                    rig: rig.clone(),
                    runs: a.runs,
                    seed: 1,
                    device: a.device,
                })?,
            };
            cases.push(case);
        }
    }
    print!("{}", format_table(&cases));
    mode360_core::atomic_file::write_atomic(&a.json, serde_json::to_string_pretty(&cases)?)
        .with_context(|| format!("writing {}", a.json.display()))?;
    println!("wrote {}", a.json.display());
    Ok(())
}

/// One case in a child process, so that its peak memory is its own.
fn bench_model_child(
    a: &BenchModelArgs,
    preset: BenchSubject,
    width: usize,
    weights: Option<&std::path::Path>,
) -> Result<ModelBenchCase> {
    let json = std::env::temp_dir().join(format!(
        "mode360-bench-{}-{preset}-{width}.json",
        std::process::id()
    ));
    let exe = std::env::current_exe().context("locating the mode360 binary")?;
    let mut cmd = std::process::Command::new(exe);
    cmd.arg("bench-model")
        .args(["--presets", preset.as_str()])
        .args(["--widths", &width.to_string()])
        .args(["--runs", &a.runs.to_string()])
        .args(["--device", &a.device.to_string()])
        .args(["--pair-width", &a.pair_width.to_string()])
        .arg("--rig")
        .arg(&a.rig)
        .arg("--json")
        .arg(&json)
        .stdout(std::process::Stdio::null());
    if let Some(w) = weights {
        cmd.arg("--weights").arg(w);
    }
    if a.composites {
        cmd.arg("--composites");
    }
    let status = cmd.status().context("starting the bench child process")?;
    if !status.success() {
        bail!("bench-model case {preset} at width {width} failed ({status})");
    }
    let text =
        std::fs::read_to_string(&json).with_context(|| format!("reading {}", json.display()))?;
    // Best effort: a leftover file in the temp dir is harmless.
    let _ = std::fs::remove_file(&json);
    let mut cases: Vec<ModelBenchCase> = serde_json::from_str(&text)?;
    cases
        .pop()
        .with_context(|| format!("{} holds no case", json.display()))
}
