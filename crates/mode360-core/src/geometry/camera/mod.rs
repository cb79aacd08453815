//! Camera models: where a camera-frame point lands in the image, and which ray a pixel sees.
//!
//! Pure geometry, free of tensors and ROS. Pixel coordinates are continuous with integer
//! values at pixel centres ([`PixelCoord`]): the top-left pixel's centre is `(0, 0)`, its
//! outer corner `(-0.5, -0.5)` (the convention of Kalibr, Basalt and OpenCV). A pixel is in
//! an image of `W x H` when `-0.5 <= u <= W - 0.5` and `-0.5 <= v <= H - 0.5`.
//!
//! Frames: the fisheye models project points in the lens's **optical frame** (z along the
//! optical axis, x to the image's right, y down), as Kalibr and Basalt calibrate them. The
//! equirectangular model uses the REP 103-like panorama frame of [`super::erp`] (x at the centre
//! column, y left, z up).
//!
//! * [`DoubleSphere`] (Usenko et al. 2018), [`Eucm`] (extended unified model, same paper),
//!   [`KannalaBrandt`] (equidistant with `k1..k4`, Kannala and Brandt 2006): one lens each,
//!   gathered in [`FisheyeLens`] and bounded by an image in [`FisheyeCamera`].
//! * [`DualFisheye`]: two lenses back to back in one image, left half and right half.
//! * [`ErpGrid`] implements [`CameraModel`] too (a full sphere, every direction seen).
//!
//! Every model answers `None` for what it does not see: a point outside its field of view
//! or off the image, a pixel outside the image or outside the region its model can unproject.
//! Nothing is wrapped or clamped.

mod double_sphere;
mod dual_fisheye;
mod eucm;
mod kannala_brandt;
mod scale;

pub use double_sphere::DoubleSphere;
pub use dual_fisheye::{DualFisheye, DualLens, Ray, DUAL_FISHEYE_LENSES};
pub use eucm::Eucm;
pub use kannala_brandt::KannalaBrandt;
pub use scale::MAX_SCALE_FACTOR;

use super::erp::{ErpGrid, PixelCoord};
use nalgebra::{Unit, Vector3};

/// A pixel-space extent below this is not an image.
pub const MIN_IMAGE_SIDE_PX: u32 = 2;

/// An intrinsic parameter that does not describe a camera: names the parameter (`fx`, `xi`,
/// `cx`, ...) as the rig YAML and the calibration tools spell it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{field}: {problem}")]
pub struct IntrinsicsError {
    pub field: String,
    pub problem: String,
}

impl IntrinsicsError {
    pub fn new(field: impl Into<String>, problem: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            problem: problem.into(),
        }
    }

    /// The same error with `prefix` before the field (`lenses[1].intrinsics.` + `cx`).
    pub fn prefixed(self, prefix: &str) -> Self {
        Self {
            field: format!("{prefix}{}", self.field),
            problem: self.problem,
        }
    }
}

/// Largest image side a camera may have, pixels (a 16K sensor side; more would only exhaust
/// memory).
pub const MAX_IMAGE_SIDE_PX: u32 = 16_384;

/// Image size in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ImageSize {
    pub width: u32,
    pub height: u32,
}

impl ImageSize {
    /// Both sides at least [`MIN_IMAGE_SIDE_PX`] and at most [`MAX_IMAGE_SIDE_PX`] (checked
    /// before anything is allocated for the image); the error names `image_size`.
    pub fn new(width: u32, height: u32) -> Result<Self, IntrinsicsError> {
        if width < MIN_IMAGE_SIDE_PX || height < MIN_IMAGE_SIDE_PX {
            return Err(IntrinsicsError::new(
                "image_size",
                format!("{width} x {height} is not an image (each side at least {MIN_IMAGE_SIDE_PX} px)"),
            ));
        }
        if width > MAX_IMAGE_SIDE_PX || height > MAX_IMAGE_SIDE_PX {
            return Err(IntrinsicsError::new(
                "image_size",
                format!("{width} x {height} is larger than any camera's (each side at most {MAX_IMAGE_SIDE_PX} px)"),
            ));
        }
        Ok(Self { width, height })
    }

    /// `-0.5 <= u <= W - 0.5` and `-0.5 <= v <= H - 0.5`.
    pub fn contains(&self, p: PixelCoord) -> bool {
        p.u >= -0.5
            && p.u <= self.width as f64 - 0.5
            && p.v >= -0.5
            && p.v <= self.height as f64 - 0.5
    }
}

/// Focal lengths and principal point in pixels: the linear part every fisheye model shares,
/// `u = fx * mx + cx`, `v = fy * my + cy`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Focal {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Focal {
    /// Finite values and positive focal lengths.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Self, IntrinsicsError> {
        for (name, v) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
            finite(name, v)?;
        }
        for (name, v) in [("fx", fx), ("fy", fy)] {
            if v <= 0.0 {
                return Err(IntrinsicsError::new(
                    name,
                    format!("focal length {v} must be positive"),
                ));
            }
        }
        Ok(Self { fx, fy, cx, cy })
    }

    /// `(u, v) = (fx mx + cx, fy my + cy)`.
    pub fn pixel(&self, mx: f64, my: f64) -> PixelCoord {
        PixelCoord {
            u: self.fx * mx + self.cx,
            v: self.fy * my + self.cy,
        }
    }

    /// `(mx, my) = ((u - cx) / fx, (v - cy) / fy)`.
    pub fn normalized(&self, p: PixelCoord) -> (f64, f64) {
        ((p.u - self.cx) / self.fx, (p.v - self.cy) / self.fy)
    }
}

