//! Equirectangular projection (ERP) of a 360° camera.
//!
//! An ERP image has `W` columns and `H = W / 2` rows; pixel centres sit at `+0.5`:
//!
//! ```text
//! lon = pi * (1 - 2 (u + 0.5) / W)     0 at the centre column, +pi/2 looks along +y (left)
//! lat = pi/2 - pi (v + 0.5) / H        the top row looks up
//! dir = (cos lat cos lon, cos lat sin lon, sin lat)
//! ```
//!
//! Continuous pixel coordinates in this module put pixel `(i, j)`'s centre at `(u, v) = (i, j)`.

use super::GeometryError;
use nalgebra::Vector3;
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, PI};

/// The smallest ERP width accepted.
pub const MIN_ERP_WIDTH: usize = 4;
/// The largest ERP width accepted (16K panoramas; a larger grid would only exhaust memory).
pub const MAX_ERP_WIDTH: usize = 16_384;

/// Longitude and latitude of a viewing direction, radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LonLat {
    pub lon_rad: f64,
    pub lat_rad: f64,
}

/// A continuous pixel position: integer values are pixel centres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelCoord {
    pub u: f64,
    pub v: f64,
}

/// The four neighbours of a continuous pixel position with their bilinear weights.
/// Indices are row-major (`v * W + u`); weights sum to one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BilinearTaps {
    pub index: [u32; 4],
    pub weight: [f32; 4],
}

impl BilinearTaps {
    /// Taps of a sample a camera does not see: zero weights, so it contributes nothing.
    pub const UNSEEN: Self = Self {
        index: [0; 4],
        weight: [0.0; 4],
    };

    /// Taps at fractional offsets `(fu, fv)` from the top-left of four corners given as
    /// `[top-left, top-right, bottom-left, bottom-right]` indices:
    /// `w = [(1-fu)(1-fv), fu (1-fv), (1-fu) fv, fu fv]`.
    #[inline(always)]
    pub fn from_corners(index: [u32; 4], fu: f32, fv: f32) -> Self {
        Self {
            index,
            weight: [
                (1.0 - fu) * (1.0 - fv),
                fu * (1.0 - fv),
                (1.0 - fu) * fv,
                fu * fv,
            ],
        }
    }
}

/// The pixel grid of an ERP image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ErpGrid {
    width: usize,
    height: usize,
}

