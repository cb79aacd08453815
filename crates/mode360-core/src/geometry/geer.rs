//! Generalized epipolar equirectangular projection (GEER, paper section 3.1).
//!
//! For a camera pair (l, r) the GEER frame has its x axis along the baseline `O_r -> O_l`,
//! z along the rig's up direction made orthogonal to the baseline (the rig's forward direction
//! when the baseline is vertical) and `y = z x x`. A ray with GEER-frame direction `g` has
//!
//! ```text
//! phi   = acos(g_x / |g|)         in [0, pi]     (angle from the baseline)
//! theta = atan2(g_y, g_z)         in [-pi, pi]   (angle about the baseline, from z)
//! u = phi W / pi,   v = (theta + pi) H / (2 pi),   H = 2 W
//! ```
//!
//! (`u`, `v` here are continuous image coordinates whose pixel centres sit at `+0.5`, as in
//! the ERP module.) Both cameras of the pair see a 3D point at the same `theta`, so epipolar
//! lines are image rows. The angular disparity `d = phi_l - phi_r` gives the range from the
//! left camera by the law of sines: `rho_l = B sin(phi_r) / sin(d)`.

use super::erp::PixelCoord;
use super::GeometryError;
use nalgebra::{Matrix3, Rotation3, Vector3};
use std::f64::consts::PI;

/// Below this baseline length (metres) a pair has no usable GEER frame.
pub const MIN_BASELINE_M: f64 = 1e-9;
/// When the up direction is this close to parallel with the baseline, the rig's forward
/// direction defines GEER's z axis instead.
const PARALLEL_COS_LIMIT: f64 = 0.999_999;

/// GEER angles of a ray, radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeerAngles {
    pub phi_rad: f64,
    pub theta_rad: f64,
}

/// Angular disparity of a 3D point seen by both cameras of a pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointDisparity {
    pub phi_l_rad: f64,
    pub phi_r_rad: f64,
    /// `phi_l - phi_r`
    pub disparity_rad: f64,
    pub theta_rad: f64,
}

/// The GEER frame and image size of one camera pair, in rig coordinates.
#[derive(Clone, Debug, PartialEq)]
pub struct GeerPair {
    rig_from_geer: Rotation3<f64>,
    left_origin_rig: Vector3<f64>,
    right_origin_rig: Vector3<f64>,
    baseline_m: f64,
    width: usize,
}

impl GeerPair {
    /// GEER pair for camera centres `left_origin_rig`, `right_origin_rig` (rig frame, metres),
    /// the rig's `up_rig` direction, and a GEER image `width` columns wide (`2 width` rows).
    pub fn new(
        left_origin_rig: Vector3<f64>,
        right_origin_rig: Vector3<f64>,
        up_rig: Vector3<f64>,
        width: usize,
    ) -> Result<Self, GeometryError> {
        let baseline = left_origin_rig - right_origin_rig;
        let baseline_m = baseline.norm();
        if baseline_m.is_nan() || baseline_m <= MIN_BASELINE_M {
            return Err(GeometryError::ZeroBaseline { baseline_m });
        }
        if width == 0 {
            return Err(GeometryError::BadErpWidth { width, min: 1 });
        }
        let x = baseline / baseline_m;
        let up = up_rig.normalize();
        let z_seed = if up.dot(&x).abs() > PARALLEL_COS_LIMIT {
            // Vertical baseline: use the rig's forward direction.
            Vector3::x()
        } else {
            up
        };
        let z = (z_seed - x * z_seed.dot(&x)).normalize();
        let y = z.cross(&x);
        let rig_from_geer = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        Ok(Self {
            rig_from_geer,
            left_origin_rig,
            right_origin_rig,
            baseline_m,
            width,
        })
    }

    pub fn baseline_m(&self) -> f64 {
        self.baseline_m
    }

    pub fn width(&self) -> usize {
        self.width
    }

    /// GEER images are twice as tall as they are wide.
    pub fn height(&self) -> usize {
        2 * self.width
    }

    pub fn rig_from_geer(&self) -> &Rotation3<f64> {
        &self.rig_from_geer
    }

    /// GEER angles of a direction given in rig axes (any non-zero length).
    pub fn angles_from_dir_rig(&self, dir_rig: &Vector3<f64>) -> GeerAngles {
        let g = self.rig_from_geer.inverse_transform_vector(dir_rig);
        let n = g.norm();
        GeerAngles {
            phi_rad: (g.x / n).clamp(-1.0, 1.0).acos(),
            theta_rad: g.y.atan2(g.z),
        }
    }

