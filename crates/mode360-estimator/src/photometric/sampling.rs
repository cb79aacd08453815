//! Exact per-sphere sampling of one camera onto the output ERP grid, computed on the fly.
//!
//! For output pixel `k` with unit ray `dir_k` (output frame) and sphere range `rho`, camera `c`
//! sees the point `p = R_c (rho dir_k) + t_c = rho (R_c dir_k) + t_c` (with
//! `cam_from_output = (R_c, t_c)`) at the ERP pixel
//!
//! ```text
//! lon = atan2(p_y, p_x),  lat = atan2(p_z, hypot(p_x, p_y))
//! u = (1 - lon/pi) W/2 - 0.5,  v = (pi/2 - lat) H/pi - 0.5
//! ```
//!
//! the same formula as [`mode360_core::geometry::SweepGeometry::sample`]. The rotated rays `R_c dir_k`
//! are cached per rig, so a sphere costs one multiply-add and two arctangents per pixel; the
//! arctangent is a Cephes-style polynomial accurate to about 1e-7 rad (1e-5 px at 512 wide).
//! Bilinear interpolation matches [`mode360_core::geometry::ErpGrid::bilinear_taps`]: columns wrap
//! across the longitude seam, rows clamp at the poles.

use mode360_core::geometry::ErpGrid;
use nalgebra::Isometry3;
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// `tan(3 pi / 8)`: above it, `atan(x) = pi/2 - atan(1/x)`.
const TAN_3PI_8: f32 = 2.414_213_6;
/// `tan(pi / 8)`: above it, `atan(x) = pi/4 + atan((x - 1)/(x + 1))`.
const TAN_PI_8: f32 = 0.414_213_57;
/// Cephes `atanf` minimax coefficients for `atan(x) = x + x z P(z)`, `z = x^2`, `|x| <= tan(pi/8)`.
const ATAN_P3: f32 = 8.053_744_5e-2;
const ATAN_P2: f32 = -1.387_768_6e-1;
const ATAN_P1: f32 = 1.997_771_1e-1;
const ATAN_P0: f32 = -3.333_295e-1;

/// Arctangent of `x >= 0` with range reduction at `tan(pi/8)` and `tan(3pi/8)`.
#[inline]
fn atan_non_negative(x: f32) -> f32 {
    let (offset, t) = if x > TAN_3PI_8 {
        (FRAC_PI_2, -1.0 / x)
    } else if x > TAN_PI_8 {
        (FRAC_PI_4, (x - 1.0) / (x + 1.0))
    } else {
        (0.0, x)
    };
    let z = t * t;
    let poly = ((ATAN_P3 * z + ATAN_P2) * z + ATAN_P1) * z + ATAN_P0;
    offset + t + t * z * poly
}

