//! The SSMODE network and its building blocks (candle).
//!
//! Stages, one file each: [`feature`] (spherical feature extraction, per camera, weights shared),
//! [`sphere_conv`] (SphereNet kernel tables), [`cost_volume`] (spherical sweep with exact tables,
//! count-invariant mean/variance over views), [`hourglass`] (3-D stacked hourglass aggregation),
//! [`fine_head`] (the final cost corrected at the cost volume's full resolution),
//! [`regression`] (soft-argmin over inverse-depth hypotheses, confidence), [`ssmode`] (the whole
//! network), [`photometric_cost`] (the sweep's ZNCC matching cost as a cost-volume channel),
//! [`seam`] (the aggregation's longitude wrap), [`fusion`] (PSMODE's second stage: the pairs'
//! ranges fused with the reference panorama),
//! [`weights`] (safetensors with the config in the header), [`config`] (presets),
//! [`readout`] (how the output is read: far-plane test, edge refinement; a setting),
//! [`sweep_sampling`] (per-rig sampling tables), [`device`] (the CPU or a CUDA GPU).

pub mod config;
pub mod cost_volume;
pub mod device;
pub mod feature;
pub mod fine_head;
pub mod fusion;
pub mod hourglass;
pub mod input;
pub mod ops;
pub mod photometric_cost;
pub mod presets;
pub mod readout;
pub mod regression;
pub mod seam;
pub mod softmax_stats;
pub mod sphere_conv;
pub mod ssmode;
pub mod sweep_sampling;
pub mod weights;

pub use config::SsmodeConfig;
pub use device::{ComputeDevice, DeviceError};
pub use fusion::{Fusion, FusionConfig, FusionHead, FusionOutput};
pub use input::input_tensor;
pub use presets::Preset;
pub use readout::{Readout, ReadoutOverrides};
pub use ssmode::{Ssmode, SsmodeOutput, StageProfiler, StageTiming};
pub use sweep_sampling::SweepSampling;
pub use weights::{
    load_fusion_weights, load_weights, load_weights_and_readout, read_config, save_fusion_weights,
    save_weights,
};

/// Errors of the model code (configs, sampling tables, weight files).
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("unknown SSMODE preset '{name}' (known: {known})")]
    UnknownPreset { name: String, known: String },
    #[error("SSMODE config field '{field}': {problem}")]
    BadConfig { field: String, problem: String },
    #[error(
        "image is {width}x{height}; ERP images must be twice as wide as tall and of even width"
    )]
    BadImage { width: u32, height: u32 },
    #[error("SSMODE needs at least {min} cameras, the rig has {got}")]
    TooFewCameras { got: usize, min: usize },
    #[error("{0}")]
    Geometry(#[from] mode360_core::geometry::GeometryError),
    #[error("weights file {path}: {problem}")]
    Weights { path: String, problem: String },
    #[error("weights file {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("tensor error: {0}")]
    Candle(#[from] candle_core::Error),
    #[error("{0}")]
    Device(#[from] DeviceError),
}
