//! The double sphere model (Usenko, Demmel and Cremers, "The Double Sphere Camera Model",
//! 3DV 2018): a point is projected onto two unit spheres whose centres are `xi` apart, then
//! onto a pinhole shifted by `alpha / (1 - alpha)`.
//!
//! ```text
//! d1 = |p|,  d2 = sqrt(x^2 + y^2 + (xi d1 + z)^2)
//! u  = fx x / (alpha d2 + (1 - alpha)(xi d1 + z)) + cx        (v likewise with fy, y, cy)
//! valid if z > -w2 d1,   w2 = (w1 + xi) / sqrt(2 w1 xi + xi^2 + 1),
//!                        w1 = alpha / (1 - alpha) if alpha <= 0.5, else (1 - alpha) / alpha
//! ```
//!
//! Unprojection, with `mx = (u - cx) / fx`, `my = (v - cy) / fy`, `r^2 = mx^2 + my^2`:
//!
//! ```text
//! mz  = (1 - alpha^2 r^2) / (alpha sqrt(1 - (2 alpha - 1) r^2) + 1 - alpha)
//! dir = (mz xi + sqrt(mz^2 + (1 - xi^2) r^2)) / (mz^2 + r^2) * (mx, my, mz) - (0, 0, xi)
//! valid if alpha <= 0.5 or r^2 <= 1 / (2 alpha - 1)
//! ```

use super::{in_range, Focal, IntrinsicsError};
use crate::geometry::erp::PixelCoord;
use nalgebra::{Unit, Vector3};

/// `xi` must lie in `[XI_MIN, XI_MAX]` (the paper's range).
pub const XI_MIN: f64 = -1.0;
pub const XI_MAX: f64 = 1.0;

/// A double-sphere lens: `fx fy cx cy xi alpha`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DoubleSphere {
    focal: Focal,
    xi: f64,
    alpha: f64,
    /// `w2` of the validity condition `z > -w2 |p|`.
    w2: f64,
}

impl DoubleSphere {
    /// The name in the rig YAML.
    pub const NAME: &'static str = "double_sphere";

    /// `xi` in `[-1, 1]`, `alpha` in `[0, 1]`.
    pub fn new(focal: Focal, xi: f64, alpha: f64) -> Result<Self, IntrinsicsError> {
        let xi = in_range("xi", xi, XI_MIN, XI_MAX)?;
        let alpha = in_range("alpha", alpha, 0.0, 1.0)?;
        let w1 = if alpha <= 0.5 {
            alpha / (1.0 - alpha)
        } else {
            (1.0 - alpha) / alpha
        };
        let w2 = (w1 + xi) / (2.0 * w1 * xi + xi * xi + 1.0).sqrt();
        Ok(Self {
            focal,
            xi,
            alpha,
            w2,
        })
    }

    pub fn focal(&self) -> Focal {
        self.focal
    }

    pub fn xi(&self) -> f64 {
        self.xi
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Whether `p` lies in the projection's valid region `z > -w2 |p|` (and is not zero).
    pub fn is_valid_point(&self, p: &Vector3<f64>) -> bool {
        let d1 = p.norm();
        d1 > 0.0 && d1.is_finite() && p.z > -self.w2 * d1
    }

    /// See the module docs; `None` outside the valid region.
    pub fn project(&self, p: &Vector3<f64>) -> Option<PixelCoord> {
        if !self.is_valid_point(p) {
            return None;
        }
        let d1 = p.norm();
        let zs = self.xi * d1 + p.z;
        let d2 = (p.x * p.x + p.y * p.y + zs * zs).sqrt();
        let denom = self.alpha * d2 + (1.0 - self.alpha) * zs;
        if denom <= 0.0 {
            return None;
        }
        Some(self.focal.pixel(p.x / denom, p.y / denom))
    }

    /// See the module docs; `None` outside the unprojection region or when the ray found is
    /// not one the model projects (so `project(unproject(px)) == px` wherever it is `Some`).
    pub fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        let (mx, my) = self.focal.normalized(px);
        let r2 = mx * mx + my * my;
        let a = self.alpha;
        let k = 1.0 - (2.0 * a - 1.0) * r2;
        if k < 0.0 || !r2.is_finite() {
            return None;
        }
        let mz = (1.0 - a * a * r2) / (a * k.sqrt() + 1.0 - a);
        let s = (mz * mz + (1.0 - self.xi * self.xi) * r2).sqrt();
        let scale = (mz * self.xi + s) / (mz * mz + r2);
        let dir = Vector3::new(scale * mx, scale * my, scale * mz - self.xi);
        if !self.is_valid_point(&dir) {
            return None;
        }
        Some(Unit::new_normalize(dir))
    }
}
