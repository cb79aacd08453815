//! An ERP panorama seen from a rotated frame at the same centre ([`ErpRotation`]): PSMODE's
//! first stage turns each camera's panorama into its pair's epipolar frame with it.
//!
//! For a pixel `p` of the destination grid, `src(src_from_dst dir_dst(p))` is sampled
//! bilinearly (longitude wraps, latitude clamps).

use super::erp::{BilinearTaps, ErpGrid, PixelCoord};
use super::GeometryError;
use image::RgbImage;
use nalgebra::Rotation3;
use rayon::prelude::*;

/// RGB channels.
const RGB: usize = 3;

/// The bilinear taps of a rotated ERP resampling, built once per pair of grids and rotation.
#[derive(Clone, Debug)]
pub struct ErpRotation {
    src: ErpGrid,
    dst: ErpGrid,
    /// Per destination pixel (row-major), the taps into the source.
    taps: Vec<BilinearTaps>,
}

impl ErpRotation {
    /// Taps of `dst(p) = src(src_from_dst dir_dst(p))`.
    pub fn new(src: ErpGrid, dst: ErpGrid, src_from_dst: &Rotation3<f64>) -> Self {
        let taps = (0..dst.len())
            .into_par_iter()
            .with_min_len(dst.width())
            .map(|k| {
                let p = PixelCoord {
                    u: (k % dst.width()) as f64,
                    v: (k / dst.width()) as f64,
                };
                src.bilinear_taps(src.pixel_from_dir(&(src_from_dst * dst.dir_from_pixel(p))))
            })
            .collect();
        Self { src, dst, taps }
    }

    pub fn source(&self) -> ErpGrid {
        self.src
    }

    pub fn destination(&self) -> ErpGrid {
        self.dst
    }

    /// `channels`-interleaved row-major values on the source grid, resampled.
    pub fn apply(&self, values: &[f32], channels: usize) -> Result<Vec<f32>, GeometryError> {
        if values.len() != self.src.len() * channels {
            return Err(GeometryError::WrongImageSize {
                expected: (self.src.width() * channels, self.src.height()),
                got: (values.len() / self.src.height().max(1), self.src.height()),
            });
        }
        let mut out = vec![0.0f32; self.dst.len() * channels];
        out.par_chunks_mut(channels)
            .zip(self.taps.par_iter())
            .for_each(|(px, t)| {
                for (&i, &w) in t.index.iter().zip(&t.weight) {
                    let s = i as usize * channels;
                    for (c, o) in px.iter_mut().enumerate() {
                        *o += w * values[s + c];
                    }
                }
            });
        Ok(out)
    }

    /// An RGB panorama on the source grid, resampled.
    pub fn apply_rgb(&self, image: &RgbImage) -> Result<RgbImage, GeometryError> {
        let got = (image.width() as usize, image.height() as usize);
        if got != (self.src.width(), self.src.height()) {
            return Err(GeometryError::WrongImageSize {
                expected: (self.src.width(), self.src.height()),
                got,
            });
        }
        let src = image.as_raw();
        let mut out = vec![0u8; self.dst.len() * RGB];
        out.par_chunks_mut(RGB)
            .zip(self.taps.par_iter())
            .for_each(|(px, t)| {
                for (c, o) in px.iter_mut().enumerate() {
                    let v: f32 = t
                        .index
                        .iter()
                        .zip(&t.weight)
                        .map(|(&i, &w)| w * f32::from(src[i as usize * RGB + c]))
                        .sum();
                    *o = v.round().clamp(0.0, 255.0) as u8;
                }
            });
        RgbImage::from_raw(self.dst.width() as u32, self.dst.height() as u32, out).ok_or(
            GeometryError::WrongImageSize {
                expected: (self.dst.width(), self.dst.height()),
                got: (0, 0),
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// A smooth function of direction, so bilinear resampling error stays small.
    fn field(d: &Vector3<f64>) -> f32 {
        (0.5 + 0.3 * d.x + 0.2 * d.y * d.z) as f32
    }

    fn sampled(grid: ErpGrid) -> Vec<f32> {
        (0..grid.len())
            .map(|k| {
                field(&grid.dir_from_pixel(PixelCoord {
                    u: (k % grid.width()) as f64,
                    v: (k / grid.width()) as f64,
                }))
            })
            .collect()
    }

    #[test]
    fn a_rotated_panorama_shows_each_direction_where_the_rotation_says() {
        let src = ErpGrid::new(256).unwrap();
        let dst = ErpGrid::new(128).unwrap();
        let src_from_dst = Rotation3::from_euler_angles(0.4, -1.1, 2.0);
        let rot = ErpRotation::new(src, dst, &src_from_dst);
        let out = rot.apply(&sampled(src), 1).unwrap();
        let mut worst = 0.0f32;
        for (k, got) in out.iter().enumerate() {
            let p = PixelCoord {
                u: (k % dst.width()) as f64,
                v: (k / dst.width()) as f64,
            };
            let want = field(&(src_from_dst * dst.dir_from_pixel(p)));
            worst = worst.max((got - want).abs());
        }
        assert!(worst < 0.01, "worst error {worst}");
        // the identity at equal grids is the image itself
        let same = ErpRotation::new(dst, dst, &Rotation3::identity());
        let values = sampled(dst);
        let back = same.apply(&values, 1).unwrap();
        let diff = back
            .iter()
            .zip(&values)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(diff < 1e-5, "identity differs by {diff}");
        assert!(rot.apply(&values, 1).is_err(), "wrong size accepted");
    }
}
