//! SphereNet-style spherical convolution (Coors et al. 2018) on an ERP grid.
//!
//! The 3x3 kernel of output pixel `(lon0, lat0)` samples the sphere at the inverse gnomonic
//! projection of a regular grid on the tangent plane, step `delta = 2 pi / W` (one pixel):
//!
//! ```text
//! x = j tan(delta), y = -i tan(delta)          (i: row offset, j: column offset)
//! r = sqrt(x^2 + y^2), nu = atan(r)
//! lat = asin(cos nu sin lat0 + y sin nu cos lat0 / r)
//! lon = lon0 - atan2(x sin nu, r cos lat0 cos nu - y sin lat0 sin nu)
//! ```
//!
//! (`lon` decreases to the right in an ERP image, hence the minus.) The taps are bilinear in the
//! ERP (longitude wraps, latitude clamps). The layer is `table_sample` of the features followed
//! by a learned linear map over `taps x channels`:
//! `out[b, p, o] = bias[o] + sum_{t, c} weight[t C + c, o] f(tap_t(p))[c]`.

use candle_core::{Result, Tensor};
use candle_nn::{Init, VarBuilder};

use crate::model::ops::{add_bias, count_flops, table_sample, SampleTable};
use mode360_core::geometry::{ErpGrid, LonLat};

/// Kernel side (3x3 taps).
pub const SPHERE_KERNEL: usize = 3;
/// Taps per kernel.
pub const SPHERE_TAPS: usize = SPHERE_KERNEL * SPHERE_KERNEL;

/// The SphereNet sampling pattern of one ERP resolution: `SPHERE_TAPS` samples per pixel,
/// pixel-major (sample index `p * SPHERE_TAPS + t`).
#[derive(Clone, Debug)]
pub struct SphereConvTable {
    grid: ErpGrid,
    table: SampleTable,
}

impl SphereConvTable {
    pub fn new(grid: ErpGrid) -> Self {
        let delta_rad = 2.0 * std::f64::consts::PI / grid.width() as f64;
        let step = delta_rad.tan();
        let half = (SPHERE_KERNEL / 2) as i64;
        let mut taps = Vec::with_capacity(grid.len() * SPHERE_TAPS);
        for k in 0..grid.len() {
            let centre = grid.pixel_of_index(k);
            let ll0 = grid.lonlat_from_pixel(centre);
            let (sin_lat0, cos_lat0) = ll0.lat_rad.sin_cos();
            for i in -half..=half {
                for j in -half..=half {
                    let x = j as f64 * step;
                    let y = -(i as f64) * step;
                    let r = x.hypot(y);
                    let p = if r == 0.0 {
                        centre
                    } else {
                        let nu = r.atan();
                        let (sin_nu, cos_nu) = nu.sin_cos();
                        let lat = (cos_nu * sin_lat0 + y * sin_nu * cos_lat0 / r)
                            .clamp(-1.0, 1.0)
                            .asin();
                        let lon = ll0.lon_rad
                            - (x * sin_nu).atan2(r * cos_lat0 * cos_nu - y * sin_lat0 * sin_nu);
                        grid.pixel_from_lonlat(LonLat {
                            lon_rad: lon,
                            lat_rad: lat,
                        })
                    };
                    taps.push(grid.bilinear_taps(p));
                }
            }
        }
        Self {
            grid,
            table: SampleTable::new(&taps),
        }
    }

    pub fn grid(&self) -> ErpGrid {
        self.grid
    }

    pub fn table(&self) -> &SampleTable {
        &self.table
    }
}

/// One spherical convolution layer: `weight (SPHERE_TAPS * Cin, Cout)`, `bias (Cout)`.
#[derive(Clone, Debug)]
pub struct SphereConv {
    weight: Tensor,
    bias: Tensor,
    c_in: usize,
    c_out: usize,
}

impl SphereConv {
    pub fn new(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        let fan_in = SPHERE_TAPS * c_in;
        let bound = (6.0 / fan_in as f64).sqrt();
        let weight = vb.get_with_hints(
            (fan_in, c_out),
            "weight",
            Init::Uniform {
                lo: -bound,
                up: bound,
            },
        )?;
        let bias = vb.get_with_hints(c_out, "bias", Init::Const(0.0))?;
        Ok(Self {
            weight,
            bias,
            c_in,
            c_out,
        })
    }

    /// x `(B, H, W, Cin)` channels-last on `table`'s grid -> `(B, H, W, Cout)`.
    pub fn forward(&self, x: &Tensor, table: &SphereConvTable) -> Result<Tensor> {
        let (b, h, w, _c) = x.dims4()?;
        // (B, H W SPHERE_TAPS, Cin)
        let sampled = table_sample(x, table.table())?;
        // (B H W, SPHERE_TAPS Cin) x (SPHERE_TAPS Cin, Cout) -> (B H W, Cout)
        let flat = sampled.reshape((b * h * w, SPHERE_TAPS * self.c_in))?;
        count_flops(2.0 * (b * h * w * SPHERE_TAPS * self.c_in * self.c_out) as f64);
        let out = add_bias(&flat.matmul(&self.weight)?, &self.bias)?;
        // (B, H, W, Cout)
        out.reshape((b, h, w, self.c_out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::PixelCoord;

    /// The continuous `u` of a tap from its bilinear weights (columns `u0`, `u0 + 1`).
    fn tap_u(t: &mode360_core::geometry::BilinearTaps, width: usize) -> f64 {
        let u0 = (t.index[0] as usize % width) as f64;
        u0 + (t.weight[1] + t.weight[3]) as f64
    }

    #[test]
    fn centre_tap_is_the_pixel_and_equator_neighbours_are_one_pixel_away() {
        const WIDTH: usize = 64;
        let grid = ErpGrid::new(WIDTH).expect("grid");
        let t = SphereConvTable::new(grid);
        assert_eq!(t.table().len(), grid.len() * SPHERE_TAPS);
        let tap = |p: usize, k: usize| t.table().taps(p * SPHERE_TAPS + k);
        // Centre tap (k = 4) of pixel (10, 5): all weight on that pixel.
        let p = 5 * WIDTH + 10;
        let c = tap(p, 4);
        assert_eq!(c.index[0] as usize, p);
        assert!((c.weight[0] - 1.0).abs() < 1e-6);
        // Row 15 of 32 is just above the equator (lat = pi/64): the right neighbour (k = 5)
        // is within 0.01 px of one pixel to the right.
        let p = 15 * WIDTH + 20;
        let right = tap_u(&tap(p, 5), WIDTH);
        assert!((right - 21.0).abs() < 0.01, "right tap at u = {right}");
        // Near the pole (row 1, lat = 84.4 deg) the same tangent step spans about
        // 1 / cos(lat) = 10 columns of the ERP.
        let p = WIDTH + 20;
        let ll = grid.lonlat_from_pixel(PixelCoord { u: 20.0, v: 1.0 });
        let right = tap_u(&tap(p, 5), WIDTH) - 20.0;
        let expected = 1.0 / ll.lat_rad.cos();
        assert!(
            right > 0.8 * expected && right < 1.2 * expected,
            "{right} vs {expected}"
        );
    }
}
