//! [`LensGuard`]: runs an estimator with the lens masks of the frames before and keeps the
//! lens check's window (the node's and replay's lens health, eval's masks).

use super::lens_health::{lens_votes, LensHealth};
use super::lens_window::LensHealthWindow;
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::{ErpGrid, Rig};
use mode360_estimator::lens_mask::LensMask;
use mode360_estimator::{DepthEstimate, DepthEstimator, EstimatorError};

/// Runs an estimator on complete groups with the lens masks of the frames before, and keeps the
/// lens check's window (the node's and replay's lens health, eval's masks).
#[derive(Debug)]
pub struct LensGuard {
    window: LensHealthWindow,
    masks: Vec<Option<LensMask>>,
    /// Whether the estimator gets the masks (the check runs either way).
    masking: bool,
}

impl LensGuard {
    /// A guard over a window of `frames` frames; `masking` false only checks.
    pub fn new(frames: usize, masking: bool) -> Self {
        Self {
            window: LensHealthWindow::new(frames),
            masks: Vec::new(),
            masking,
        }
    }

    /// Each camera's health over the window (empty before the first frame).
    pub fn health(&self) -> Vec<LensHealth> {
        self.window.health()
    }

    /// Each camera's current mask (empty before the first frame or without masking).
    pub fn masks(&self) -> &[Option<LensMask>] {
        &self.masks
    }

    /// Estimates a complete group (`images` of every camera of `rig`), with the masks found so
    /// far, then checks the lenses on the estimate. On the first frame, when the check finds a
    /// blocked lens, the frame is estimated again with its mask rather than a frame late.
    pub fn estimate(
        &mut self,
        estimator: &mut dyn DepthEstimator,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        let first = !self.has_checked();
        let mut estimate = self.estimate_masked(estimator, rig, images, output)?;
        let changed = self.check(rig, images, &estimate.range_m)?;
        if changed && first && self.masks.iter().any(Option::is_some) {
            estimator.set_lens_masks(&self.masks);
            estimate = estimator.estimate(rig, images, output)?;
        }
        Ok(estimate)
    }

    /// Estimates with the masks the check has found so far, leaving this frame's check to
    /// [`Self::check`] (the node runs it after publishing, off the latency path).
    pub fn estimate_masked(
        &self,
        estimator: &mut dyn DepthEstimator,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        estimator.set_lens_masks(&self.masks);
        estimator.estimate(rig, images, output)
    }

    /// The lens check of one complete group: adds its votes (from the images and the range
    /// estimated from them) to the window and, when masking, renews the masks the next
    /// estimates get. Returns whether the masks changed.
    pub fn check(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        range_m: &FloatImage,
    ) -> Result<bool, EstimatorError> {
        self.window.add(rig, lens_votes(rig, images, range_m)?);
        if !self.masking {
            return Ok(false);
        }
        let masks = self.window.masks();
        if masks == self.masks {
            return Ok(false);
        }
        self.masks = masks;
        Ok(true)
    }

    /// Whether the check has seen a frame.
    pub fn has_checked(&self) -> bool {
        !self.window.is_empty()
    }

    /// Estimates without masks and without a lens check: a partial group (`rig` a subset of the
    /// cameras; the check needs every camera), or any group with the checks switched off.
    pub fn estimate_partial(
        &self,
        estimator: &mut dyn DepthEstimator,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        estimator.set_lens_masks(&[]);
        estimator.estimate(rig, images, output)
    }
}