impl ErpGrid {
    /// An ERP grid `width` wide and `width / 2` tall; `width` must be even, at least
    /// [`MIN_ERP_WIDTH`] and at most [`MAX_ERP_WIDTH`].
    pub fn new(width: usize) -> Result<Self, GeometryError> {
        if width < MIN_ERP_WIDTH || !width.is_multiple_of(2) {
            return Err(GeometryError::BadErpWidth {
                width,
                min: MIN_ERP_WIDTH,
            });
        }
        if width > MAX_ERP_WIDTH {
            return Err(GeometryError::ErpTooWide {
                width,
                max: MAX_ERP_WIDTH,
            });
        }
        Ok(Self {
            width,
            height: width / 2,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of pixels, `W * H`.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `lon = pi (1 - 2 (u + 0.5) / W)`, `lat = pi/2 - pi (v + 0.5) / H`.
    pub fn lonlat_from_pixel(&self, p: PixelCoord) -> LonLat {
        LonLat {
            lon_rad: PI * (1.0 - 2.0 * (p.u + 0.5) / self.width as f64),
            lat_rad: FRAC_PI_2 - PI * (p.v + 0.5) / self.height as f64,
        }
    }

    /// Inverse of [`Self::lonlat_from_pixel`]: `u = (1 - lon/pi) W/2 - 0.5`,
    /// `v = (pi/2 - lat) H/pi - 0.5`. For `lon` in `(-pi, pi]` this gives `u` in `[-0.5, W - 0.5)`.
    pub fn pixel_from_lonlat(&self, ll: LonLat) -> PixelCoord {
        PixelCoord {
            u: (1.0 - ll.lon_rad / PI) * self.width as f64 / 2.0 - 0.5,
            v: (FRAC_PI_2 - ll.lat_rad) * self.height as f64 / PI - 0.5,
        }
    }

    /// Unit viewing direction of a pixel, `(cos lat cos lon, cos lat sin lon, sin lat)`.
    pub fn dir_from_pixel(&self, p: PixelCoord) -> Vector3<f64> {
        dir_from_lonlat(self.lonlat_from_pixel(p))
    }

    /// Pixel that looks along `dir` (any non-zero length). The zero vector maps to the
    /// forward direction.
    pub fn pixel_from_dir(&self, dir: &Vector3<f64>) -> PixelCoord {
        self.pixel_from_lonlat(lonlat_from_dir(dir))
    }

    /// Centre of the pixel with row-major index `k`: `(k mod W, k div W)`.
    pub fn pixel_of_index(&self, k: usize) -> PixelCoord {
        PixelCoord {
            u: (k % self.width) as f64,
            v: (k / self.width) as f64,
        }
    }

    /// Row-major index of the pixel whose centre is nearest to the direction `dir`: the
    /// column rounded and wrapped around the seam, the row rounded and clamped at the poles.
    pub fn index_from_dir(&self, dir: &Vector3<f64>) -> usize {
        let p = self.pixel_from_dir(dir);
        let u = (p.u.round() as i64).rem_euclid(self.width as i64) as usize;
        let v = (p.v.round().max(0.0) as usize).min(self.height - 1);
        v * self.width + u
    }

    /// Bilinear taps at a continuous pixel position: columns wrap around the longitude seam,
    /// rows clamp at the poles. [`Self::taps_of`] of [`Self::bilinear_sample`] are the same
    /// taps with the offsets rounded to [`ErpSample::FRACTION_STEPS`].
    pub fn bilinear_taps(&self, p: PixelCoord) -> BilinearTaps {
        let (u0, v0, fu, fv) = self.corner_and_offsets(p);
        self.corner_taps(u0, v0, fu, fv)
    }

    /// The top-left corner `(floor(u) mod W, floor(clamp(v, 0, H - 1)))` of a continuous
    /// pixel position and its fractional offsets in `[0, 1)`.
    fn corner_and_offsets(&self, p: PixelCoord) -> (u32, u32, f32, f32) {
        let (w, h) = (self.width as i64, self.height as i64);
        let u0 = p.u.floor();
        let fu = (p.u - u0) as f32;
        let u0 = (u0 as i64).rem_euclid(w);
        let v_clamped = p.v.clamp(0.0, (h - 1) as f64);
        let v0 = v_clamped.floor();
        let fv = (v_clamped - v0) as f32;
        // 0 <= u0 < W and 0 <= v0 < H, both at most MAX_ERP_WIDTH < 2^16
        (u0 as u32, v0 as u32, fu, fv)
    }

    /// The bilinear sample at a continuous pixel position in compact form: the top-left
    /// corner and the fractional offsets rounded to `1 / FRACTION_STEPS` of a pixel.
    pub fn bilinear_sample(&self, p: PixelCoord) -> ErpSample {
        let (u0, v0, fu, fv) = self.corner_and_offsets(p);
        ErpSample {
            u0: u0 as u16,
            v0: v0 as u16,
            fu: ErpSample::quantize(fu),
            fv: ErpSample::quantize(fv),
        }
    }

    /// The four taps of `s` (of this grid): corners `(u0, v0)`, `(u0 + 1 mod W, v0)`,
    /// `(u0, min(v0 + 1, H - 1))`, `(u0 + 1 mod W, min(v0 + 1, H - 1))`, weights
    /// [`BilinearTaps::from_corners`]; [`BilinearTaps::UNSEEN`] for [`ErpSample::UNSEEN`].
    #[inline(always)]
    pub fn taps_of(&self, s: ErpSample) -> BilinearTaps {
        if !s.is_seen() {
            return BilinearTaps::UNSEEN;
        }
        let (fu, fv) = s.offsets();
        self.corner_taps(u32::from(s.u0), u32::from(s.v0), fu, fv)
    }

    /// The bilinear value of `values` (row-major, one per pixel of this grid) at `s`, as two
    /// interpolations along the rows and one across them:
    ///
    /// ```text
    /// top = a + fu (b - a),   bottom = c + fu (d - c),   value = top + fv (bottom - top)
    /// ```
    ///
    /// with `a, b, c, d` the values at the corners of [`Self::taps_of`] (top-left, top-right,
    /// bottom-left, bottom-right): its weighted sum to rounding, in 3 multiplications instead
    /// of 8. 0 for [`ErpSample::UNSEEN`]. Panics if `values` is shorter than the grid.
    #[inline(always)]
    pub fn interpolate(&self, s: ErpSample, values: &[f32]) -> f32 {
        if !s.is_seen() {
            return 0.0;
        }
        let w = self.width;
        let (u0, v0) = (usize::from(s.u0), usize::from(s.v0));
        let (u1, v1) = self.opposite_corner(u0, v0);
        let (fu, fv) = s.offsets();
        let (top_row, bottom_row) = (&values[v0 * w..][..w], &values[v1 * w..][..w]);
        let top = top_row[u0] + fu * (top_row[u1] - top_row[u0]);
        let bottom = bottom_row[u0] + fu * (bottom_row[u1] - bottom_row[u0]);
        top + fv * (bottom - top)
    }

    /// The bottom-right corner `(u0 + 1 mod W, min(v0 + 1, H - 1))` of the top-left `(u0, v0)`:
    /// longitude wraps, latitude clamps.
    #[inline(always)]
    fn opposite_corner(&self, u0: usize, v0: usize) -> (usize, usize) {
        let u1 = if u0 + 1 == self.width { 0 } else { u0 + 1 };
        (u1, (v0 + 1).min(self.height - 1))
    }

    #[inline(always)]
    fn corner_taps(&self, u0: u32, v0: u32, fu: f32, fv: f32) -> BilinearTaps {
        let w = self.width as u32;
        let (u1, v1) = self.opposite_corner(u0 as usize, v0 as usize);
        let (u1, v1) = (u1 as u32, v1 as u32);
        let idx = |u: u32, v: u32| v * w + u;
        BilinearTaps::from_corners([idx(u0, v0), idx(u1, v0), idx(u0, v1), idx(u1, v1)], fu, fv)
    }
}

/// A bilinear sample of an [`ErpGrid`] in 8 bytes instead of [`BilinearTaps`]' 32: the
/// top-left corner and the fractional offsets in steps of `1 / FRACTION_STEPS` of a pixel,
/// expanded by [`ErpGrid::taps_of`] (the sweep's tables hold millions of samples per camera;
/// 99 MiB for the Deep360 rig at 256 against 148 MiB with f32 offsets).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ErpSample {
    /// Column of the top-left corner; `u16::MAX` for [`Self::UNSEEN`].
    u0: u16,
    /// Row of the top-left corner.
    v0: u16,
    /// Offset right of the corner, in `1 / FRACTION_STEPS` of a pixel.
    fu: u16,
    /// Offset below the corner, likewise.
    fv: u16,
}

impl ErpSample {
    /// Steps per pixel of the offsets: a sample lands within `1 / (2 FRACTION_STEPS)` of a
    /// pixel (7.6e-6) of its exact position (`1 / FRACTION_STEPS` for an offset that rounds
    /// to 1, kept at the last step), each weight within 3.1e-5 of the exact one.
    pub const FRACTION_STEPS: u32 = 1 << 16;
    /// One step of the offsets, in pixels.
    const FRACTION_STEP: f32 = 1.0 / Self::FRACTION_STEPS as f32;

    /// A sample the camera does not see: it expands to [`BilinearTaps::UNSEEN`].
    pub const UNSEEN: Self = Self {
        u0: u16::MAX,
        v0: 0,
        fu: 0,
        fv: 0,
    };

    /// An offset in `[0, 1)` to the nearest step (the last step where it rounds to 1).
    fn quantize(f: f32) -> u16 {
        let steps = (f * Self::FRACTION_STEPS as f32).round();
        steps.clamp(0.0, f32::from(u16::MAX)) as u16
    }

    /// The offsets right of and below the corner, in pixels.
    #[inline(always)]
    fn offsets(&self) -> (f32, f32) {
        (
            f32::from(self.fu) * Self::FRACTION_STEP,
            f32::from(self.fv) * Self::FRACTION_STEP,
        )
    }

    /// Whether the sample has taps (is not [`Self::UNSEEN`]); widths stay below `u16::MAX`
    /// ([`MAX_ERP_WIDTH`]).
    #[inline(always)]
    pub fn is_seen(&self) -> bool {
        self.u0 != u16::MAX
    }
}

/// Bilinear ERP resampling of `channels`-interleaved row-major data from `src` to `dst`
/// (pixel centres aligned: `u_src = (u + 0.5) W_src / W_dst - 0.5`, likewise `v`; longitude
/// wraps, latitude clamps).
pub fn resample_erp(data: &[f32], channels: usize, src: ErpGrid, dst: ErpGrid) -> Vec<f32> {
    if src == dst {
        return data.to_vec();
    }
    let scale = src.width() as f64 / dst.width() as f64;
    let mut out = vec![0.0; dst.len() * channels];
    // one task per output row (the node resamples three or four 512-wide maps a frame)
    out.par_chunks_mut((dst.width() * channels).max(1))
        .enumerate()
        .for_each(|(v, row)| {
            for u in 0..dst.width() {
                let taps = src.bilinear_taps(PixelCoord {
                    u: (u as f64 + 0.5) * scale - 0.5,
                    v: (v as f64 + 0.5) * scale - 0.5,
                });
                let o = u * channels;
                for (&i, &w) in taps.index.iter().zip(taps.weight.iter()) {
                    let s = i as usize * channels;
                    for c in 0..channels {
                        row[o + c] += w * data[s + c];
                    }
                }
            }
        });
    out
}

/// `(cos lat cos lon, cos lat sin lon, sin lat)`.
pub fn dir_from_lonlat(ll: LonLat) -> Vector3<f64> {
    let (sl, cl) = ll.lat_rad.sin_cos();
    let (so, co) = ll.lon_rad.sin_cos();
    Vector3::new(cl * co, cl * so, sl)
}

/// `lon = atan2(y, x)`, `lat = atan2(z, hypot(x, y))`.
pub fn lonlat_from_dir(d: &Vector3<f64>) -> LonLat {
    LonLat {
        lon_rad: d.y.atan2(d.x),
        lat_rad: d.z.atan2(d.x.hypot(d.y)),
    }
}

impl BilinearTaps {
    /// Weighted sum of `values` (row-major, one value per pixel) at these taps.
    pub fn sample(&self, values: &[f32]) -> f32 {
        self.index
            .iter()
            .zip(self.weight.iter())
            .map(|(&i, &w)| values[i as usize] * w)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// 4,000 positions spread over a 64x32 grid and past its edges (across the seam, above the
    /// first row and below the last).
    fn scattered_pixels() -> impl Iterator<Item = PixelCoord> {
        (0..4000).map(|k| {
            let t = k as f64;
            PixelCoord {
                u: (t * 0.618_033_988_7).fract() * 70.0 - 3.0,
                v: (t * 0.414_213_562_3).fract() * 34.0 - 1.0,
            }
        })
    }

    /// The compact sample rounds the offsets to 1/65536 of a pixel: the same corners as the
    /// exact taps and weights within 3.1e-5 of them (offsets next to 1 included), summing to 1.
    #[test]
    fn compact_samples_round_the_offsets_only() {
        let grid = ErpGrid::new(64).unwrap();
        let mut worst = 0f32;
        for p in scattered_pixels() {
            let (exact, compact) = (grid.bilinear_taps(p), grid.taps_of(grid.bilinear_sample(p)));
            assert_eq!(exact.index, compact.index, "{p:?}");
            for (a, b) in exact.weight.iter().zip(&compact.weight) {
                worst = worst.max((a - b).abs());
            }
            assert!((compact.weight.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        let near_one = PixelCoord {
            u: 5.0 - 1e-7,
            v: 3.0 - 1e-7,
        };
        let (exact, compact) = (
            grid.bilinear_taps(near_one),
            grid.taps_of(grid.bilinear_sample(near_one)),
        );
        assert_eq!(exact.index, compact.index);
        for (a, b) in exact.weight.iter().zip(&compact.weight) {
            worst = worst.max((a - b).abs());
        }
        assert!(worst > 0.0 && worst < 3.1e-5, "worst weight error {worst}");
    }

    /// `interpolate` reads the value of the taps' weighted sum (to rounding) on samples across
    /// the seam, on the last row and off the grid (0 for the unseen sample).
    #[test]
    fn interpolate_is_the_weighted_sum_of_the_taps() {
        let grid = ErpGrid::new(64).unwrap();
        let values: Vec<f32> = (0..grid.len())
            .map(|k| ((k as f32) * 0.37).sin() * 2.0 + 0.5)
            .collect();
        let mut worst = 0f32;
        for p in scattered_pixels() {
            let s = grid.bilinear_sample(p);
            let taps = grid.taps_of(s).sample(&values);
            worst = worst.max((grid.interpolate(s, &values) - taps).abs());
        }
        assert!(worst < 1e-5, "worst difference {worst}");
        assert_eq!(grid.interpolate(ErpSample::UNSEEN, &values), 0.0);
    }

    #[test]
    fn rejects_odd_or_tiny_width() {
        assert!(ErpGrid::new(3).is_err());
        assert!(ErpGrid::new(7).is_err());
        assert!(ErpGrid::new(8).is_ok());
    }

    #[test]
    fn centre_column_looks_forward_left_half_looks_left() {
        let g = ErpGrid::new(8).unwrap();
        // The centre column boundary u = W/2 - 0.5 looks exactly forward.
        let d = g.dir_from_pixel(PixelCoord { u: 3.5, v: 1.5 });
        assert_relative_eq!(d, Vector3::new(1.0, 0.0, 0.0), epsilon = 1e-12);
        let left = g.dir_from_pixel(PixelCoord { u: 1.5, v: 1.5 });
        assert_relative_eq!(left, Vector3::new(0.0, 1.0, 0.0), epsilon = 1e-12);
        let up = g.lonlat_from_pixel(PixelCoord { u: 0.0, v: -0.5 });
        assert_relative_eq!(up.lat_rad, FRAC_PI_2, epsilon = 1e-12);
    }

    #[test]
    fn round_trip_pixels() {
        let g = ErpGrid::new(64).unwrap();
        for j in 0..32 {
            for i in 0..64 {
                let p = PixelCoord {
                    u: i as f64 + 0.25,
                    v: j as f64 + 0.1,
                };
                let q = g.pixel_from_dir(&(g.dir_from_pixel(p) * 3.7));
                let du = (q.u - p.u).rem_euclid(64.0);
                assert!(du < 1e-9 || (64.0 - du) < 1e-9, "u {} vs {}", q.u, p.u);
                assert_relative_eq!(q.v, p.v, epsilon = 1e-9);
            }
        }
    }

    #[test]
    fn taps_wrap_across_seam() {
        let g = ErpGrid::new(8).unwrap();
        let t = g.bilinear_taps(PixelCoord { u: -0.25, v: 1.0 });
        // Between column 7 (weight 0.25) and column 0 (weight 0.75) of row 1.
        assert_eq!(t.index[0], 8 + 7);
        assert_eq!(t.index[1], 8);
        assert_relative_eq!(t.weight[0], 0.25);
        assert_relative_eq!(t.weight[1], 0.75);
        let t = g.bilinear_taps(PixelCoord { u: 7.5, v: 1.0 });
        assert_eq!((t.index[0], t.index[1]), (15, 8));
        let sum: f32 = t.weight.iter().sum();
        assert_relative_eq!(sum, 1.0);
    }

    /// Two channels, 32 -> 64 wide and back: a field linear in the row (channel 0) and a
    /// longitude wave (channel 1) read at their pixel-centre positions; the wave wraps the seam.
    #[test]
    fn resample_erp_interpolates_rows_and_wraps_longitude() {
        let (small, large) = (ErpGrid::new(32).unwrap(), ErpGrid::new(64).unwrap());
        let field = |grid: ErpGrid, u: f64, v: f64| {
            let lon = 2.0 * PI * (u + 0.5) / grid.width() as f64;
            [v as f32 * 0.5, (lon.cos()) as f32]
        };
        let data: Vec<f32> = (0..small.len())
            .flat_map(|k| field(small, (k % 32) as f64, (k / 32) as f64))
            .collect();
        let up = resample_erp(&data, 2, small, large);
        assert_eq!(up.len(), large.len() * 2);
        for v in 1..large.height() - 1 {
            for u in 0..large.width() {
                let k = (v * large.width() + u) * 2;
                // the small grid's row of this pixel's centre: (v + 0.5) / 2 - 0.5
                let row = (v as f64 + 0.5) / 2.0 - 0.5;
                assert_relative_eq!(up[k], row as f32 * 0.5, epsilon = 1e-5);
                let lon = 2.0 * PI * (u as f64 + 0.5) / 64.0;
                // linear interpolation of a cosine sampled 32 times a turn
                assert!(
                    (f64::from(up[k + 1]) - lon.cos()).abs() < 0.01,
                    "u {u}: {}",
                    up[k + 1]
                );
            }
        }
        let down = resample_erp(&up, 2, large, small);
        for (k, (a, b)) in down.iter().zip(&data).enumerate() {
            let row = k / 2 / 32;
            if row > 0 && row < small.height() - 1 {
                assert!((a - b).abs() < 0.01, "value {k}: {a} against {b}");
            }
        }
    }
}
