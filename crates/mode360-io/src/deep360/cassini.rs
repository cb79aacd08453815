//! Cassini (GEER) images of the Deep360 dataset and ERP, both ways.
//!
//! Dataset frame `D`: x left, y up, z forward. Row `i`, column `j` of an `H x W` Cassini
//! image look along `(sin phi, cos phi sin theta, cos phi cos theta)` with
//! `theta = pi - (i + 0.5) 2 pi / H` and `phi = pi/2 - (j + 0.5) pi / W`; REP 103 is
//! `x = z_D`, `y = x_D`, `z = y_D`. Colour resamples bilinearly (rows wrap around
//! theta = +-pi, columns clamp at the poles), range by nearest neighbour.

use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::{ErpGrid, PixelCoord};
use nalgebra::Vector3;
use std::f64::consts::{FRAC_PI_2, PI};

/// Width (columns) of a Deep360 Cassini image.
pub const CASSINI_WIDTH: usize = 512;
/// Height (rows) of a Deep360 Cassini image.
pub const CASSINI_HEIGHT: usize = 1024;

/// A continuous position in a Cassini image (`col` = j, `row` = i, pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CassiniCoord {
    pub col: f64,
    pub row: f64,
}

/// REP 103 direction from a dataset-frame (x left, y up, z forward) direction.
pub fn rep_from_dataset(d: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(d.z, d.x, d.y)
}

/// Dataset-frame direction from a REP 103 direction.
pub fn dataset_from_rep(r: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(r.y, r.z, r.x)
}

/// REP 103 unit direction of Cassini pixel `(row i, col j)` of a `width x height` image:
/// `dir_D = (sin phi, cos phi sin theta, cos phi cos theta)`.
pub fn cassini_dir(c: CassiniCoord, width: usize, height: usize) -> Vector3<f64> {
    let theta = PI - (c.row + 0.5) * 2.0 * PI / height as f64;
    let phi = FRAC_PI_2 - (c.col + 0.5) * PI / width as f64;
    let (sp, cp) = phi.sin_cos();
    let (st, ct) = theta.sin_cos();
    rep_from_dataset(&Vector3::new(sp, cp * st, cp * ct))
}

/// Cassini position that looks along the REP 103 direction `dir` (any non-zero length).
pub fn cassini_from_dir(dir: &Vector3<f64>, width: usize, height: usize) -> CassiniCoord {
    let d = dataset_from_rep(dir);
    let norm = d.norm().max(f64::MIN_POSITIVE);
    let phi = (d.x / norm).clamp(-1.0, 1.0).asin();
    let theta = d.y.atan2(d.z);
    CassiniCoord {
        col: (FRAC_PI_2 - phi) * width as f64 / PI - 0.5,
        row: (PI - theta) * height as f64 / (2.0 * PI) - 0.5,
    }
}

/// Bilinear taps in a Cassini image: rows wrap (theta is periodic), columns clamp.
fn cassini_taps(c: CassiniCoord, width: usize, height: usize) -> ([usize; 4], [f32; 4]) {
    let (w, h) = (width as i64, height as i64);
    let col = c.col.clamp(0.0, (w - 1) as f64);
    let j0 = col.floor();
    let fj = (col - j0) as f32;
    let j0 = j0 as i64;
    let j1 = (j0 + 1).min(w - 1);
    let i0f = c.row.floor();
    let fi = (c.row - i0f) as f32;
    let i0 = (i0f as i64).rem_euclid(h);
    let i1 = (i0 + 1) % h;
    let idx = |i: i64, j: i64| (i * w + j) as usize;
    (
        [idx(i0, j0), idx(i0, j1), idx(i1, j0), idx(i1, j1)],
        [
            (1.0 - fj) * (1.0 - fi),
            fj * (1.0 - fi),
            (1.0 - fj) * fi,
            fj * fi,
        ],
    )
}

