//! The Kannala-Brandt model with four coefficients (Kannala and Brandt, "A Generic Camera
//! Model and Calibration Method for Conventional, Wide-Angle, and Fish-Eye Lenses", 2006),
//! as Kalibr's `pinhole` + `equidistant`, Basalt's `kb4` and OpenCV's fisheye model use it:
//!
//! ```text
//! r = sqrt(x^2 + y^2),  theta = atan2(r, z)               angle from the optical axis
//! d(theta) = theta + k1 theta^3 + k2 theta^5 + k3 theta^7 + k4 theta^9
//! u = fx d(theta) x / r + cx                              (v likewise with fy, y, cy)
//! valid if theta < theta_max
//! ```
//!
//! `theta_max` is where `d` stops increasing: the first root of
//! `d'(theta) = 1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8` in `(0, pi]`,
//! or `pi` (the whole sphere but the backward axis) when there is none. Beyond it the
//! polynomial folds back and the same pixel would see two rays, so those points are not seen.
//!
//! Unprojection: `r_d = sqrt(mx^2 + my^2)` with `mx = (u - cx) / fx`, `my = (v - cy) / fy`;
//! solve `d(theta) = r_d` on `[0, theta_max)` (safeguarded Newton) and
//! `dir = (sin(theta) mx / r_d, sin(theta) my / r_d, cos(theta))`; `None` when
//! `r_d >= d(theta_max)`.

use super::{finite, Focal, IntrinsicsError};
use crate::geometry::erp::PixelCoord;
use nalgebra::{Unit, Vector3};
use std::f64::consts::PI;

/// Steps of the scan for the first root of `d'` on `(0, pi]`.
const THETA_MAX_SCAN_STEPS: usize = 4096;
/// Bisection and Newton iterations; both converge far sooner.
const SOLVER_ITERATIONS: usize = 200;
/// Solver tolerance on `theta`, radians.
const THETA_TOLERANCE_RAD: f64 = 1e-15;

/// A Kannala-Brandt lens: `fx fy cx cy k1 k2 k3 k4`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KannalaBrandt {
    focal: Focal,
    k: [f64; 4],
    theta_max_rad: f64,
}

impl KannalaBrandt {
    /// The name in the rig YAML.
    pub const NAME: &'static str = "kannala_brandt";

    /// Any finite `k1..k4`.
    pub fn new(focal: Focal, k: [f64; 4]) -> Result<Self, IntrinsicsError> {
        for (i, v) in k.iter().enumerate() {
            finite(&format!("k{}", i + 1), *v)?;
        }
        let mut m = Self {
            focal,
            k,
            theta_max_rad: PI,
        };
        m.theta_max_rad = m.first_derivative_root().unwrap_or(PI);
        Ok(m)
    }

    pub fn focal(&self) -> Focal {
        self.focal
    }

    /// `[k1, k2, k3, k4]`.
    pub fn coefficients(&self) -> [f64; 4] {
        self.k
    }

    /// The largest angle from the optical axis the model sees, radians.
    pub fn theta_max_rad(&self) -> f64 {
        self.theta_max_rad
    }

    /// `d(theta) = theta + k1 theta^3 + k2 theta^5 + k3 theta^7 + k4 theta^9`.
    pub fn distorted_radius(&self, theta: f64) -> f64 {
        let t2 = theta * theta;
        let [k1, k2, k3, k4] = self.k;
        theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    }

    /// `d'(theta) = 1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8`.
    fn derivative(&self, theta: f64) -> f64 {
        let t2 = theta * theta;
        let [k1, k2, k3, k4] = self.k;
        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    }

    /// The first `theta` in `(0, pi]` with `d'(theta) = 0`, by a scan and bisection.
    fn first_derivative_root(&self) -> Option<f64> {
        let step = PI / THETA_MAX_SCAN_STEPS as f64;
        let mut lo = 0.0;
        for i in 1..=THETA_MAX_SCAN_STEPS {
            let hi = i as f64 * step;
            if self.derivative(hi) <= 0.0 {
                let (mut a, mut b) = (lo, hi);
                for _ in 0..SOLVER_ITERATIONS {
                    let mid = 0.5 * (a + b);
                    if self.derivative(mid) > 0.0 {
                        a = mid;
                    } else {
                        b = mid;
                    }
                    if b - a < THETA_TOLERANCE_RAD {
                        break;
                    }
                }
                return Some(a);
            }
            lo = hi;
        }
        None
    }

    /// See the module docs; `None` at or beyond `theta_max` (and for the backward axis,
    /// whose pixel is a whole circle).
    pub fn project(&self, p: &Vector3<f64>) -> Option<PixelCoord> {
        if !p.iter().all(|c| c.is_finite()) {
            return None;
        }
        let r = p.x.hypot(p.y);
        if r == 0.0 {
            return (p.z > 0.0).then(|| self.focal.pixel(0.0, 0.0));
        }
        let theta = r.atan2(p.z);
        if theta >= self.theta_max_rad {
            return None;
        }
        let s = self.distorted_radius(theta) / r;
        Some(self.focal.pixel(s * p.x, s * p.y))
    }

    /// See the module docs.
    pub fn unproject(&self, px: PixelCoord) -> Option<Unit<Vector3<f64>>> {
        let (mx, my) = self.focal.normalized(px);
        let rd = mx.hypot(my);
        if !rd.is_finite() || rd >= self.distorted_radius(self.theta_max_rad) {
            return None;
        }
        if rd == 0.0 {
            return Some(Vector3::z_axis());
        }
        let theta = self.solve_theta(rd);
        let (s, c) = theta.sin_cos();
        Some(Unit::new_normalize(Vector3::new(
            s * mx / rd,
            s * my / rd,
            c,
        )))
    }

    /// `theta` in `[0, theta_max)` with `d(theta) = rd`: Newton steps kept inside a shrinking
    /// bracket (`d` increases on it), bisection when a step leaves it.
    fn solve_theta(&self, rd: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, self.theta_max_rad);
        let mut theta = rd.min(hi);
        for _ in 0..SOLVER_ITERATIONS {
            let f = self.distorted_radius(theta) - rd;
            if f > 0.0 {
                hi = theta;
            } else {
                lo = theta;
            }
            let slope = self.derivative(theta);
            let mut next = theta - f / slope;
            if !(next > lo && next < hi && next.is_finite()) {
                next = 0.5 * (lo + hi);
            }
            if (next - theta).abs() < THETA_TOLERANCE_RAD {
                return next;
            }
            theta = next;
        }
        theta
    }
}
