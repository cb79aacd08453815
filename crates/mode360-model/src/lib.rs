//! The SSMODE network ([`model`]) in candle: spherical feature extraction, the sweep onto
//! concentric spheres, the cost volume with its photometric channel, hourglass aggregation and
//! the regression readout, with the ops they run on (CPU kernels and their CUDA twins). Also
//! the windowed ZNCC matching ([`matching`]) that the photometric sweep of `mode360-estimator`
//! shares, and the run-time CPU feature check of the vectorised kernels ([`cpu`]).

pub mod cpu;
pub mod matching;
pub mod model;