/// Resamples a Cassini colour image to ERP on `grid` (bilinear).
pub fn cassini_to_erp_rgb(cassini: &RgbImage, grid: ErpGrid) -> RgbImage {
    let (cw, ch) = (cassini.width() as usize, cassini.height() as usize);
    let src = cassini.as_raw();
    let mut out = RgbImage::new(grid.width() as u32, grid.height() as u32);
    for (v, row) in out.chunks_mut(grid.width() * 3).enumerate() {
        for (u, px) in row.chunks_mut(3).enumerate() {
            let dir = grid.dir_from_pixel(PixelCoord {
                u: u as f64,
                v: v as f64,
            });
            let (idx, wt) = cassini_taps(cassini_from_dir(&dir, cw, ch), cw, ch);
            for (c, out_c) in px.iter_mut().enumerate() {
                let s: f32 = idx
                    .iter()
                    .zip(wt)
                    .map(|(&i, w)| f32::from(src[i * 3 + c]) * w)
                    .sum();
                *out_c = s.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// Nearest Cassini pixel index for a continuous position (rows wrap, columns clamp).
fn cassini_nearest(c: CassiniCoord, width: usize, height: usize) -> usize {
    let j = (c.col.round() as i64).clamp(0, width as i64 - 1);
    let i = (c.row.round() as i64).rem_euclid(height as i64);
    (i * width as i64 + j) as usize
}

/// Resamples a Cassini range image to ERP on `grid` (nearest neighbour). The ray directions
/// are the same, so range values carry over unchanged.
pub fn cassini_to_erp_range(cassini: &FloatImage, grid: ErpGrid) -> FloatImage {
    let mut out = FloatImage::filled(grid.width(), grid.height(), f32::NAN);
    for v in 0..grid.height() {
        for u in 0..grid.width() {
            let dir = grid.dir_from_pixel(PixelCoord {
                u: u as f64,
                v: v as f64,
            });
            let c = cassini_from_dir(&dir, cassini.width, cassini.height);
            out.data[v * grid.width() + u] =
                cassini.data[cassini_nearest(c, cassini.width, cassini.height)];
        }
    }
    out
}

/// Resamples an ERP colour image to a `width x height` Cassini image (bilinear, ERP seam
/// wraps). Used to write Deep360-style fixtures.
pub fn erp_to_cassini_rgb(erp: &RgbImage, width: usize, height: usize) -> RgbImage {
    let grid_w = erp.width() as usize;
    let grid = match ErpGrid::new(grid_w) {
        Ok(g) => g,
        Err(_) => return RgbImage::new(width as u32, height as u32),
    };
    let src = erp.as_raw();
    let mut out = RgbImage::new(width as u32, height as u32);
    for (i, row) in out.chunks_mut(width * 3).enumerate() {
        for (j, px) in row.chunks_mut(3).enumerate() {
            let dir = cassini_dir(
                CassiniCoord {
                    col: j as f64,
                    row: i as f64,
                },
                width,
                height,
            );
            let taps = grid.bilinear_taps(grid.pixel_from_dir(&dir));
            for (c, out_c) in px.iter_mut().enumerate() {
                let s: f32 = taps
                    .index
                    .iter()
                    .zip(taps.weight)
                    .map(|(&k, w)| f32::from(src[k as usize * 3 + c]) * w)
                    .sum();
                *out_c = s.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// Resamples an ERP range image to a `width x height` Cassini image (nearest neighbour).
pub fn erp_to_cassini_range(erp: &FloatImage, width: usize, height: usize) -> FloatImage {
    let mut out = FloatImage::filled(width, height, f32::NAN);
    let Ok(grid) = ErpGrid::new(erp.width) else {
        return out;
    };
    for i in 0..height {
        for j in 0..width {
            let dir = cassini_dir(
                CassiniCoord {
                    col: j as f64,
                    row: i as f64,
                },
                width,
                height,
            );
            let p = grid.pixel_from_dir(&dir);
            let u = (p.u.round() as i64).rem_euclid(erp.width as i64) as usize;
            let v = (p.v.round() as i64).clamp(0, erp.height as i64 - 1) as usize;
            out.data[i * width + j] = erp.get(u, v);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cassini_direction_round_trip() {
        for &(col, row) in &[(0.0, 0.0), (100.3, 700.2), (511.0, 1023.0), (256.0, 512.0)] {
            let c = CassiniCoord { col, row };
            let d = cassini_dir(c, CASSINI_WIDTH, CASSINI_HEIGHT);
            let back = cassini_from_dir(&d, CASSINI_WIDTH, CASSINI_HEIGHT);
            assert!((back.col - col).abs() < 1e-6, "{back:?} vs {c:?}");
            let drow = (back.row - row).rem_euclid(CASSINI_HEIGHT as f64);
            assert!(drow < 1e-6 || CASSINI_HEIGHT as f64 - drow < 1e-6);
        }
        // Centre row (theta = 0) centre column (phi = 0) looks forward (+x in REP 103).
        let fwd = cassini_from_dir(&Vector3::new(1.0, 0.0, 0.0), CASSINI_WIDTH, CASSINI_HEIGHT);
        assert!((fwd.col - (CASSINI_WIDTH as f64 / 2.0 - 0.5)).abs() < 1e-9);
        assert!((fwd.row - (CASSINI_HEIGHT as f64 / 2.0 - 0.5)).abs() < 1e-9);
        // Column 0 edge (phi = pi/2) looks left (+y).
        let left = cassini_from_dir(&Vector3::new(0.0, 1.0, 0.0), CASSINI_WIDTH, CASSINI_HEIGHT);
        assert!((left.col + 0.5).abs() < 1e-9);
    }
}
