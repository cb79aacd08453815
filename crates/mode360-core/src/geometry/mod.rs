//! Spherical geometry: free of tensors and ROS.
//!
//! * [`erp`]: the equirectangular (ERP) projection of a 360° camera and bilinear taps with
//!   longitude wrap.
//! * [`geer`]: the paper's generalized epipolar equirectangular projection (GEER) for a camera
//!   pair, in which epipolar lines are image rows.
//! * [`camera`]: camera models (double sphere, Kannala-Brandt, EUCM, dual fisheye, and the
//!   ERP grid) behind one `project` / `unproject` interface.
//! * [`rig`]: the rig calibration, validated by `Rig::new`; [`rig_yaml`] reads and writes it.
//! * [`import`]: a Kalibr camchain or a Basalt `calibration.json` into a rig.
//! * [`erp_rotation`]: an ERP panorama resampled into a rotated frame at the same centre.
//! * [`pair_view`]: a camera pair in its GEER frame (PSMODE's first stage): the pair as a
//!   two-camera rig, panoramas turned into it, its range brought back into the output frame.
//! * [`panorama`]: every camera as a panorama (its REP 103 frame, which directions it sees,
//!   a fisheye image resampled into an ERP panorama with a validity mask).
//! * [`sweep`]: inverse-depth hypotheses and exact spherical-sweep sampling tables.
//! * [`far_field`]: per output pixel, the hypotheses a rig cannot tell from the far plane.
//! * [`occlusion`]: per pixel of a range image, the cameras that see its point with no nearer
//!   surface of the same image in the way.

pub mod camera;
pub mod erp;
pub mod erp_rotation;
pub mod far_field;
pub mod geer;
pub mod import;
pub mod occlusion;
pub mod pair_view;
pub mod panorama;
pub mod rig;
pub mod rig_match;
pub mod rig_yaml;
pub mod sweep;

pub use camera::{CameraModel, ImageSize, IntrinsicsError};
pub use erp::{resample_erp, BilinearTaps, ErpGrid, ErpSample, LonLat, PixelCoord};
pub use erp_rotation::ErpRotation;
pub use far_field::FarField;
pub use geer::{GeerAngles, GeerPair};
pub use pair_view::{AlignedRange, CameraPair, PairSide, PairView};
pub use rig::{ImageSizeError, Projection, Rig, RigCamera, RigError, RigOutput};
pub use sweep::{DepthHypotheses, DepthRange, HypothesisSpacing, SweepGeometry, SweepTable};

/// The far range, metres: the sky's range and the clamp of depth images unless configured
/// otherwise (the paper's maximum depth and Deep360's).
pub const DEFAULT_MAX_DEPTH_M: f64 = 1000.0;

/// Errors of the geometry constructors.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    #[error("ERP width must be even and at least {min}, got {width}")]
    BadErpWidth { width: usize, min: usize },
    #[error("ERP width {width} is larger than the largest accepted, {max}")]
    ErpTooWide { width: usize, max: usize },
    #[error("GEER pair needs two distinct camera centres (baseline {baseline_m} m)")]
    ZeroBaseline { baseline_m: f64 },
    #[error("depth range must satisfy 0 < min < max, got min {min_m} m, max {max_m} m")]
    BadDepthRange { min_m: f64, max_m: f64 },
    #[error("need at least {min} hypotheses, got {count}")]
    TooFewHypotheses { count: usize, min: usize },
    #[error("image is {}x{}, expected {}x{}", got.0, got.1, expected.0, expected.1)]
    WrongImageSize {
        expected: (usize, usize),
        got: (usize, usize),
    },
    #[error("camera index {index} out of range for a rig of {count} cameras")]
    NoSuchCamera { index: usize, count: usize },
    #[error("camera {camera}: projection {projection} is not supported by {consumer} yet (equirectangular cameras only)")]
    UnsupportedProjection {
        camera: String,
        projection: &'static str,
        consumer: &'static str,
    },
}
