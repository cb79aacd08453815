//! The `--estimator` / `--weights` / `--device` group shared by `eval`, `replay`, `demo` and
//! `bench-node`.

use clap::Args;
use mode360_estimator::estimator::{EstimatorKind, EstimatorSpec};
use mode360_model::model::ComputeDevice;
use std::path::PathBuf;

/// Which depth estimator a command runs, flattened into its arguments.
#[derive(Args, Clone, Debug)]
pub struct EstimatorArgs {
    /// Depth estimator (the trained network by default; the photometric sweep is the
    /// learning-free option).
    #[arg(long, value_enum, default_value_t = EstimatorKind::default())]
    pub estimator: EstimatorKind,
    /// SSMODE weights file (default: the shipped weights; an error with other estimators).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Where SSMODE runs: cpu, or cuda:N for the N-th NVIDIA GPU (needs a build with the `cuda`
    /// feature; the photometric estimator runs on the CPU only).
    #[arg(long, default_value_t = ComputeDevice::Cpu)]
    pub device: ComputeDevice,
}

impl EstimatorArgs {
    /// The estimator these arguments name, not yet loaded.
    pub fn spec(&self) -> EstimatorSpec {
        EstimatorSpec::with_weights(self.estimator, self.weights.clone()).on_device(self.device)
    }
}
