//! The extended unified camera model (Khomutenko, Garcia and Martinet 2016, in the form of
//! Usenko, Demmel and Cremers, "The Double Sphere Camera Model", 3DV 2018):
//!
//! ```text
//! d = sqrt(beta (x^2 + y^2) + z^2)
//! u = fx x / (alpha d + (1 - alpha) z) + cx                    (v likewise with fy, y, cy)
//! valid if z > -w d,  w = alpha / (1 - alpha) if alpha <= 0.5, else (1 - alpha) / alpha
//! ```
//!
//! Unprojection, with `mx = (u - cx) / fx`, `my = (v - cy) / fy`, `r^2 = mx^2 + my^2`:
//!
//! ```text
//! mz  = (1 - beta alpha^2 r^2) / (alpha sqrt(1 - (2 alpha - 1) beta r^2) + 1 - alpha)
//! dir = (mx, my, mz) / |(mx, my, mz)|
//! valid if alpha <= 0.5 or r^2 <= 1 / (beta (2 alpha - 1))
//! ```
//!
//! `alpha = 0` is the pinhole camera; `beta = 1` is the unified model (Mei's `xi` with
//! `alpha = xi / (1 + xi)` and focal lengths divided by `1 + xi`).

use super::{finite, in_range, Focal, IntrinsicsError};
use crate::geometry::erp::PixelCoord;
use nalgebra::{Unit, Vector3};

/// An EUCM lens: `fx fy cx cy alpha beta`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eucm {
    focal: Focal,
    alpha: f64,
    beta: f64,
    /// `w` of the validity condition `z > -w d`.
    w: f64,
}

impl Eucm {
    /// The name in the rig YAML.
    pub const NAME: &'static str = "eucm";

    /// `alpha` in `[0, 1]`, `beta > 0`.
    pub fn new(focal: Focal, alpha: f64, beta: f64) -> Result<Self, IntrinsicsError> {
        let alpha = in_range("alpha", alpha, 0.0, 1.0)?;
        let beta = finite("beta", beta)?;
        if beta <= 0.0 {
            return Err(IntrinsicsError::new(
                "beta",
                format!("{beta} must be positive"),
            ));
        }
        let w = if alpha <= 0.5 {
            alpha / (1.0 - alpha)
        } else {
            (1.0 - alpha) / alpha
        };
        Ok(Self {
            focal,
            alpha,
            beta,
            w,
        })
    }

    pub fn focal(&self) -> Focal {
        self.focal
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    pub fn beta(&self) -> f64 {
        self.beta
    }

    fn d(&self, p: &Vector3<f64>) -> f64 {
        (self.beta * (p.x * p.x + p.y * p.y) + p.z * p.z).sqrt()
    }

    /// Whether `p` lies in the projection's valid region `z > -w d` (and is not zero).
    pub fn is_valid_point(&self, p: &Vector3<f64>) -> bool {
        let d = self.d(p);
        d > 0.0 && d.is_finite() && p.z > -self.w * d
    }

    /// See the module docs; `None` outside the valid region.
    pub fn project(&self, p: &Vector3<f64>) -> Option<PixelCoord> {
        if !self.is_valid_point(p) {
            return None;
        }
        let denom = self.alpha * self.d(p) + (1.0 - self.alpha) * p.z;
        if denom <= 0.0 {
            return None;
        }
        Some(self.focal.pixel(p.x / denom, p.y / denom))
    }

    /// See the module docs; `None` outside the unprojection region.
    pub fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        let (mx, my) = self.focal.normalized(px);
        let r2 = mx * mx + my * my;
        let a = self.alpha;
        let k = 1.0 - (2.0 * a - 1.0) * self.beta * r2;
        if k < 0.0 || !r2.is_finite() {
            return None;
        }
        let mz = (1.0 - self.beta * a * a * r2) / (a * k.sqrt() + 1.0 - a);
        let dir = Vector3::new(mx, my, mz);
        if !self.is_valid_point(&dir) {
            return None;
        }
        Some(Unit::new_normalize(dir))
    }
}
