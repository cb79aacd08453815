//! Conversions between `sensor_msgs` images and mode360's in-memory images.
//!
//! An `Image` holds `height` rows of `step` bytes; row `v` starts at byte `v * step` and
//! its pixel `u` at `v * step + u * bytes_per_pixel`, so `step >= width * bytes_per_pixel`
//! (the rest of a row is padding) and `data.len() == height * step` (the size the message
//! definition gives; more data means width, height or step do not describe it).

use super::types::{CompressedImage, Header, Image};
use mode360_core::frame::{FloatImage, RgbImage};

/// `sensor_msgs/image_encodings` names used here.
pub mod encodings {
    pub const RGB8: &str = "rgb8";
    pub const BGR8: &str = "bgr8";
    pub const RGBA8: &str = "rgba8";
    pub const BGRA8: &str = "bgra8";
    pub const MONO8: &str = "mono8";
    pub const TYPE_32FC1: &str = "32FC1";
    pub const TYPE_8UC1: &str = "8UC1";
    pub const TYPE_16UC1: &str = "16UC1";
}

/// Colour encodings [`rgb_from_image_msg`] accepts.
pub const ACCEPTED_COLOUR_ENCODINGS: &str = "rgb8, bgr8, rgba8, bgra8, mono8";
/// Bytes of one 32FC1 pixel.
const FLOAT_BYTES: usize = std::mem::size_of::<f32>();
/// Bytes of one rgb8 pixel.
const RGB_BYTES: usize = 3;

/// An image message that cannot be converted.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ImageMsgError {
    #[error("unsupported encoding '{encoding}' (expected one of: {expected})")]
    UnsupportedEncoding {
        encoding: String,
        expected: &'static str,
    },
    #[error(
        "step {step} is smaller than width {width} x {bytes_per_pixel} bytes per pixel \
         for encoding '{encoding}'"
    )]
    StepTooSmall {
        encoding: String,
        step: u32,
        width: u32,
        bytes_per_pixel: usize,
    },
    #[error(
        "data holds {actual} bytes but height {height} x step {step} needs {expected} \
         (encoding '{encoding}'): truncated"
    )]
    DataTooShort {
        encoding: String,
        height: u32,
        step: u32,
        expected: usize,
        actual: usize,
    },
    #[error(
        "data holds {actual} bytes but height {height} x step {step} is {expected} \
         (encoding '{encoding}'): height or step do not describe the data"
    )]
    DataTooLong {
        encoding: String,
        height: u32,
        step: u32,
        expected: usize,
        actual: usize,
    },
    #[error("image of {width}x{height} is too large to address")]
    TooLarge { width: u64, height: u64 },
    #[error(
        "{format} data ({len} bytes) decodes to {width}x{height}, more than the {max_pixels} \
         pixels accepted (refused before decoding)"
    )]
    TooManyPixels {
        format: String,
        len: usize,
        width: u32,
        height: u32,
        max_pixels: u64,
    },
    #[error("compressed format '{format}' is not supported (expected jpeg or png)")]
    UnsupportedFormat { format: String },
    #[error("cannot decode {format} data ({len} bytes): {message}")]
    Decode {
        format: String,
        len: usize,
        message: String,
    },
}

/// Where each output channel comes from in a source pixel.
#[derive(Clone, Copy, Debug)]
struct ColourLayout {
    bytes_per_pixel: usize,
    /// Source byte offsets of red, green and blue.
    rgb_offsets: [usize; 3],
}

fn colour_layout(encoding: &str) -> Option<ColourLayout> {
    let layout = |bytes_per_pixel, rgb_offsets| {
        Some(ColourLayout {
            bytes_per_pixel,
            rgb_offsets,
        })
    };
    match encoding {
        encodings::RGB8 => layout(3, [0, 1, 2]),
        encodings::BGR8 => layout(3, [2, 1, 0]),
        encodings::RGBA8 => layout(4, [0, 1, 2]),
        encodings::BGRA8 => layout(4, [2, 1, 0]),
        encodings::MONO8 => layout(1, [0, 0, 0]),
        _ => None,
    }
}

