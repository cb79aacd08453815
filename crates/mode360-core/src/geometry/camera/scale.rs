//! The same camera at another image resolution (for rendering or training fisheye rigs at a
//! lower resolution than they were calibrated at).
//!
//! Scaling an image by `s_u` across and `s_v` down maps a continuous pixel coordinate (pixel
//! centres at integers, see [`super`]) as `u' = s_u (u + 0.5) - 0.5`, so the focal lengths
//! scale (`fx' = s_u fx`) and the principal point moves (`cx' = s_u (cx + 0.5) - 0.5`). The
//! other parameters (`xi`, `alpha`, `beta`, `k1..k4`) act on normalized or angular
//! coordinates and stay. New sides are rounded to whole pixels (a dual-fisheye width to an
//! even number), and `s_u`, `s_v` are the exact ratios of the new sides to the old.

use super::{
    DoubleSphere, DualFisheye, DualLens, Eucm, FisheyeCamera, FisheyeLens, Focal, ImageSize,
    IntrinsicsError, KannalaBrandt,
};

/// A resolution factor must lie in `(0, MAX_SCALE_FACTOR]`.
pub const MAX_SCALE_FACTOR: f64 = 16.0;

fn check_factor(factor: f64) -> Result<(), IntrinsicsError> {
    if !factor.is_finite() || factor <= 0.0 || factor > MAX_SCALE_FACTOR {
        return Err(IntrinsicsError::new(
            "image_size",
            format!("scale factor {factor} must be in (0, {MAX_SCALE_FACTOR}]"),
        ));
    }
    Ok(())
}

/// `side * factor` rounded to a multiple of `multiple` (at least one multiple).
fn scaled_side(side: u32, factor: f64, multiple: u32) -> u32 {
    let units = (side as f64 * factor / multiple as f64).round().max(1.0);
    units as u32 * multiple
}

/// `size` scaled by `factor`, the width a multiple of `width_multiple`; the exact ratios.
fn scaled_size(
    size: ImageSize,
    factor: f64,
    width_multiple: u32,
) -> Result<(ImageSize, f64, f64), IntrinsicsError> {
    check_factor(factor)?;
    let new = ImageSize::new(
        scaled_side(size.width, factor, width_multiple),
        scaled_side(size.height, factor, 1),
    )?;
    let s_u = new.width as f64 / size.width as f64;
    let s_v = new.height as f64 / size.height as f64;
    Ok((new, s_u, s_v))
}

impl Focal {
    /// The focal lengths and principal point of the image scaled by `s_u` across, `s_v` down.
    pub fn scaled(&self, s_u: f64, s_v: f64) -> Result<Self, IntrinsicsError> {
        Focal::new(
            self.fx * s_u,
            self.fy * s_v,
            s_u * (self.cx + 0.5) - 0.5,
            s_v * (self.cy + 0.5) - 0.5,
        )
    }
}

impl FisheyeLens {
    /// The same lens drawing into an image scaled by `s_u` across and `s_v` down.
    pub fn scaled(&self, s_u: f64, s_v: f64) -> Result<Self, IntrinsicsError> {
        let focal = self.focal().scaled(s_u, s_v)?;
        Ok(match self {
            Self::DoubleSphere(m) => {
                Self::DoubleSphere(DoubleSphere::new(focal, m.xi(), m.alpha())?)
            }
            Self::KannalaBrandt(m) => {
                Self::KannalaBrandt(KannalaBrandt::new(focal, m.coefficients())?)
            }
            Self::Eucm(m) => Self::Eucm(Eucm::new(focal, m.alpha(), m.beta())?),
        })
    }
}

impl FisheyeCamera {
    /// The camera at `factor` times its resolution (0.5: half the width and height).
    pub fn scaled(&self, factor: f64) -> Result<Self, IntrinsicsError> {
        let (size, s_u, s_v) = scaled_size(self.size, factor, 1)?;
        FisheyeCamera::new(self.lens.scaled(s_u, s_v)?, size)
    }
}

impl DualFisheye {
    /// The camera at `factor` times its resolution; the width stays even.
    pub fn scaled(&self, factor: f64) -> Result<Self, IntrinsicsError> {
        use super::CameraModel;
        let (size, s_u, s_v) = scaled_size(self.image_size(), factor, 2)?;
        let [a, b] = self.lenses();
        let lens = |l: &DualLens, i: usize| -> Result<DualLens, IntrinsicsError> {
            Ok(DualLens {
                model: l
                    .model
                    .scaled(s_u, s_v)
                    .map_err(|e| e.prefixed(&format!("lenses[{i}].intrinsics.")))?,
                cam_from_lens: l.cam_from_lens,
            })
        };
        DualFisheye::new([lens(a, 0)?, lens(b, 1)?], size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::camera::CameraModel;
    use crate::geometry::PixelCoord;
    use nalgebra::Vector3;

    fn camera() -> FisheyeCamera {
        let focal = Focal::new(88.5, 88.5, 191.5, 191.5).unwrap();
        let lens = FisheyeLens::DoubleSphere(DoubleSphere::new(focal, -0.2, 0.6).unwrap());
        FisheyeCamera::new(lens, ImageSize::new(384, 384).unwrap()).unwrap()
    }

    #[test]
    fn half_resolution_maps_pixels_to_half_coordinates() {
        let cam = camera();
        let half = cam.scaled(0.5).unwrap();
        assert_eq!(half.image_size(), ImageSize::new(192, 192).unwrap());
        let f = half.lens().focal();
        assert_eq!((f.fx, f.cx), (44.25, 95.5));
        for p in [
            Vector3::new(0.3, -0.2, 1.0),
            Vector3::new(1.0, 0.5, -0.2),
            Vector3::new(-0.7, 0.9, 0.1),
        ] {
            let a = cam.project(&p).unwrap();
            let b = half.project(&p).unwrap();
            assert!((0.5 * (a.u + 0.5) - 0.5 - b.u).abs() < 1e-9, "{a:?} {b:?}");
            assert!((0.5 * (a.v + 0.5) - 0.5 - b.v).abs() < 1e-9, "{a:?} {b:?}");
        }
        // The image centre still looks along the optical axis.
        let axis = half.unproject(PixelCoord { u: 95.5, v: 95.5 }).unwrap();
        assert!((axis.z - 1.0).abs() < 1e-12);
    }

    #[test]
    fn bad_factors_are_refused() {
        for f in [0.0, -1.0, f64::NAN, 100.0] {
            let e = camera().scaled(f).unwrap_err();
            assert_eq!(e.field, "image_size");
        }
        // 384 x 0.001 rounds to 0 pixels: no image.
        assert!(camera().scaled(0.001).is_err());
    }
}
