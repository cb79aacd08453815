//! Calibration check and refinement: which small rotation of one camera makes the cameras
//! agree best at the estimated depth.
//!
//! On an ERP grid of the output frame ([`RotationCheckConfig::analysis_width`] wide), every
//! camera's grey panorama is sampled at the estimated 3-D point `X_k = rho_k dir_k` of each
//! direction `k` (as in [`super::lens_health`]). Camera `c` turned about its own centre by a
//! small rotation `Q(w) = exp([w]x)` (axis and angle `w` in the rig frame, so
//! `rig_from_cam' = (Q R_c, t_c)`) samples `X_k` elsewhere; its *agreement* with the other
//! cameras is
//!
//! ```text
//! A_c(w) = sum_f sum_{b != c} sum_k cos(lat_k) zncc_k(c_w, b) / sum of the same weights
//! ```
//!
//! with `zncc_k` the windowed ZNCC over `(2 WINDOW_RADIUS + 1)^2` cells, over the frames `f`
//! and the cells `k` where both views are seen and textured at `w = 0` (a fixed set, so that
//! scores at different `w` compare). The correction of camera `c` maximizes `A_c` within
//! [`RotationCheckConfig::max_correction_deg`], by a pattern search along the rig axes with
//! halving steps down to [`RotationCheckConfig::min_step_deg`], then a parabola per axis
//! through the last step. Far points need no depth at all (only rotation moves them), near
//! ones use the estimate; a camera that was knocked disagrees with the others, which keep
//! the estimate right where it matters.
//!
//! Cameras are corrected one at a time against the others; a two-camera rig only shows the
//! rotation between its cameras (both get the same correction, mirrored).
//!
//! | file | what |
//! |---|---|
//! | `frame.rs` | [`CheckFrame`]: one frame's grey panoramas and estimated range, prepared |
//! | `check.rs` | [`RotationCheck`]: the agreement `A_c(w)` and the cells it is measured on |
//! | `search.rs` | each camera's best turn: the pattern search (refine) and Newton steps (drift) |
//! | `refine.rs` | [`refine_rotations`]; [`keep_earned_corrections`] undoes turns that gain nothing |

mod check;
mod frame;
mod refine;
mod search;

use nalgebra::{UnitQuaternion, Vector3};

pub use check::RotationCheck;
pub use frame::CheckFrame;
pub use refine::{
    apply_corrections, correction_gains, keep_earned_corrections, refine_rotations, turns,
};

/// Radius of the ZNCC window, analysis cells.
pub const WINDOW_RADIUS: usize = 2;
/// A window whose deviation (grey in `[0, 1]`) is at most this carries no texture to align.
pub const TEXTURELESS_SIGMA: f32 = 0.02;
/// Relative depth error the cell weights allow for: a cell weighs `cos(lat) / (1 + s^2)`,
/// with `s` the shift in cells that this error of its range would cause for the camera
/// farthest from the output origin.
pub const DEPTH_ERROR_FRACTION: f32 = 0.1;
/// Most cameras a check handles (partners are a 32-bit mask per cell).
pub const MAX_CAMERAS: usize = 32;
/// Smallest agreement gain for which `refine_rotations` turns a camera: below it the change is
/// within what depth errors and occlusions move (clean cameras gain under 0.001).
pub const MIN_REFINE_GAIN: f64 = 0.0005;
/// Least agreement a camera's whole correction must be worth ([`correction_gains`]) to be
/// kept by [`keep_earned_corrections`]. Measured on three Deep360 worlds (6 frames at 256, two
/// and three passes): undoing a 1 degree knock's correction costs 0.079 to 0.103, a 0.3 degree
/// knock's 0.0087 to 0.0116; undoing the turns the refinement gave cameras that were not
/// knocked (0.06 to 0.17 degree) costs at most 0.0020. The cost grows as the square of the
/// turn (about 0.1 per square degree either way), so this keeps turns from about 0.2 degree.
pub const MIN_KEEP_GAIN: f64 = 0.004;
/// Fewest textured cells (over all frames and partners) a camera needs for a correction.
pub const MIN_TEXTURED_CELLS: usize = 500;

/// How the check samples and searches.
#[derive(Clone, Debug, PartialEq)]
pub struct RotationCheckConfig {
    /// Width of the analysis grid (height half of it).
    pub analysis_width: usize,
    /// Largest correction searched, degrees (about every rig axis).
    pub max_correction_deg: f64,
    /// First step of the pattern search, degrees.
    pub initial_step_deg: f64,
    /// The search stops when its step falls below this, degrees.
    pub min_step_deg: f64,
}

impl RotationCheckConfig {
    /// `rig refine`: fine steps (a 256-wide grid recovers a 1 degree turn to about 0.02
    /// degrees with true depth).
    pub fn refine() -> Self {
        Self {
            analysis_width: 256,
            max_correction_deg: 5.0,
            initial_step_deg: 0.5,
            min_step_deg: 0.01,
        }
    }

    /// The node's drift check: a coarser grid and search, a fraction of a frame's inference.
    pub fn drift() -> Self {
        Self {
            analysis_width: 128,
            max_correction_deg: 3.0,
            initial_step_deg: 0.5,
            min_step_deg: 0.04,
        }
    }
}

/// The best small rotation of one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraCorrection {
    /// Index in rig order.
    pub camera: usize,
    pub name: String,
    /// `w` (radians, rig axes): the camera's rotation becomes `exp([w]x) R_c`.
    pub rotation_vector_rig: Vector3<f64>,
    /// `|w|`, degrees.
    pub angle_deg: f64,
    /// Agreement `A_c` before and after (mean ZNCC, at most 1).
    pub agreement_before: f64,
    pub agreement_after: f64,
    /// Textured cells the agreement was measured on.
    pub cells: usize,
}

impl CameraCorrection {
    /// `agreement_after - agreement_before`.
    pub fn gain(&self) -> f64 {
        self.agreement_after - self.agreement_before
    }

    /// The correction as a rotation in the rig frame.
    pub fn rotation_rig(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(self.rotation_vector_rig)
    }
}