/// Checks `step` and the data length against `width`, `height` and `bytes_per_pixel`:
/// `step >= width * bytes_per_pixel` and `data.len() == height * step`.
pub(super) fn check_layout(msg: &Image, bytes_per_pixel: usize) -> Result<(), ImageMsgError> {
    let too_large = || ImageMsgError::TooLarge {
        width: u64::from(msg.width),
        height: u64::from(msg.height),
    };
    let row_bytes = (msg.width as usize)
        .checked_mul(bytes_per_pixel)
        .ok_or_else(too_large)?;
    if (msg.step as usize) < row_bytes {
        return Err(ImageMsgError::StepTooSmall {
            encoding: msg.encoding.clone(),
            step: msg.step,
            width: msg.width,
            bytes_per_pixel,
        });
    }
    let expected = (msg.height as usize)
        .checked_mul(msg.step as usize)
        .ok_or_else(too_large)?;
    if msg.data.len() < expected {
        return Err(ImageMsgError::DataTooShort {
            encoding: msg.encoding.clone(),
            height: msg.height,
            step: msg.step,
            expected,
            actual: msg.data.len(),
        });
    }
    if msg.data.len() > expected {
        return Err(ImageMsgError::DataTooLong {
            encoding: msg.encoding.clone(),
            height: msg.height,
            step: msg.step,
            expected,
            actual: msg.data.len(),
        });
    }
    Ok(())
}

/// `u32` form of an image dimension (saturating; real images are far smaller).
pub(super) fn dim_u32(value: usize) -> u32 {
    u32::try_from(value).unwrap_or(u32::MAX)
}

/// An rgb8 message of `image`: `step = 3 * width`, no padding.
pub fn image_msg_from_rgb(header: Header, image: &RgbImage) -> Image {
    Image {
        header,
        height: image.height(),
        width: image.width(),
        encoding: encodings::RGB8.to_string(),
        is_bigendian: 0,
        step: image.width().saturating_mul(RGB_BYTES as u32),
        data: image.as_raw().clone(),
    }
}

/// The RGB image of an rgb8, bgr8, rgba8, bgra8 (alpha dropped) or mono8 (grey copied to
/// all three channels) message, honouring row padding (`step`). `is_bigendian` does not
/// matter for 8-bit channels.
pub fn rgb_from_image_msg(msg: &Image) -> Result<RgbImage, ImageMsgError> {
    let layout =
        colour_layout(&msg.encoding).ok_or_else(|| ImageMsgError::UnsupportedEncoding {
            encoding: msg.encoding.clone(),
            expected: ACCEPTED_COLOUR_ENCODINGS,
        })?;
    check_layout(msg, layout.bytes_per_pixel)?;
    let (width, height) = (msg.width as usize, msg.height as usize);
    let mut rgb = Vec::with_capacity(width * height * RGB_BYTES);
    for row in msg.data.chunks(msg.step.max(1) as usize).take(height) {
        for pixel in row[..width * layout.bytes_per_pixel].chunks_exact(layout.bytes_per_pixel) {
            rgb.extend(layout.rgb_offsets.iter().map(|&i| pixel[i]));
        }
    }
    RgbImage::from_raw(msg.width, msg.height, rgb).ok_or(ImageMsgError::TooLarge {
        width: u64::from(msg.width),
        height: u64::from(msg.height),
    })
}

