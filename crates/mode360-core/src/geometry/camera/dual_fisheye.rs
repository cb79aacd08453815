//! Two fisheye lenses back to back in one image (Ricoh Theta, Insta360 and similar raw
//! frames): lens 0 draws into the left half of the image, lens 1 into the right half.
//!
//! Each lens has its own model ([`FisheyeLens`], any of the fisheye models) with its principal
//! point in **full-image** pixel coordinates (so lens 1's `cx` is about `3 W / 4`), and its
//! pose `cam_from_lens` (`p_cam = R p_lens + t`) from its optical frame to the camera's frame.
//!
//! ```text
//! project(p_cam):  for each lens i, p_i = lens_from_cam_i p_cam, px_i = lens_i(p_i);
//!                  keep px_i if it falls in lens i's half; of those keep the lens whose
//!                  optical axis is nearest the point (largest z_i / |p_i|)
//! unproject(px):   the lens whose half holds px; dir = R_i lens_i^-1(px)
//! ```
//!
//! Halves: lens 0 owns columns `-0.5 <= u < W/2 - 0.5`, lens 1 owns `W/2 - 0.5 <= u <= W - 0.5`.
//! A ray of lens i starts at its centre `t_i`; with the lenses a few centimetres apart,
//! [`CameraModel::unproject`] gives its direction and [`DualFisheye::unproject_ray`] the ray.

use super::{principal_point_within, CameraModel, FisheyeLens, ImageSize, IntrinsicsError};
use crate::geometry::erp::PixelCoord;
use nalgebra::{Isometry3, Point3, Unit, Vector3};

/// A dual-fisheye image holds exactly this many lenses.
pub const DUAL_FISHEYE_LENSES: usize = 2;

/// One lens of a dual-fisheye camera.
#[derive(Clone, Debug, PartialEq)]
pub struct DualLens {
    pub model: FisheyeLens,
    /// `p_cam = cam_from_lens * p_lens`.
    pub cam_from_lens: Isometry3<f64>,
}

/// A ray: origin and unit direction, both in the camera frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Point3<f64>,
    pub dir: Unit<Vector3<f64>>,
}

/// Two lenses in the left and right halves of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct DualFisheye {
    lenses: [DualLens; DUAL_FISHEYE_LENSES],
    size: ImageSize,
}

impl DualFisheye {
    /// The name in the rig YAML.
    pub const NAME: &'static str = "dual_fisheye";

    /// The image width must be even; each lens's principal point must lie in its own half.
    /// Errors name `image_size` or `lenses[i].intrinsics.cx|cy`.
    pub fn new(
        lenses: [DualLens; DUAL_FISHEYE_LENSES],
        size: ImageSize,
    ) -> Result<Self, IntrinsicsError> {
        if !size.width.is_multiple_of(2) {
            return Err(IntrinsicsError::new(
                "image_size",
                format!("width {} must be even: each lens has one half", size.width),
            ));
        }
        let m = Self { lenses, size };
        for (i, lens) in m.lenses.iter().enumerate() {
            let (lo, hi) = m.half_columns(i);
            principal_point_within(&lens.model.focal(), lo, hi, size)
                .map_err(|e| e.prefixed(&format!("lenses[{i}].intrinsics.")))?;
        }
        Ok(m)
    }

    pub fn lenses(&self) -> &[DualLens; DUAL_FISHEYE_LENSES] {
        &self.lenses
    }

    /// Columns `[lo, hi]` of lens `i`'s half (`hi` exclusive for lens 0).
    fn half_columns(&self, i: usize) -> (f64, f64) {
        let mid = self.size.width as f64 / 2.0 - 0.5;
        if i == 0 {
            (-0.5, mid)
        } else {
            (mid, self.size.width as f64 - 0.5)
        }
    }

    /// The lens whose half holds `px`, or `None` off the image.
    pub fn lens_of_pixel(&self, px: PixelCoord) -> Option<usize> {
        if !self.size.contains(px) {
            return None;
        }
        Some(if px.u < self.half_columns(1).0 { 0 } else { 1 })
    }

    /// The ray pixel `px` sees: from lens `i`'s centre along its unprojected direction.
    pub fn unproject_ray(&self, px: PixelCoord) -> Option<Ray> {
        let i = self.lens_of_pixel(px)?;
        let lens = &self.lenses[i];
        let dir_lens = lens.model.unproject(px)?;
        Some(Ray {
            origin: Point3::from(lens.cam_from_lens.translation.vector),
            dir: Unit::new_unchecked(lens.cam_from_lens.rotation * dir_lens.into_inner()),
        })
    }
}

impl CameraModel for DualFisheye {
    fn image_size(&self) -> ImageSize {
        self.size
    }

    fn project(&self, p_cam: &Vector3<f64>) -> Option<PixelCoord> {
        let mut best: Option<(f64, PixelCoord)> = None;
        for (i, lens) in self.lenses.iter().enumerate() {
            let p = lens
                .cam_from_lens
                .inverse_transform_point(&Point3::from(*p_cam))
                .coords;
            let norm = p.norm();
            if norm == 0.0 {
                continue;
            }
            let Some(px) = lens.model.project(&p) else {
                continue;
            };
            if self.lens_of_pixel(px) != Some(i) {
                continue;
            }
            let cos_axis = p.z / norm;
            if best.is_none_or(|(c, _)| cos_axis > c) {
                best = Some((cos_axis, px));
            }
        }
        best.map(|(_, px)| px)
    }

    fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        self.unproject_ray(px).map(|r| r.dir)
    }
}
