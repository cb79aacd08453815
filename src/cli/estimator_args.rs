//! The `--estimator` / `--weights` / `--device` group shared by `eval`, `replay`, `demo` and
//! `bench-node`.

use clap::Args;
use mode360_estimator::near_pass::NearPassSource;
use mode360_estimator::psmode::PairChoice;
use mode360_estimator::{EstimatorKind, EstimatorSpec};
use mode360_model::model::{ComputeDevice, ReadoutOverrides};
use std::path::PathBuf;

/// Which depth estimator a command runs, flattened into its arguments.
#[derive(Args, Clone, Debug)]
pub struct EstimatorArgs {
    /// Depth estimator (the trained network by default; the photometric sweep is the
    /// learning-free option).
    #[arg(long, value_enum, default_value_t = EstimatorKind::default())]
    pub estimator: EstimatorKind,
    /// SSMODE weights file, or PSMODE's stage 1 (default: the shipped weights,
    /// models/psmode_stage1.safetensors for PSMODE; an error with the photometric sweep).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Where SSMODE runs: cpu, or cuda:N for the N-th NVIDIA GPU (needs a build with the `cuda`
    /// feature; the photometric estimator runs on the CPU only).
    #[arg(long, default_value_t = ComputeDevice::Cpu)]
    pub device: ComputeDevice,
    /// PSMODE: the fusion network's weights (stage 2, `train --stage fusion`), e.g. the shipped
    /// models/psmode_fusion.safetensors; without it (or `consensus`) each pixel takes the range
    /// the pairs agree on; `none`: the most confident pair (the paper's "without fusion").
    #[arg(long)]
    pub fusion_weights: Option<PathBuf>,
    /// PSMODE: the camera pairs of stage 1, `all` or `left-right` camera names separated by
    /// commas (e.g. `cam1-cam2,cam3-cam4`).
    #[arg(long, default_value = "all", value_parser = parse_pairs)]
    pub pairs: PairChoice,
    /// PSMODE: stage 1's input width where the output is at least that wide (default 512;
    /// 0: the width its network was trained at, 256, about three times faster).
    #[arg(long)]
    pub pair_width: Option<usize>,
    /// SSMODE: a second pass of the network at this input width (e.g. 512) for near
    /// obstacles; its range replaces the first pass's where it is over 1.25 times nearer,
    /// within 30 m and confident (at least 0.8). A second forward pass at that width. Off by default.
    #[arg(long)]
    pub near_pass_width: Option<usize>,
    /// SSMODE: what the second pass (`--near-pass-width`) is: the network again, or the
    /// learning-free photometric sweep on a grid of that width, trusted only where it reads
    /// over 1.25 times nearer within 15 m and confident (at least 0.5).
    #[arg(long, value_enum, default_value_t = NearPassSource::default())]
    pub near_pass_source: NearPassSource,
    /// SSMODE's far-plane test: a pixel whose probability on the far field is at least this
    /// reads as out of range (above 1: off). Default: the weights file's, else 0.5.
    #[arg(long)]
    pub far_plane_probability: Option<f64>,
    /// SSMODE's far field: hypotheses within this many cost-volume cells of parallax from the
    /// far plane count as the far plane (0: the far plane alone). Default: the weights
    /// file's, else 0.25.
    #[arg(long)]
    pub far_parallax_cells: Option<f64>,
    /// SSMODE's near mode: a pixel reads the nearest mode of its hypothesis distribution
    /// that holds at least this probability where it is within 10 m and over 1.25 times
    /// nearer than the expectation (above 1: off). Default 0.2.
    #[arg(long)]
    pub near_mode_probability: Option<f64>,
    /// SSMODE's edge refinement: radius in network cells of the confidence-weighted median
    /// before upsampling (0: off; at most 8). Default: the weights file's, else 2.
    #[arg(long)]
    pub refine_radius_cells: Option<usize>,
}

fn parse_pairs(text: &str) -> Result<PairChoice, String> {
    PairChoice::parse(text).map_err(|e| e.to_string())
}

impl EstimatorArgs {
    /// The estimator these arguments name, not yet loaded.
    pub fn spec(&self) -> EstimatorSpec {
        EstimatorSpec {
            pairs: self.pairs.clone(),
            fusion_weights: self.fusion_weights.clone(),
            pair_width: self.pair_width,
            near_pass_width: self.near_pass_width,
            near_pass_source: self.near_pass_source,
            readout: ReadoutOverrides {
                far_plane_probability: self.far_plane_probability,
                far_parallax_cells: self.far_parallax_cells,
                near_mode_probability: self.near_mode_probability,
                refine_radius_cells: self.refine_radius_cells,
            },
            ..EstimatorSpec::with_weights(self.estimator, self.weights.clone())
                .on_device(self.device)
        }
    }
}
