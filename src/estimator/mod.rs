//! Depth estimators: N synchronized panoramas in, one ERP range image of the rig's output
//! frame out.

use crate::frame::{FloatImage, RgbImage};
use crate::geometry::{ErpGrid, Rig};

pub mod photometric;
pub mod ssmode;

/// What an estimator returns for one frame.
#[derive(Clone, Debug)]
pub struct DepthEstimate {
    /// Range in metres along each output pixel's ray (NaN where invalid).
    pub range_m: FloatImage,
    /// Per-pixel confidence in [0, 1].
    pub confidence: FloatImage,
}

impl DepthEstimate {
    /// An estimate on `output` from row-major range and confidence values.
    pub fn on_grid(output: ErpGrid, range_m: Vec<f32>, confidence: Vec<f32>) -> Self {
        let image = |data| FloatImage {
            width: output.width(),
            height: output.height(),
            data,
        };
        Self {
            range_m: image(range_m),
            confidence: image(confidence),
        }
    }
}

/// Why an estimator could not produce depth for a frame.
#[derive(Debug, thiserror::Error)]
pub enum EstimatorError {
    #[error("estimator got {got} images for a rig of {expected} cameras")]
    ImageCount { got: usize, expected: usize },
    #[error("camera '{camera}': image is {width}x{height}; ERP images must be twice as wide as tall and of even width")]
    BadImageSize {
        camera: String,
        width: u32,
        height: u32,
    },
    #[error("estimator config field '{field}': {problem}")]
    BadConfig { field: String, problem: String },
    #[error("unknown estimator '{name}' (known: {known})")]
    UnknownEstimator { name: String, known: String },
    #[error("{0}")]
    Geometry(#[from] crate::geometry::GeometryError),
    #[error("{0}")]
    Model(#[from] crate::model::ModelError),
}

/// A depth estimator. Implementations may cache per-rig work (sampling tables) between calls.
pub trait DepthEstimator: Send {
    /// Short name used on the command line and in reports (`photometric`, `ssmode`).
    fn name(&self) -> &str;

    /// Range of every pixel of `output` (an ERP grid in the rig's output frame) from `images`,
    /// one per camera of `rig`, in rig order.
    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError>;
}

/// Estimator names accepted by [`by_name`].
pub const ESTIMATOR_NAMES: &[&str] = &["photometric", "ssmode"];

/// The estimator called `name`, with its default settings (SSMODE: the shipped weights).
pub fn by_name(name: &str) -> Result<Box<dyn DepthEstimator>, EstimatorError> {
    by_name_with_weights(name, None)
}

/// Like [`by_name`]; `weights` replaces SSMODE's shipped weights (an error for estimators
/// without weights, so that a mistyped estimator name does not silently ignore them).
pub fn by_name_with_weights(
    name: &str,
    weights: Option<&std::path::Path>,
) -> Result<Box<dyn DepthEstimator>, EstimatorError> {
    match (name, weights) {
        ("photometric", None) => Ok(Box::new(photometric::PhotometricSweep::new(
            photometric::PhotometricConfig::default(),
        )?)),
        ("photometric", Some(path)) => Err(EstimatorError::BadConfig {
            field: "weights".to_string(),
            problem: format!(
                "the photometric estimator has no weights (got {})",
                path.display()
            ),
        }),
        ("ssmode", Some(path)) => Ok(Box::new(ssmode::SsmodeEstimator::load(path)?)),
        ("ssmode", None) => Ok(Box::new(ssmode::SsmodeEstimator::load(
            ssmode::default_weights_path(),
        )?)),
        (other, _) => Err(EstimatorError::UnknownEstimator {
            name: other.to_string(),
            known: ESTIMATOR_NAMES.join(", "),
        }),
    }
}
