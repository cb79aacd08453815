//! The network's input: the one place where camera images become what SSMODE reads
//! (training, inference, the benches and the tests all call [`input_tensor`]).
//!
//! ```text
//! RgbImage (W x H, 8-bit) -> [0, 1] f32 -> bilinear ERP resampling to the network width -> (1, h, w, 3)
//! ```

use candle_core::{Device, Tensor};

use super::ModelError;
use crate::matching::INTENSITY_SCALE;
use mode360_core::frame::RgbImage;
use mode360_core::geometry::{resample_erp, ErpGrid};

/// Channels of an RGB pixel.
pub const RGB_CHANNELS: usize = 3;

/// `(1, width / 2, width, 3)` f32 tensor in `[0, 1]` on `device` from an 8-bit ERP image,
/// resampled bilinearly (longitude wraps, latitude clamps) when the image is not `width` wide.
/// An image that is not twice as wide as tall, or of odd width, is an error.
pub fn input_tensor(img: &RgbImage, width: usize, device: &Device) -> Result<Tensor, ModelError> {
    let (w, h) = img.dimensions();
    let bad = || ModelError::BadImage {
        width: w,
        height: h,
    };
    if w != 2 * h {
        return Err(bad());
    }
    let src = ErpGrid::new(w as usize).map_err(|_| bad())?;
    let dst = ErpGrid::new(width)?;
    let rgb: Vec<f32> = img
        .as_raw()
        .iter()
        .map(|&b| f32::from(b) * INTENSITY_SCALE)
        .collect();
    let data = resample_erp(&rgb, RGB_CHANNELS, src, dst);
    Ok(Tensor::from_vec(
        data,
        (1, dst.height(), dst.width(), RGB_CHANNELS),
        device,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_scale_to_unit_range_and_resample_to_the_network_width() {
        let img = RgbImage::from_fn(8, 4, |u, v| {
            image::Rgb([(u * 30) as u8, (v * 60) as u8, 255])
        });
        let t = input_tensor(&img, 8, &Device::Cpu).unwrap();
        assert_eq!(t.dims(), &[1, 4, 8, 3]);
        let v: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
        // pixel (u 3, v 2): 90, 120, 255
        let o = (2 * 8 + 3) * 3;
        for (got, want) in v[o..o + 3].iter().zip([90.0, 120.0, 255.0]) {
            assert!((got - want / 255.0).abs() < 1e-6, "{got} vs {want} / 255");
        }
        // half width: each output pixel averages a 2x2 block (centres aligned)
        let half = input_tensor(&img, 4, &Device::Cpu).unwrap();
        assert_eq!(half.dims(), &[1, 2, 4, 3]);
        let h: Vec<f32> = half.flatten_all().unwrap().to_vec1().unwrap();
        // output (u 1, v 0) covers source u 2..3, v 0..1: red (60 + 90) / 2, green (0 + 60) / 2
        let o = 3;
        assert!((h[o] - 75.0 / 255.0).abs() < 1e-6, "{}", h[o]);
        assert!((h[o + 1] - 30.0 / 255.0).abs() < 1e-6, "{}", h[o + 1]);
        let e = input_tensor(&RgbImage::new(8, 3), 8, &Device::Cpu)
            .unwrap_err()
            .to_string();
        assert!(e.contains("8x3"), "{e}");
    }
}