/// `Err` naming `field` unless `v` is finite.
pub(crate) fn finite(field: &str, v: f64) -> Result<f64, IntrinsicsError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(IntrinsicsError::new(
            field,
            format!("value {v} is not finite"),
        ))
    }
}

/// `Err` naming `field` unless `lo <= v <= hi` (and finite).
pub(crate) fn in_range(field: &str, v: f64, lo: f64, hi: f64) -> Result<f64, IntrinsicsError> {
    finite(field, v)?;
    if v < lo || v > hi {
        return Err(IntrinsicsError::new(
            field,
            format!("{v} is outside the model's valid range [{lo}, {hi}]"),
        ));
    }
    Ok(v)
}

/// A camera: projects camera-frame points to pixels and pixels back to unit rays. Models are
/// plain data, shared freely between threads (sampling tables are built in parallel).
pub trait CameraModel: Send + Sync {
    /// The image this model draws into.
    fn image_size(&self) -> ImageSize;
    /// The pixel that sees `p_cam` (any non-zero length), or `None` when the point is outside
    /// the field of view, off the image, or the zero vector.
    fn project(&self, p_cam: &Vector3<f64>) -> Option<PixelCoord>;
    /// The unit ray (camera frame) a pixel sees, or `None` when the pixel is off the image or
    /// outside the region the model can unproject.
    fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>>;
}

/// The model of one fisheye lens, without an image bound. Pixels are in the image the lens
/// draws into (so a dual-fisheye lens's principal point is in full-image coordinates).
#[derive(Clone, Debug, PartialEq)]
pub enum FisheyeLens {
    DoubleSphere(DoubleSphere),
    KannalaBrandt(KannalaBrandt),
    Eucm(Eucm),
}

impl FisheyeLens {
    /// The model's name in the rig YAML: `double_sphere`, `kannala_brandt` or `eucm`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::DoubleSphere(_) => DoubleSphere::NAME,
            Self::KannalaBrandt(_) => KannalaBrandt::NAME,
            Self::Eucm(_) => Eucm::NAME,
        }
    }

    pub fn focal(&self) -> Focal {
        match self {
            Self::DoubleSphere(m) => m.focal(),
            Self::KannalaBrandt(m) => m.focal(),
            Self::Eucm(m) => m.focal(),
        }
    }

    /// The pixel of an optical-frame point, `None` outside the model's valid region (its
    /// field of view). No image bound is applied.
    pub fn project(&self, p: &Vector3<f64>) -> Option<PixelCoord> {
        match self {
            Self::DoubleSphere(m) => m.project(p),
            Self::KannalaBrandt(m) => m.project(p),
            Self::Eucm(m) => m.project(p),
        }
    }

    /// The optical-frame unit ray of a pixel, `None` outside the model's unprojection region.
    /// No image bound is applied.
    pub fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        match self {
            Self::DoubleSphere(m) => m.unproject(px),
            Self::KannalaBrandt(m) => m.unproject(px),
            Self::Eucm(m) => m.unproject(px),
        }
    }
}

/// One fisheye lens filling one image.
#[derive(Clone, Debug, PartialEq)]
pub struct FisheyeCamera {
    lens: FisheyeLens,
    size: ImageSize,
}

impl FisheyeCamera {
    /// The principal point must lie in the image (`-0.5 <= cx <= W - 0.5`, likewise `cy`):
    /// intrinsics that put it elsewhere do not describe this image.
    pub fn new(lens: FisheyeLens, size: ImageSize) -> Result<Self, IntrinsicsError> {
        principal_point_within(&lens.focal(), -0.5, size.width as f64 - 0.5, size)?;
        Ok(Self { lens, size })
    }

    pub fn lens(&self) -> &FisheyeLens {
        &self.lens
    }
}

/// `Err` naming `cx` or `cy` unless `u_lo <= cx <= u_hi` and `-0.5 <= cy <= H - 0.5`.
pub(crate) fn principal_point_within(
    f: &Focal,
    u_lo: f64,
    u_hi: f64,
    size: ImageSize,
) -> Result<(), IntrinsicsError> {
    if f.cx < u_lo || f.cx > u_hi {
        return Err(IntrinsicsError::new(
            "cx",
            format!(
                "principal point column {} is outside the image (columns {u_lo} to {u_hi} of a {} x {} image)",
                f.cx, size.width, size.height
            ),
        ));
    }
    let v_hi = size.height as f64 - 0.5;
    if f.cy < -0.5 || f.cy > v_hi {
        return Err(IntrinsicsError::new(
            "cy",
            format!(
                "principal point row {} is outside the image (rows -0.5 to {v_hi} of a {} x {} image)",
                f.cy, size.width, size.height
            ),
        ));
    }
    Ok(())
}

impl CameraModel for FisheyeCamera {
    fn image_size(&self) -> ImageSize {
        self.size
    }

    fn project(&self, p_cam: &Vector3<f64>) -> Option<PixelCoord> {
        self.lens
            .project(p_cam)
            .filter(|px| self.size.contains(*px))
    }

    fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        if !self.size.contains(px) {
            return None;
        }
        self.lens.unproject(px)
    }
}

/// The full sphere: every non-zero direction lands on the image, `u` in `[-0.5, W - 0.5)`.
impl CameraModel for ErpGrid {
    fn image_size(&self) -> ImageSize {
        ImageSize {
            width: self.width() as u32,
            height: self.height() as u32,
        }
    }

    fn project(&self, p_cam: &Vector3<f64>) -> Option<PixelCoord> {
        if *p_cam == Vector3::zeros() || !p_cam.iter().all(|c| c.is_finite()) {
            return None;
        }
        Some(self.pixel_from_dir(p_cam))
    }

    fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        if !self.image_size().contains(px) {
            return None;
        }
        Some(Unit::new_normalize(self.dir_from_pixel(px)))
    }
}
