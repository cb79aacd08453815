//! Calibration drift on a running rig: every few frames, a quick estimate
//! ([`RotationCheck::quick_corrections`]) of the rotation that would make each camera agree
//! best with the others at the estimated depth, and over the newest checks, per camera, the
//! median of its size. A knocked camera is the one whose correction raises the agreement most
//! (the others are pulled a little towards it); the node warns when that camera's correction
//! passes its `calibration_warn_deg` parameter.

use std::collections::VecDeque;

use super::calibration::{CameraCorrection, CheckFrame, RotationCheck, RotationCheckConfig};
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::Rig;
use mode360_estimator::lens_mask::LensMask;
use mode360_estimator::EstimatorError;

/// Frames between two checks (the first complete frame is checked).
pub const DRIFT_CHECK_EVERY: usize = 3;
/// Checks the median is taken over.
pub const DRIFT_WINDOW_CHECKS: usize = 3;
/// Newton steps of a quick check.
pub const DRIFT_NEWTON_STEPS: usize = 2;
/// Difference step of a quick check, degrees.
pub const DRIFT_STEP_DEG: f64 = 0.25;
/// Narrowest camera image the check runs on, pixels: at 128 wide a pixel is 2.8 degrees, and
/// depth that coarse turns a correct camera by up to 0.9 degree (measured), so such rigs are
/// not checked.
pub const DRIFT_MIN_IMAGE_WIDTH: u32 = 256;
/// Smallest median agreement gain of the suspect camera: a knocked camera gains 0.03 or more
/// (1 degree, 256 and 512 wide), a correct one under 0.002.
pub const DRIFT_MIN_GAIN: f64 = 0.005;

/// One camera's calibration as the newest checks see it.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationDrift {
    pub camera: usize,
    pub name: String,
    /// Median over the window of the correction's size, degrees.
    pub correction_deg: f64,
    /// Median over the window of the agreement the correction gains.
    pub gain: f64,
    /// Whether this camera gains the most, and at least [`DRIFT_MIN_GAIN`] (the one a warning
    /// may name).
    pub suspect: bool,
}

/// The drift check over the newest frames of one rig.
#[derive(Clone, Debug)]
pub struct CalibrationDriftMonitor {
    check: RotationCheck,
    every: usize,
    frames_seen: usize,
    checks: VecDeque<Vec<CameraCorrection>>,
}

impl CalibrationDriftMonitor {
    pub fn new(rig: &Rig) -> Result<Self, EstimatorError> {
        Ok(Self {
            check: RotationCheck::new(rig, RotationCheckConfig::drift())?,
            every: DRIFT_CHECK_EVERY,
            frames_seen: 0,
            checks: VecDeque::new(),
        })
    }

    /// Takes one complete frame (`images` in rig order, `range_m` its estimated range, `masks`
    /// the lens check's masks, whose blocked parts the check leaves out); every
    /// [`DRIFT_CHECK_EVERY`] frames it runs a check, unless an image is narrower than
    /// [`DRIFT_MIN_IMAGE_WIDTH`]. Returns whether it did.
    pub fn add(
        &mut self,
        images: &[RgbImage],
        range_m: &FloatImage,
        masks: &[Option<LensMask>],
    ) -> Result<bool, EstimatorError> {
        if images.iter().any(|img| img.width() < DRIFT_MIN_IMAGE_WIDTH) {
            return Ok(false);
        }
        let due = self.frames_seen.is_multiple_of(self.every);
        self.frames_seen += 1;
        if !due {
            return Ok(false);
        }
        let mut frame: CheckFrame = self.check.frame(images, range_m)?;
        frame.mask_lenses(masks);
        let corrections = self.check.quick_corrections(
            std::slice::from_ref(&frame),
            DRIFT_NEWTON_STEPS,
            DRIFT_STEP_DEG,
        )?;
        if self.checks.len() == DRIFT_WINDOW_CHECKS {
            self.checks.pop_front();
        }
        self.checks.push_back(corrections);
        Ok(true)
    }

    /// Each camera's drift over the window (empty before the first check).
    pub fn drift(&self) -> Vec<CalibrationDrift> {
        let Some(first) = self.checks.front() else {
            return Vec::new();
        };
        let median = |mut v: Vec<f64>| -> f64 {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let mut out: Vec<CalibrationDrift> = first
            .iter()
            .map(|c| {
                let of = |f: fn(&CameraCorrection) -> f64| {
                    median(
                        self.checks
                            .iter()
                            .filter_map(|check| check.get(c.camera).map(f))
                            .collect(),
                    )
                };
                CalibrationDrift {
                    camera: c.camera,
                    name: c.name.clone(),
                    correction_deg: of(|x| x.angle_deg),
                    gain: of(CameraCorrection::gain),
                    suspect: false,
                }
            })
            .collect();
        if let Some(best) = out
            .iter_mut()
            .max_by(|a, b| a.gain.total_cmp(&b.gain))
            .filter(|best| best.gain >= DRIFT_MIN_GAIN)
        {
            best.suspect = true;
        }
        out
    }
}
