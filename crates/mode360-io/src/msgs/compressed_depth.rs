//! image_transport's `compressedDepth` codec for 32FC1 depth (what
//! `compressed_depth_image_transport` publishes on `<topic>/compressedDepth`).
//!
//! A `sensor_msgs/CompressedImage` with `format` = `"32FC1; compressedDepth png"` whose `data`
//! is a 12-byte little-endian header, `int32 compressionFormat` (0: inverse depth) and
//! `float32 depthParam[2]` = `(A, B)`, then a 16-bit grayscale PNG of quantized inverse depth:
//!
//! `A = Q (Q + 1)`, `B = 1 - A / d_max`, `q = A / d + B` for `0 < d < d_max`, else `q = 0`;
//! decoded `d = A / (q - B)` for `q > 0`, NaN for `q = 0`.
//!
//! With `Q` = [`DEFAULT_DEPTH_QUANTIZATION`] the step at range `d` is about `d^2 / A` (1 cm at
//! 10 m, 1 m at 100 m), and ranges below `A / (65535 - B)` do not fit. Only finite ranges
//! below `d_max` survive: `+Inf` (beyond range) and NaN (invalid) both decode as NaN, since the
//! format has one "no value" code.

use super::{CompressedImage, Header};
use image::{ImageBuffer, Luma};
use mode360_core::frame::FloatImage;

/// A compressedDepth message that cannot be written or read.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CompressedDepthError {
    #[error("format '{format}' is not 32FC1 compressedDepth")]
    Format { format: String },
    #[error("data of {len} bytes has no {HEADER_BYTES}-byte header")]
    Header { len: usize },
    #[error("compressionFormat {0} is not inverse depth (0)")]
    CompressionFormat(i32),
    #[error("depth PNG: {0}")]
    Png(String),
    #[error("{width}x{height} range image holds {len} values")]
    Size {
        width: usize,
        height: usize,
        len: usize,
    },
}

/// `compressionFormat` of inverse-depth quantization.
pub const INV_DEPTH_FORMAT: i32 = 0;
/// Bytes before the PNG.
pub const HEADER_BYTES: usize = 12;
/// The `format` string of 32FC1 depth compressed with PNG.
pub const COMPRESSED_DEPTH_FORMAT: &str = "32FC1; compressedDepth png";
/// image_transport's default depth quantization `Q`.
pub const DEFAULT_DEPTH_QUANTIZATION: f32 = 100.0;
/// Largest quantized value.
const MAX_CODE: f32 = u16::MAX as f32;

/// Quantization constants `(A, B)` for quantization `q` and maximum range `depth_max_m`.
pub fn quantization_params(quantization: f32, depth_max_m: f32) -> (f32, f32) {
    let a = quantization * (quantization + 1.0);
    (a, 1.0 - a / depth_max_m)
}

/// Encodes `range` (metres, REP 117) as a compressedDepth message.
pub fn encode_compressed_depth(
    header: Header,
    range: &FloatImage,
    quantization: f32,
    depth_max_m: f32,
) -> Result<CompressedImage, CompressedDepthError> {
    let (a, b) = quantization_params(quantization, depth_max_m);
    let codes: Vec<u16> = range
        .data
        .iter()
        .map(|&d| {
            if d.is_finite() && d > 0.0 && d < depth_max_m {
                (a / d + b).round().clamp(1.0, MAX_CODE) as u16
            } else {
                0
            }
        })
        .collect();
    let img: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(range.width as u32, range.height as u32, codes).ok_or(
            CompressedDepthError::Size {
                width: range.width,
                height: range.height,
                len: range.data.len(),
            },
        )?;
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| CompressedDepthError::Png(e.to_string()))?;
    let mut data = Vec::with_capacity(HEADER_BYTES + png.get_ref().len());
    data.extend_from_slice(&INV_DEPTH_FORMAT.to_le_bytes());
    data.extend_from_slice(&a.to_le_bytes());
    data.extend_from_slice(&b.to_le_bytes());
    data.extend_from_slice(png.get_ref());
    Ok(CompressedImage {
        header,
        format: COMPRESSED_DEPTH_FORMAT.into(),
        data,
    })
}

/// Decodes a compressedDepth message back to ranges in metres (NaN where no value).
pub fn decode_compressed_depth(msg: &CompressedImage) -> Result<FloatImage, CompressedDepthError> {
    if !msg.format.contains("compressedDepth") || !msg.format.starts_with("32FC1") {
        return Err(CompressedDepthError::Format {
            format: msg.format.clone(),
        });
    }
    if msg.data.len() < HEADER_BYTES {
        return Err(CompressedDepthError::Header {
            len: msg.data.len(),
        });
    }
    let word = |k: usize| {
        let o = 4 * k;
        [
            msg.data[o],
            msg.data[o + 1],
            msg.data[o + 2],
            msg.data[o + 3],
        ]
    };
    let format = i32::from_le_bytes(word(0));
    if format != INV_DEPTH_FORMAT {
        return Err(CompressedDepthError::CompressionFormat(format));
    }
    let (a, b) = (f32::from_le_bytes(word(1)), f32::from_le_bytes(word(2)));
    let png =
        image::load_from_memory_with_format(&msg.data[HEADER_BYTES..], image::ImageFormat::Png)
            .map_err(|e| CompressedDepthError::Png(e.to_string()))?
            .into_luma16();
    let (w, h) = (png.width() as usize, png.height() as usize);
    let data = png
        .into_raw()
        .into_iter()
        .map(|q| {
            if q == 0 {
                f32::NAN
            } else {
                a / (f32::from(q) - b)
            }
        })
        .collect();
    Ok(FloatImage {
        width: w,
        height: h,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_within_one_quantization_step() {
        let max = 1000.0;
        let (a, _) = quantization_params(DEFAULT_DEPTH_QUANTIZATION, max);
        let mut range = FloatImage::filled(8, 4, 0.0);
        let values = [0.5, 1.0, 3.3, 10.0, 57.0, 250.0, 999.0];
        for (k, v) in values.iter().enumerate() {
            range.data[k] = *v;
        }
        range.data[10] = f32::INFINITY;
        range.data[11] = f32::NAN;
        range.data[12] = 1500.0;
        let msg = encode_compressed_depth(
            Header::new(7, "base_link"),
            &range,
            DEFAULT_DEPTH_QUANTIZATION,
            max,
        )
        .unwrap();
        assert_eq!(msg.format, COMPRESSED_DEPTH_FORMAT);
        assert_eq!(i32::from_le_bytes(msg.data[..4].try_into().unwrap()), 0);
        let back = decode_compressed_depth(&msg).unwrap();
        assert_eq!((back.width, back.height), (8, 4));
        for (k, v) in values.iter().enumerate() {
            // half a code step: d^2 / (2 A), plus f32 rounding
            let tol = v * v / (2.0 * a) * 1.01 + 1e-4;
            assert!((back.data[k] - v).abs() <= tol, "{v} -> {}", back.data[k]);
        }
        assert!(back.data[10].is_nan() && back.data[11].is_nan() && back.data[12].is_nan());
        assert!(back.data[13].is_nan(), "0 m is no measurement");
        let mut wrong = msg.clone();
        wrong.format = "png".into();
        assert!(decode_compressed_depth(&wrong).is_err());
    }
}
