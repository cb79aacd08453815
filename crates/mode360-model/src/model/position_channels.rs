//! SSMODE's position channels ([`SsmodeConfig::position_channels`], a departure from the
//! paper): two cost-volume channels that say where a cell lies, so that the aggregation can
//! learn a prior for the cells where the views give no evidence.
//!
//! A 3-D convolution is the same at every sphere and every latitude, so without them the
//! network has no way to prefer one hypothesis over another where the matching evidence is flat:
//! near an epipole (the zenith of a vertical camera pair, where no depth moves a point in any
//! view) or on a textureless floor. There it answers the middle of its range. The learning-free
//! sweep breaks such ties towards the far plane; these channels let the network learn its own
//! tie-break from the scenes (sky above, ground below), and only where the evidence leaves it
//! free: they are the same for every scene, so they carry nothing of what a panorama looks
//! like (the geometry share still measures that).
//!
//! For sphere `d` of `D` (0 the farthest) and cost cell row `v` of `h`:
//!
//! ```text
//! channel 0 = 2 d / (D - 1) - 1            in [-1, 1]: -1 the farthest sphere, 1 the nearest
//! channel 1 = sin(lat_v),  lat_v = pi / 2 - pi (v + 0.5) / h      1 up, -1 down
//! ```
//!
//! They are appended after the other cost-volume channels, `(B, D, h, w, 2)`.
//!
//! [`SsmodeConfig::position_channels`]: super::config::SsmodeConfig::position_channels

use candle_core::{Device, Result, Tensor};

/// Channels this stage appends.
pub const POSITION_CHANNELS: usize = 2;

/// The position channels `(batch, spheres, height, width, 2)` on `device`.
pub fn position_channels(
    batch: usize,
    spheres: usize,
    height: usize,
    width: usize,
    device: &Device,
) -> Result<Tensor> {
    let sphere_position = |d: usize| -> f32 {
        if spheres > 1 {
            (2.0 * d as f64 / (spheres - 1) as f64 - 1.0) as f32
        } else {
            0.0
        }
    };
    let sin_latitude = |v: usize| -> f32 {
        let lat =
            std::f64::consts::FRAC_PI_2 - std::f64::consts::PI * (v as f64 + 0.5) / height as f64;
        lat.sin() as f32
    };
    let mut data = Vec::with_capacity(batch * spheres * height * width * POSITION_CHANNELS);
    for _ in 0..batch {
        for d in 0..spheres {
            let p = sphere_position(d);
            for v in 0..height {
                let s = sin_latitude(v);
                for _ in 0..width {
                    data.push(p);
                    data.push(s);
                }
            }
        }
    }
    Tensor::from_vec(
        data,
        (batch, spheres, height, width, POSITION_CHANNELS),
        device,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channels_span_spheres_and_latitude() -> Result<()> {
        let t = position_channels(1, 5, 4, 8, &Device::Cpu)?;
        assert_eq!(t.dims(), &[1, 5, 4, 8, 2]);
        let v: Vec<f32> = t.flatten_all()?.to_vec1()?;
        let at =
            |d: usize, row: usize, col: usize, c: usize| v[(((d * 4) + row) * 8 + col) * 2 + c];
        assert_eq!(at(0, 0, 0, 0), -1.0);
        assert_eq!(at(4, 3, 7, 0), 1.0);
        assert_eq!(at(2, 1, 3, 0), 0.0);
        // Row 0 of 4 looks up at latitude 67.5 degrees, row 3 down at -67.5.
        let expected = (67.5f64).to_radians().sin() as f32;
        assert!((at(1, 0, 5, 1) - expected).abs() < 1e-6);
        assert!((at(1, 3, 5, 1) + expected).abs() < 1e-6);
        Ok(())
    }
}
