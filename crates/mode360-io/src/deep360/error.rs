//! Errors of the Deep360 reader; each names the file at fault.

use mode360_core::geometry::{GeometryError, RigError};

/// Errors reading Deep360: each names the file and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum Deep360Error {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot decode image: {message}")]
    Image { path: String, message: String },
    #[error("{path}: image is {width}x{height}, expected {expected_width}x{expected_height}")]
    ImageSize {
        path: String,
        width: u32,
        height: u32,
        expected_width: usize,
        expected_height: usize,
    },
    #[error("{path}: not a valid .npz archive: {message}")]
    Npz { path: String, message: String },
    #[error("{path}: array '{key}': {message}")]
    Npy {
        path: String,
        key: String,
        message: String,
    },
    #[error("Deep360 rig: {0}")]
    Rig(#[from] RigError),
    #[error("Deep360 output grid: {0}")]
    Grid(#[from] GeometryError),
}