/// A 32FC1 little-endian message of `image`: `step = 4 * width`.
pub fn image_msg_from_float(header: Header, image: &FloatImage) -> Image {
    Image {
        header,
        height: dim_u32(image.height),
        width: dim_u32(image.width),
        encoding: encodings::TYPE_32FC1.to_string(),
        is_bigendian: 0,
        step: dim_u32(image.width.saturating_mul(FLOAT_BYTES)),
        data: image.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

/// The float image of a 32FC1 message (little or big endian as `is_bigendian` says),
/// honouring row padding.
pub fn float_from_image_msg(msg: &Image) -> Result<FloatImage, ImageMsgError> {
    if msg.encoding != encodings::TYPE_32FC1 {
        return Err(ImageMsgError::UnsupportedEncoding {
            encoding: msg.encoding.clone(),
            expected: encodings::TYPE_32FC1,
        });
    }
    check_layout(msg, FLOAT_BYTES)?;
    let (width, height) = (msg.width as usize, msg.height as usize);
    let big_endian = msg.is_bigendian != 0;
    let mut data = Vec::with_capacity(width * height);
    for row in msg.data.chunks(msg.step.max(1) as usize).take(height) {
        for bytes in row[..width * FLOAT_BYTES].chunks_exact(FLOAT_BYTES) {
            let raw = [bytes[0], bytes[1], bytes[2], bytes[3]];
            data.push(if big_endian {
                f32::from_be_bytes(raw)
            } else {
                f32::from_le_bytes(raw)
            });
        }
    }
    Ok(FloatImage {
        width,
        height,
        data,
    })
}

/// The codec named in a `CompressedImage.format` such as `jpeg`, `png` or
/// `rgb8; jpeg compressed bgr8` (image_transport's form: the codec follows the `;`).
fn compressed_codec(format: &str) -> Option<image::ImageFormat> {
    let codec_part = format
        .rsplit(';')
        .next()
        .unwrap_or(format)
        .to_ascii_lowercase();
    let words: Vec<&str> = codec_part.split_whitespace().collect();
    if words.contains(&"compresseddepth") {
        return None;
    }
    if words.iter().any(|w| *w == "jpeg" || *w == "jpg") {
        Some(image::ImageFormat::Jpeg)
    } else if words.contains(&"png") {
        Some(image::ImageFormat::Png)
    } else {
        None
    }
}

/// Most pixels a compressed image may decode to by default: a 8192x4096 panorama (a PNG or
/// JPEG of a few hundred kilobytes can claim gigabytes).
pub const MAX_DECODED_PIXELS: u64 = 8192 * 4096;
/// Bytes a decoder may allocate per decoded pixel (16-bit RGBA, the widest these codecs give).
const MAX_DECODER_BYTES_PER_PIXEL: u64 = 8;

fn decode_err(msg: &CompressedImage) -> impl Fn(image::ImageError) -> ImageMsgError + '_ {
    move |err| ImageMsgError::Decode {
        format: msg.format.clone(),
        len: msg.data.len(),
        message: err.to_string(),
    }
}

fn compressed_reader(
    msg: &CompressedImage,
) -> Result<image::ImageReader<std::io::Cursor<&[u8]>>, ImageMsgError> {
    let codec = compressed_codec(&msg.format).ok_or_else(|| ImageMsgError::UnsupportedFormat {
        format: msg.format.clone(),
    })?;
    let mut reader = image::ImageReader::new(std::io::Cursor::new(msg.data.as_slice()));
    reader.set_format(codec);
    Ok(reader)
}

/// The width and height a jpeg or png `CompressedImage` declares, read from its header
/// without decoding the pixels.
pub fn compressed_dimensions(msg: &CompressedImage) -> Result<(u32, u32), ImageMsgError> {
    compressed_reader(msg)?
        .into_dimensions()
        .map_err(decode_err(msg))
}

/// Decodes a jpeg or png `CompressedImage` to RGB (grey images are expanded, alpha dropped,
/// 16-bit channels scaled to 8 bits), refusing before decoding one that declares more than
/// [`MAX_DECODED_PIXELS`].
pub fn rgb_from_compressed(msg: &CompressedImage) -> Result<RgbImage, ImageMsgError> {
    rgb_from_compressed_within(msg, MAX_DECODED_PIXELS)
}

/// [`rgb_from_compressed`] with at most `max_pixels`: the header's size is checked first and
/// the decoder may not allocate more than that many pixels need.
pub fn rgb_from_compressed_within(
    msg: &CompressedImage,
    max_pixels: u64,
) -> Result<RgbImage, ImageMsgError> {
    let (width, height) = compressed_dimensions(msg)?;
    if u64::from(width) * u64::from(height) > max_pixels {
        return Err(ImageMsgError::TooManyPixels {
            format: msg.format.clone(),
            len: msg.data.len(),
            width,
            height,
            max_pixels,
        });
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(width);
    limits.max_image_height = Some(height);
    limits.max_alloc = Some(max_pixels.saturating_mul(MAX_DECODER_BYTES_PER_PIXEL));
    let mut reader = compressed_reader(msg)?;
    reader.limits(limits);
    reader
        .decode()
        .map(|decoded| decoded.to_rgb8())
        .map_err(decode_err(msg))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> Header {
        Header::new(1_500_000_000, "cam")
    }

    /// CRC-32 (ISO-HDLC, as PNG chunks use), bit by bit.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = 0xFFFF_FFFFu32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    /// A valid 2x1 PNG whose IHDR is rewritten to claim `width` x `height` (CRC fixed).
    fn png_claiming(width: u32, height: u32) -> Vec<u8> {
        let mut png = Vec::new();
        RgbImage::new(2, 1)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        // Signature (8), IHDR length (4), "IHDR" (4), width (4), height (4), ... CRC after
        // the 13 data bytes.
        png[16..20].copy_from_slice(&width.to_be_bytes());
        png[20..24].copy_from_slice(&height.to_be_bytes());
        let crc = crc32(&png[12..29]);
        png[29..33].copy_from_slice(&crc.to_be_bytes());
        png
    }

    #[test]
    fn a_compressed_bomb_is_refused_before_decoding() {
        let msg = CompressedImage {
            header: header(),
            format: "png".into(),
            data: png_claiming(20_000, 10_000),
        };
        assert_eq!(compressed_dimensions(&msg), Ok((20_000, 10_000)));
        let err = rgb_from_compressed(&msg).unwrap_err();
        assert!(
            matches!(
                err,
                ImageMsgError::TooManyPixels {
                    width: 20_000,
                    height: 10_000,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("refused before decoding"), "{err}");
        // A small limit refuses a real image too; the untouched 2x1 PNG decodes.
        let small = CompressedImage {
            data: png_claiming(2, 1),
            ..msg
        };
        assert!(rgb_from_compressed_within(&small, 1).is_err());
        assert_eq!(
            rgb_from_compressed(&small).map(|i| i.dimensions()),
            Ok((2, 1))
        );
    }

    #[test]
    fn bgra_with_padding_reads_right_pixels() {
        // 2x2 bgra8 image, step 10 (2 padding bytes a row).
        let data = vec![
            1, 2, 3, 255, 4, 5, 6, 255, 99, 99, //
            7, 8, 9, 255, 10, 11, 12, 255, 99, 99,
        ];
        let msg = Image {
            header: header(),
            height: 2,
            width: 2,
            encoding: "bgra8".into(),
            is_bigendian: 0,
            step: 10,
            data,
        };
        let rgb = rgb_from_image_msg(&msg).map_err(|e| e.to_string());
        assert_eq!(
            rgb.map(|img| img.into_raw()),
            Ok(vec![3, 2, 1, 6, 5, 4, 9, 8, 7, 12, 11, 10])
        );
    }

    #[test]
    fn mono_expands_and_short_data_is_rejected() {
        let mut msg = Image {
            header: header(),
            height: 1,
            width: 3,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 3,
            data: vec![10, 20, 30],
        };
        assert_eq!(
            rgb_from_image_msg(&msg).map(|i| i.into_raw()),
            Ok(vec![10, 10, 10, 20, 20, 20, 30, 30, 30])
        );
        msg.data.pop();
        let err = rgb_from_image_msg(&msg).err();
        assert!(matches!(
            err,
            Some(ImageMsgError::DataTooShort {
                expected: 3,
                actual: 2,
                ..
            })
        ));
        msg.step = 2;
        assert!(matches!(
            rgb_from_image_msg(&msg),
            Err(ImageMsgError::StepTooSmall { step: 2, .. })
        ));
        msg.encoding = "16UC1".into();
        assert!(matches!(
            rgb_from_image_msg(&msg),
            Err(ImageMsgError::UnsupportedEncoding { .. })
        ));
    }

    #[test]
    fn data_longer_than_height_times_step_is_rejected() {
        // Claims 2x1 rgb8 but carries 2x2 worth of bytes.
        let msg = Image {
            header: header(),
            height: 1,
            width: 2,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 6,
            data: vec![0; 12],
        };
        let err = rgb_from_image_msg(&msg).err();
        assert_eq!(
            err,
            Some(ImageMsgError::DataTooLong {
                encoding: "rgb8".into(),
                height: 1,
                step: 6,
                expected: 6,
                actual: 12,
            })
        );
        let text = err.map(|e| e.to_string()).unwrap_or_default();
        assert!(
            text.contains("12 bytes") && text.contains("height 1 x step 6 is 6"),
            "{text}"
        );
        let float = Image {
            encoding: "32FC1".into(),
            step: 8,
            data: vec![0; 9],
            ..msg
        };
        assert!(matches!(
            float_from_image_msg(&float),
            Err(ImageMsgError::DataTooLong {
                expected: 8,
                actual: 9,
                ..
            })
        ));
    }

    #[test]
    fn float_round_trip_and_big_endian() {
        let img = FloatImage {
            width: 2,
            height: 1,
            data: vec![1.5, f32::NAN],
        };
        let msg = image_msg_from_float(header(), &img);
        assert_eq!(msg.step, 8);
        assert_eq!(&msg.data[..4], &1.5f32.to_le_bytes());
        let back = float_from_image_msg(&msg).map_err(|e| e.to_string());
        let back = back.map(|b| (b.width, b.height, b.data[0], b.data[1].is_nan()));
        assert_eq!(back, Ok((2, 1, 1.5, true)));

        let be = Image {
            is_bigendian: 1,
            data: [2.25f32.to_be_bytes(), (-3.0f32).to_be_bytes()].concat(),
            ..msg
        };
        let back = float_from_image_msg(&be).map(|b| b.data);
        assert_eq!(back, Ok(vec![2.25, -3.0]));
    }

    #[test]
    fn compressed_codec_parsing() {
        assert_eq!(compressed_codec("jpeg"), Some(image::ImageFormat::Jpeg));
        assert_eq!(
            compressed_codec("rgb8; jpeg compressed bgr8"),
            Some(image::ImageFormat::Jpeg)
        );
        assert_eq!(
            compressed_codec("bgr8; png compressed bgr8"),
            Some(image::ImageFormat::Png)
        );
        assert_eq!(compressed_codec("16UC1; compressedDepth png"), None);
        assert_eq!(compressed_codec("tiff"), None);
    }
}
