//! [`CheckFrame`]: one frame prepared for the calibration check.

use crate::lens_health::ranges_on;
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::panorama::RigRemap;
use mode360_core::geometry::{ErpGrid, Rig};
use mode360_estimator::lens_mask::LensMask;
use mode360_estimator::photometric::sampling::bilinear_wrapped;
use mode360_estimator::EstimatorError;
use mode360_model::matching::{luma, INTENSITY_SCALE};

/// One frame, prepared for the check: each camera's grey panorama and where it sees, and the
/// estimated range on the analysis grid.
#[derive(Clone, Debug)]
pub struct CheckFrame {
    pub(super) grey: Vec<Panorama>,
    pub(super) ranges_m: Vec<f32>,
    /// Per camera, the range estimated without it (empty: `ranges_m` for every camera).
    pub(super) ranges_without_m: Vec<Vec<f32>>,
}

impl CheckFrame {
    /// Leaves out the blocked part of each camera's view (`masks` in rig order, `None` or
    /// missing where nothing is blocked): mud agrees with nothing at any turn, and where it
    /// covers a part seen by few cameras it pulls the best turn off.
    pub fn mask_lenses(&mut self, masks: &[Option<LensMask>]) {
        for (pano, mask) in self.grey.iter_mut().zip(masks) {
            let Some(mask) = mask else { continue };
            let blocked = mask.blocked_on(pano.grid);
            let valid = pano.valid.get_or_insert_with(|| vec![1.0; blocked.len()]);
            for (v, b) in valid.iter_mut().zip(blocked) {
                if b {
                    *v = 0.0;
                }
            }
        }
    }

    /// The range camera `c` is checked at: estimated without it where that was given.
    pub(super) fn ranges_for(&self, c: usize) -> &[f32] {
        self.ranges_without_m.get(c).unwrap_or(&self.ranges_m)
    }
}

#[derive(Clone, Debug)]
pub(super) struct Panorama {
    pub(super) grid: ErpGrid,
    grey: Vec<f32>,
    /// Per panorama pixel, whether the camera sees it (`None`: everywhere).
    valid: Option<Vec<f32>>,
}

impl Panorama {
    /// Grey value at panorama pixel `[u, v]`, or `None` where the camera does not see.
    pub(super) fn sample(&self, [u, v]: [f32; 2]) -> Option<f32> {
        let (w, h) = (self.grid.width(), self.grid.height());
        if let Some(valid) = &self.valid {
            let ui = (u.round() as i64).rem_euclid(w as i64) as usize;
            let vi = (v.round() as i64).clamp(0, h as i64 - 1) as usize;
            if valid[vi * w + ui] <= 0.5 {
                return None;
            }
        }
        Some(bilinear_wrapped(&self.grey, w, h, u, v))
    }
}

impl CheckFrame {
    /// One frame of `rig` on the analysis `grid`: `images` in rig order, `range_m` the
    /// estimated range of the output frame (any ERP width; NaN or infinite ranges count as the
    /// farthest estimate).
    pub(super) fn new(
        rig: &Rig,
        grid: ErpGrid,
        images: &[RgbImage],
        range_m: &FloatImage,
    ) -> Result<Self, EstimatorError> {
        if images.len() != rig.cameras.len() {
            return Err(EstimatorError::ImageCount {
                got: images.len(),
                expected: rig.cameras.len(),
            });
        }
        let remap = RigRemap::new(rig, grid);
        let panoramas =
            remap
                .panoramas(images)
                .map_err(|(camera, e)| EstimatorError::BadImage {
                    camera,
                    problem: e.to_string(),
                })?;
        let validity = remap.validity();
        let grey = panoramas
            .iter()
            .zip(validity)
            .zip(&rig.cameras)
            .map(|((pano, valid), cam)| {
                let (w, h) = (pano.width() as usize, pano.height() as usize);
                let grid = ErpGrid::new(w).map_err(|_| EstimatorError::BadImageSize {
                    camera: cam.name.clone(),
                    width: w as u32,
                    height: h as u32,
                })?;
                let grey = pano
                    .pixels()
                    .map(|p| {
                        luma([f32::from(p[0]), f32::from(p[1]), f32::from(p[2])]) * INTENSITY_SCALE
                    })
                    .collect();
                Ok(Panorama { grid, grey, valid })
            })
            .collect::<Result<Vec<_>, EstimatorError>>()?;
        Ok(Self {
            grey,
            ranges_m: ranges_on(grid, range_m),
            ranges_without_m: Vec::new(),
        })
    }

    /// Sets, per camera (rig order), the range estimated without it.
    pub(super) fn set_ranges_without(
        &mut self,
        grid: ErpGrid,
        without_m: &[FloatImage],
    ) -> Result<(), EstimatorError> {
        if without_m.len() != self.grey.len() {
            return Err(EstimatorError::ImageCount {
                got: without_m.len(),
                expected: self.grey.len(),
            });
        }
        self.ranges_without_m = without_m.iter().map(|r| ranges_on(grid, r)).collect();
        Ok(())
    }
}