    /// Unit direction in rig axes: `rig_from_geer * (cos phi, sin phi sin theta, sin phi cos theta)`.
    pub fn dir_rig_from_angles(&self, a: GeerAngles) -> Vector3<f64> {
        let (sp, cp) = a.phi_rad.sin_cos();
        let (st, ct) = a.theta_rad.sin_cos();
        self.rig_from_geer * Vector3::new(cp, sp * st, sp * ct)
    }

    /// `u = phi W / pi - 0.5`, `v = (theta + pi) H / (2 pi) - 0.5` (pixel centres at integers).
    pub fn pixel_from_angles(&self, a: GeerAngles) -> PixelCoord {
        PixelCoord {
            u: a.phi_rad * self.width as f64 / PI - 0.5,
            v: (a.theta_rad + PI) * self.height() as f64 / (2.0 * PI) - 0.5,
        }
    }

    /// Inverse of [`Self::pixel_from_angles`].
    pub fn angles_from_pixel(&self, p: PixelCoord) -> GeerAngles {
        GeerAngles {
            phi_rad: (p.u + 0.5) * PI / self.width as f64,
            theta_rad: (p.v + 0.5) * 2.0 * PI / self.height() as f64 - PI,
        }
    }

    /// Angles of a rig-frame point as seen from both cameras, and their disparity.
    pub fn point_disparity(&self, point_rig: &Vector3<f64>) -> PointDisparity {
        let l = self.angles_from_dir_rig(&(point_rig - self.left_origin_rig));
        let r = self.angles_from_dir_rig(&(point_rig - self.right_origin_rig));
        PointDisparity {
            phi_l_rad: l.phi_rad,
            phi_r_rad: r.phi_rad,
            disparity_rad: l.phi_rad - r.phi_rad,
            theta_rad: l.theta_rad,
        }
    }

    /// Range from the left camera, `rho_l = B sin(phi_r) / sin(d)`; `None` for `d <= 0`
    /// (a point at infinity or behind the baseline geometry).
    pub fn range_from_disparity(&self, phi_r_rad: f64, disparity_rad: f64) -> Option<f64> {
        let s = disparity_rad.sin();
        (disparity_rad > 0.0 && s > 0.0).then(|| self.baseline_m * phi_r_rad.sin() / s)
    }

    /// Disparity of a point at range `range_m` along the left camera's ray with GEER angle
    /// `phi_l`: `d = phi_l - phi_r` with `phi_r = atan2(rho sin phi_l, rho cos phi_l + B)`.
    pub fn disparity_from_range(&self, phi_l_rad: f64, range_m: f64) -> f64 {
        let (s, c) = phi_l_rad.sin_cos();
        let phi_r = (range_m * s).atan2(range_m * c + self.baseline_m);
        phi_l_rad - phi_r
    }

    /// Disparity in GEER pixels for an angular disparity: `d W / pi`.
    pub fn disparity_px(&self, disparity_rad: f64) -> f64 {
        disparity_rad * self.width as f64 / PI
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn pair(l: [f64; 3], r: [f64; 3]) -> GeerPair {
        GeerPair::new(Vector3::from(l), Vector3::from(r), Vector3::z(), 256).unwrap()
    }

    #[test]
    fn zero_baseline_is_an_error() {
        assert!(GeerPair::new(Vector3::zeros(), Vector3::zeros(), Vector3::z(), 8).is_err());
    }

    #[test]
    fn angles_pixels_round_trip() {
        let p = pair([0.0, 0.0, 0.0], [0.0, -1.0, 0.0]);
        for &(phi, theta) in &[(0.3, -2.0), (1.5, 0.1), (2.9, 3.0)] {
            let a = GeerAngles {
                phi_rad: phi,
                theta_rad: theta,
            };
            let b = p.angles_from_dir_rig(&p.dir_rig_from_angles(a));
            assert_relative_eq!(b.phi_rad, phi, epsilon = 1e-12);
            assert_relative_eq!(b.theta_rad, theta, epsilon = 1e-12);
            let c = p.angles_from_pixel(p.pixel_from_angles(a));
            assert_relative_eq!(c.phi_rad, phi, epsilon = 1e-12);
            assert_relative_eq!(c.theta_rad, theta, epsilon = 1e-12);
        }
    }

    #[test]
    fn disparity_and_range_invert() {
        let p = pair([0.3, 0.2, 0.0], [-0.4, 0.9, 0.1]);
        let pt = Vector3::new(4.0, -3.0, 1.5);
        let d = p.point_disparity(&pt);
        let rho = p
            .range_from_disparity(d.phi_r_rad, d.disparity_rad)
            .unwrap();
        assert_relative_eq!(
            rho,
            (pt - Vector3::new(0.3, 0.2, 0.0)).norm(),
            epsilon = 1e-9
        );
        let d2 = p.disparity_from_range(d.phi_l_rad, rho);
        assert_relative_eq!(d2, d.disparity_rad, epsilon = 1e-12);
    }
}
