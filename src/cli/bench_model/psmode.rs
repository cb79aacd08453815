//! PSMODE's cases of `mode360 bench-model`: the whole estimator per frame, as the node runs it
//! (stage 1 on every camera pair of the rig at its network's width, each pair's range brought
//! into the output frame, then the pairs' consensus per pixel or the fusion network).
//!
//! Unlike the SSMODE cases, the width is the frame's (images in, depth out), not a network's:
//! both networks run at the widths they were trained at, as in the node.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};

use mode360_core::geometry::{ErpGrid, Rig};
use mode360_core::memory::{reset_peak_resident, resident_mib};
use mode360_estimator::psmode::{
    fusion_weights_path, PairChoice, PsmodeEstimator, CONSENSUS_FUSION, DEFAULT_FUSION_WEIGHTS_PATH,
};
use mode360_estimator::ssmode::{locate_weights, PSMODE_STAGE1_WEIGHTS_PATH};
use mode360_estimator::DepthEstimator;
use mode360_model::model::{read_config, ComputeDevice};
use mode360_synth::{SynthConfig, SynthRenderer};

use super::{median, observed_peak_mib, ModelBenchCase, StageSummary};

/// Name of PSMODE without the fusion network (its default: the pairs' consensus per pixel) in
/// `--presets`.
pub const PSMODE: &str = "psmode";
/// Name of PSMODE with the fusion network in `--presets`.
pub const PSMODE_FUSION: &str = "psmode_fusion";

/// The stage a PSMODE case reports: the estimator's whole frame.
const ESTIMATE_STAGE: &str = "estimate";

/// What one PSMODE case measures.
#[derive(Clone, Debug)]
pub struct PsmodeBenchOptions {
    /// Stage-1 weights (SSMODE's); `None`: the shipped default.
    pub stage1_weights: Option<PathBuf>,
    /// Fusion weights; `None`: no fusion network (PSMODE's default).
    pub fusion_weights: Option<PathBuf>,
    /// Frame width (images and depth; height = width / 2).
    pub width: usize,
    /// Stage 1's input width where `width` is at least that ([`PsmodeEstimator::load_on`]).
    pub pair_width: usize,
    pub rig: Rig,
    /// Timed frames (after one untimed warm-up frame).
    pub runs: usize,
    /// Scene seed of the rendered input frame.
    pub seed: u64,
    pub device: ComputeDevice,
}

/// The fusion weights of the case named `name`: the shipped fusion network for
/// [`PSMODE_FUSION`], PSMODE's default (the pairs' consensus) for [`PSMODE`].
pub fn case_fusion_weights(name: &str) -> Option<PathBuf> {
    fusion_weights_path((name == PSMODE_FUSION).then_some(Path::new(DEFAULT_FUSION_WEIGHTS_PATH)))
}

/// Parameters stored in a weights file (every tensor of it).
fn stored_parameters(path: &Path) -> Result<usize> {
    let tensors = candle_core::safetensors::load(path, &candle_core::Device::Cpu)
        .with_context(|| format!("reading {}", path.display()))?;
    Ok(tensors.values().map(|t| t.elem_count()).sum())
}

/// Runs one PSMODE case: one warm-up frame (the per-rig tables are built then), `runs` timed
/// frames of the estimator, peak memory over all of it.
pub fn bench_psmode_case(opts: &PsmodeBenchOptions) -> Result<ModelBenchCase> {
    anyhow::ensure!(opts.runs >= 1, "--runs must be at least 1");
    let peak_reset = reset_peak_resident();
    let rss_start_mib = resident_mib().unwrap_or(0.0);
    let stage1 = locate_weights(
        opts.stage1_weights
            .as_deref()
            .unwrap_or(Path::new(PSMODE_STAGE1_WEIGHTS_PATH)),
    );
    let cfg = read_config(&stage1)
        .with_context(|| format!("reading the config of {}", stage1.display()))?;
    let mut estimator = PsmodeEstimator::load_on(
        &stage1,
        opts.fusion_weights.as_deref(),
        opts.device,
        PairChoice::All,
        opts.pair_width,
    )?;
    // the fusion network's file, if the setting names one (the consensus names none)
    let network = opts
        .fusion_weights
        .as_deref()
        .filter(|f| *f != Path::new(CONSENSUS_FUSION));
    let mut parameters = stored_parameters(&stage1)?;
    if let Some(fusion) = network {
        parameters += stored_parameters(fusion)?;
    }
    let renderer = SynthRenderer::new(SynthConfig {
        seed: opts.seed,
        width: opts.width,
        ..Default::default()
    })
    .context("rendering the benchmark frame")?;
    let frame = renderer.render_frame(&opts.rig, 0);
    let grid = ErpGrid::new(opts.width)?;
    // warm-up: the pairs' tables, page faults, thread pools
    estimator.estimate(&opts.rig, &frame.images, grid)?;
    let rss_after_warmup_mib = resident_mib().unwrap_or(0.0);
    let mut times = Vec::with_capacity(opts.runs);
    for _ in 0..opts.runs {
        let start = Instant::now();
        estimator.estimate(&opts.rig, &frame.images, grid)?;
        times.push(start.elapsed().as_secs_f64());
    }
    let network_min_s = times.iter().copied().fold(f64::INFINITY, f64::min);
    let median_s = median(&mut times);
    let name = if network.is_some() {
        PSMODE_FUSION
    } else {
        PSMODE
    };
    Ok(ModelBenchCase {
        preset: format!(
            "{name} ({}, {} pairs at {})",
            stage1
                .file_name()
                .map(|f| f.to_string_lossy())
                .unwrap_or_default(),
            estimator.pair_count(),
            estimator.stage1_width(opts.width)
        ),
        width: opts.width,
        height: opts.width / 2,
        cameras: opts.rig.cameras.len(),
        parameters,
        spheres: cfg.sphere_hypotheses()?.count(),
        hypotheses: cfg.output_hypotheses()?.count(),
        trained_weights: true,
        device: opts.device.to_string(),
        runs: opts.runs,
        threads: rayon::current_num_threads(),
        stages: vec![StageSummary {
            stage: ESTIMATE_STAGE.to_string(),
            median_s,
            // the networks' work is not counted across the pairs
            gflop: 0.0,
            gflops_per_s: 0.0,
        }],
        network_median_s: median_s,
        network_min_s,
        end_to_end_median_s: median_s,
        rss_start_mib,
        peak_rss_mib: observed_peak_mib(&[rss_start_mib, rss_after_warmup_mib]),
        peak_reset,
    })
}