/// Four-quadrant arctangent, `atan2(y, x)` in `(-pi, pi]`; `(0, 0)` gives 0.
#[inline]
pub(crate) fn fast_atan2(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let ay = y.abs();
    if ax == 0.0 && ay == 0.0 {
        return 0.0;
    }
    // atan(min/max) is better conditioned than atan(y/x).
    let (num, den, swapped) = if ay > ax {
        (ax, ay, true)
    } else {
        (ay, ax, false)
    };
    let mut a = atan_non_negative(num / den);
    if swapped {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// Per-rig sampling data of one camera.
#[derive(Clone, Debug)]
pub struct CameraSampler {
    /// `R_c dir_k` for every output pixel, row-major.
    rotated_rays: Vec<[f32; 3]>,
    /// `t_c` of `cam_from_output`, metres.
    translation_m: [f32; 3],
    grid: ErpGrid,
    /// The camera's frame and grid coincide with the output's: sampling is the identity.
    pub identity: bool,
}

/// Rotation angle (rad) and translation (m) below which a camera counts as the output frame.
const IDENTITY_TOLERANCE: f64 = 1e-9;

impl CameraSampler {
    pub fn new(output: ErpGrid, cam_from_output: &Isometry3<f64>, grid: ErpGrid) -> Self {
        let rotation = cam_from_output.rotation;
        let rotated_rays = (0..output.len())
            .map(|k| {
                let r = rotation * output.dir_from_pixel(output.pixel_of_index(k));
                [r.x as f32, r.y as f32, r.z as f32]
            })
            .collect();
        let t = cam_from_output.translation.vector;
        let identity = grid == output
            && t.norm() < IDENTITY_TOLERANCE
            && rotation.angle() < IDENTITY_TOLERANCE;
        Self {
            rotated_rays,
            translation_m: [t.x as f32, t.y as f32, t.z as f32],
            grid,
            identity,
        }
    }

    /// Camera pixel `[u, v]` of output pixel `k` on the sphere of `range_m`.
    #[inline]
    pub fn pixel(&self, k: usize, range_m: f32) -> [f32; 2] {
        let r = self.rotated_rays[k];
        let t = self.translation_m;
        let x = range_m * r[0] + t[0];
        let y = range_m * r[1] + t[1];
        let z = range_m * r[2] + t[2];
        let lon = fast_atan2(y, x);
        let lat = fast_atan2(z, (x * x + y * y).sqrt());
        let w = self.grid.width() as f32;
        let h = self.grid.height() as f32;
        [
            (1.0 - lon / PI) * w * 0.5 - 0.5,
            (FRAC_PI_2 - lat) * h / PI - 0.5,
        ]
    }

    /// Samples `image` (this camera's grey image, row-major) for every output pixel on the
    /// sphere of `range_m`, writing row-major into `out`.
    pub fn warp(&self, image: &[f32], range_m: f32, out: &mut [f32]) {
        if self.identity {
            out.copy_from_slice(image);
            return;
        }
        let w = self.grid.width();
        let h = self.grid.height();
        for (k, o) in out.iter_mut().enumerate() {
            let [u, v] = self.pixel(k, range_m);
            *o = bilinear_wrapped(image, w, h, u, v);
        }
    }
}

/// Bilinear sample at continuous pixel `(u, v)` (integers are pixel centres): columns wrap,
/// rows clamp, as [`ErpGrid::bilinear_taps`].
#[inline]
pub fn bilinear_wrapped(image: &[f32], w: usize, h: usize, u: f32, v: f32) -> f32 {
    let u_floor = u.floor();
    let fu = u - u_floor;
    let u0 = (u_floor as i64).rem_euclid(w as i64) as usize;
    let u1 = if u0 + 1 == w { 0 } else { u0 + 1 };
    let v_clamped = v.clamp(0.0, (h - 1) as f32);
    let v_floor = v_clamped.floor();
    let fv = v_clamped - v_floor;
    let v0 = v_floor as usize;
    let v1 = (v0 + 1).min(h - 1);
    let r0 = v0 * w;
    let r1 = v1 * w;
    let top = image[r0 + u0] * (1.0 - fu) + image[r0 + u1] * fu;
    let bottom = image[r1 + u0] * (1.0 - fu) + image[r1 + u1] * fu;
    top * (1.0 - fv) + bottom * fv
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::{DepthHypotheses, DepthRange, PixelCoord, Rig, SweepGeometry};

    #[test]
    fn fast_atan2_matches_libm() {
        let mut worst = 0.0f64;
        for i in 0..2000 {
            let a = i as f64 * 0.0031 - 3.1;
            for r in [1e-3, 0.7, 5.0, 900.0] {
                let (y, x) = ((a.sin() * r) as f32, (a.cos() * r) as f32);
                let err = (fast_atan2(y, x) as f64 - (y as f64).atan2(x as f64)).abs();
                worst = worst.max(err);
            }
        }
        assert!(worst < 1e-6, "worst atan2 error {worst} rad");
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
        assert!((fast_atan2(0.0, -1.0) - PI).abs() < 1e-6);
    }

    #[test]
    fn sampling_matches_sweep_geometry() -> Result<(), Box<dyn std::error::Error>> {
        let rig = Rig::from_file(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../launch_configs/rig_deep360.yaml"
        ))?;
        let output = ErpGrid::new(64)?;
        let hyp = DepthHypotheses::new(DepthRange::paper(), 16)?;
        let geometry = SweepGeometry::new(&rig, output, vec![output; 4], hyp)?;
        let mut worst = 0.0f64;
        for cam in 0..4 {
            let sampler = CameraSampler::new(output, &rig.cam_from_output(cam), output);
            assert_eq!(sampler.identity, cam == 0);
            for sphere in 0..16 {
                let range_m = hyp.depth_m(sphere as f64) as f32;
                for k in (0..output.len()).step_by(7) {
                    let p = PixelCoord {
                        u: (k % 64) as f64,
                        v: (k / 64) as f64,
                    };
                    let exact = geometry.sample(cam, sphere, p);
                    let [u, v] = sampler.pixel(k, range_m);
                    let du = (u as f64 - exact.u).rem_euclid(64.0);
                    worst = worst.max(du.min(64.0 - du)).max((v as f64 - exact.v).abs());
                }
            }
        }
        assert!(worst < 1e-3, "worst sample offset {worst} px");
        Ok(())
    }

    #[test]
    fn bilinear_matches_taps() -> Result<(), Box<dyn std::error::Error>> {
        let grid = ErpGrid::new(16)?;
        let image: Vec<f32> = (0..grid.len()).map(|i| ((i * 37) % 101) as f32).collect();
        for &(u, v) in &[
            (-0.25, 1.0),
            (15.5, 3.2),
            (3.7, -0.4),
            (7.1, 7.9),
            (0.0, 0.0),
        ] {
            let taps = grid.bilinear_taps(PixelCoord { u, v });
            let expected = taps.sample(&image);
            let got = bilinear_wrapped(&image, 16, 8, u as f32, v as f32);
            assert!(
                (got - expected).abs() < 1e-3,
                "({u},{v}): {got} vs {expected}"
            );
        }
        Ok(())
    }
}
