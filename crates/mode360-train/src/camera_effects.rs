//! What real cameras do to an image, drawn per camera and per training sample, so that the
//! network does not learn the renderer's clean pixels: exposure and white balance, vignetting,
//! blur, sensor noise and JPEG compression (the node takes compressed images), in that order
//! (optics, sensor, encoder).
//!
//! For camera `c` of sample `k` of stream `s`, everything comes from
//! `Rng::new(&[s, k, CAMERA_EFFECTS_TAG, c])`:
//!
//! ```text
//! exposure   v' = v * g^(1/2.2),      g log-uniform in [0.6, 1.6]   (8-bit sRGB v)
//! white bal. v'_ch *= w_ch,           w_ch uniform in [0.88, 1.12]
//! vignetting v' *= 1 - a (1 - |cos lat cos lon|)^2, a in [0, 0.35]  (ERP images only: a 360°
//!            camera's two lenses look along lon 0 and lon 180°)
//! blur       with p = 0.3, the [1 2 1] / 4 kernel along rows and columns
//! noise      v' += N(0, sigma^2),     sigma uniform in [0, 4] levels
//! JPEG       with p = 0.5, encoded and decoded at quality 50 to 95
//! ```

use image::codecs::jpeg::JpegEncoder;
use mode360_core::frame::RgbImage;
use mode360_synth::noise::Rng;
use std::f64::consts::PI;

/// Domain-separation word of the effects' stream.
pub const CAMERA_EFFECTS_TAG: u64 = 0x7A41_0009;
const MIN_GAIN: f64 = 0.6;
const MAX_GAIN: f64 = 1.6;
const DISPLAY_GAMMA: f64 = 2.2;
const WHITE_BALANCE_SPREAD: f64 = 0.12;
const MAX_VIGNETTING: f64 = 0.35;
const BLUR_PROBABILITY: f64 = 0.3;
const MAX_NOISE_LEVELS: f64 = 4.0;
const JPEG_PROBABILITY: f64 = 0.5;
const MIN_JPEG_QUALITY: u8 = 50;
const MAX_JPEG_QUALITY: u8 = 95;

/// One camera's draw of the effects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraEffects {
    /// Per-channel factor on 8-bit values (exposure and white balance together).
    pub channel_gain: [f64; 3],
    pub vignetting: f64,
    pub blur: bool,
    pub noise_levels: f64,
    pub jpeg_quality: Option<u8>,
}

impl CameraEffects {
    /// The effects of camera `camera` of sample `index` of stream `seed`.
    pub fn draw(seed: u64, index: u64, camera: usize) -> Self {
        let mut rng = Rng::new(&[seed, index, CAMERA_EFFECTS_TAG, camera as u64]);
        let gain = rng
            .range(MIN_GAIN.ln(), MAX_GAIN.ln())
            .exp()
            .powf(1.0 / DISPLAY_GAMMA);
        let mut channel_gain = [gain; 3];
        for g in &mut channel_gain {
            *g *= rng.range(1.0 - WHITE_BALANCE_SPREAD, 1.0 + WHITE_BALANCE_SPREAD);
        }
        let vignetting = rng.range(0.0, MAX_VIGNETTING);
        let blur = rng.chance(BLUR_PROBABILITY);
        let noise_levels = rng.range(0.0, MAX_NOISE_LEVELS);
        let jpeg_quality = rng.chance(JPEG_PROBABILITY).then(|| {
            MIN_JPEG_QUALITY + rng.index(usize::from(MAX_JPEG_QUALITY - MIN_JPEG_QUALITY) + 1) as u8
        });
        Self {
            channel_gain,
            vignetting,
            blur,
            noise_levels,
            jpeg_quality,
        }
    }

    /// Applies the effects to `img` in place; `rng` draws the noise.
    pub fn apply(&self, img: &mut RgbImage, rng: &mut Rng) {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let erp = w == 2 * h;
        let mut plane: Vec<f32> = img.as_raw().iter().map(|&v| f32::from(v)).collect();
        for v in 0..h {
            let lat = PI / 2.0 - PI * (v as f64 + 0.5) / h as f64;
            for u in 0..w {
                let falloff = if erp {
                    let lon = PI * (1.0 - 2.0 * (u as f64 + 0.5) / w as f64);
                    let off_axis = 1.0 - (lat.cos() * lon.cos()).abs();
                    1.0 - self.vignetting * off_axis * off_axis
                } else {
                    1.0
                };
                let px = &mut plane[3 * (v * w + u)..3 * (v * w + u) + 3];
                for (c, g) in px.iter_mut().zip(self.channel_gain) {
                    *c *= (g * falloff) as f32;
                }
            }
        }
        if self.blur {
            blur_121(&mut plane, w, h);
        }
        for c in plane.iter_mut() {
            *c += (gaussian(rng) * self.noise_levels) as f32;
        }
        let bytes: Vec<u8> = plane
            .iter()
            .map(|&c| c.round().clamp(0.0, 255.0) as u8)
            .collect();
        img.copy_from_slice(&bytes);
        if let Some(quality) = self.jpeg_quality {
            if let Some(decoded) = jpeg_round_trip(img, quality) {
                *img = decoded;
            }
        }
    }
}

/// A standard normal draw (Box-Muller).
fn gaussian(rng: &mut Rng) -> f64 {
    let u1 = rng.unit().max(f64::MIN_POSITIVE);
    let u2 = rng.unit();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

/// The `[1 2 1] / 4` kernel along rows (wrapping: ERP longitude) and columns (clamped), on
/// an interleaved RGB plane.
fn blur_121(plane: &mut [f32], w: usize, h: usize) {
    let src = plane.to_vec();
    for v in 0..h {
        for u in 0..w {
            let (l, r) = ((u + w - 1) % w, (u + 1) % w);
            for c in 0..3 {
                let at = |uu: usize| src[3 * (v * w + uu) + c];
                plane[3 * (v * w + u) + c] = 0.25 * at(l) + 0.5 * at(u) + 0.25 * at(r);
            }
        }
    }
    let src = plane.to_vec();
    for v in 0..h {
        let (t, b) = (v.saturating_sub(1), (v + 1).min(h - 1));
        for u in 0..w {
            for c in 0..3 {
                let at = |vv: usize| src[3 * (vv * w + u) + c];
                plane[3 * (v * w + u) + c] = 0.25 * at(t) + 0.5 * at(v) + 0.25 * at(b);
            }
        }
    }
}

/// `img` encoded as JPEG at `quality` and decoded again (`None` if the codec fails).
fn jpeg_round_trip(img: &RgbImage, quality: u8) -> Option<RgbImage> {
    let mut bytes = Vec::new();
    JpegEncoder::new_with_quality(&mut bytes, quality)
        .encode_image(img)
        .ok()?;
    image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
        .ok()
        .map(|d| d.to_rgb8())
}

/// Applies each camera's effects to `images` (rig order) of sample `index` of stream `seed`.
pub fn apply_camera_effects(images: &mut [RgbImage], seed: u64, index: u64) {
    for (camera, img) in images.iter_mut().enumerate() {
        let effects = CameraEffects::draw(seed, index, camera);
        let mut rng = Rng::new(&[seed, index, CAMERA_EFFECTS_TAG, camera as u64, 1]);
        effects.apply(img, &mut rng);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(w: u32, h: u32, level: u8) -> RgbImage {
        RgbImage::from_pixel(w, h, image::Rgb([level; 3]))
    }

    #[test]
    fn draws_are_deterministic_per_camera_and_in_range() {
        let a = CameraEffects::draw(3, 7, 0);
        assert_eq!(a, CameraEffects::draw(3, 7, 0));
        assert_ne!(a, CameraEffects::draw(3, 7, 1));
        let mut jpeg = 0;
        for k in 0..200 {
            let e = CameraEffects::draw(1, k, 0);
            let lo = MIN_GAIN.powf(1.0 / DISPLAY_GAMMA) * (1.0 - WHITE_BALANCE_SPREAD);
            let hi = MAX_GAIN.powf(1.0 / DISPLAY_GAMMA) * (1.0 + WHITE_BALANCE_SPREAD);
            assert!(
                e.channel_gain.iter().all(|g| (lo..=hi).contains(g)),
                "{e:?}"
            );
            assert!((0.0..=MAX_VIGNETTING).contains(&e.vignetting));
            jpeg += usize::from(e.jpeg_quality.is_some());
        }
        assert!((60..140).contains(&jpeg), "{jpeg} of 200 with JPEG");
    }

    #[test]
    fn gain_vignetting_and_noise_do_what_they_say() {
        let effects = CameraEffects {
            channel_gain: [1.2, 1.0, 0.8],
            vignetting: 0.3,
            blur: false,
            noise_levels: 0.0,
            jpeg_quality: None,
        };
        let mut img = grey(64, 32, 100);
        effects.apply(&mut img, &mut Rng::new(&[1]));
        // Looking along a lens axis (lon 0, lat 0: the centre) only the gain acts; at lon 90°
        // (u = W / 4), off both axes, the full vignetting.
        let centre = img.get_pixel(32, 16).0;
        assert!((i32::from(centre[0]) - 120).abs() <= 1, "{centre:?}");
        assert!((i32::from(centre[2]) - 80).abs() <= 1, "{centre:?}");
        let side = img.get_pixel(16, 16).0;
        assert!(side[1] < 75 && side[1] > 65, "{side:?}");
        // Noise of 4 levels: the spread of a flat patch is about 4.
        let noisy = CameraEffects {
            channel_gain: [1.0; 3],
            vignetting: 0.0,
            noise_levels: 4.0,
            ..effects
        };
        let mut img = grey(64, 32, 100);
        noisy.apply(&mut img, &mut Rng::new(&[2]));
        let values: Vec<f64> = img.as_raw().iter().map(|&v| f64::from(v)).collect();
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let sd =
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt();
        assert!(
            (mean - 100.0).abs() < 0.5 && (sd - 4.0).abs() < 0.5,
            "{mean} {sd}"
        );
    }

    #[test]
    fn blur_and_jpeg_keep_a_flat_image_flat_and_soften_an_edge() {
        let effects = CameraEffects {
            channel_gain: [1.0; 3],
            vignetting: 0.0,
            blur: true,
            noise_levels: 0.0,
            jpeg_quality: Some(80),
        };
        let mut flat = grey(32, 16, 90);
        effects.apply(&mut flat, &mut Rng::new(&[3]));
        assert!(flat
            .as_raw()
            .iter()
            .all(|&v| (i32::from(v) - 90).abs() <= 2));
        let mut edge =
            RgbImage::from_fn(32, 16, |u, _| image::Rgb([if u < 16 { 0 } else { 200 }; 3]));
        CameraEffects {
            jpeg_quality: None,
            ..effects
        }
        .apply(&mut edge, &mut Rng::new(&[4]));
        assert_eq!(edge.get_pixel(15, 8).0[0], 50);
        assert_eq!(edge.get_pixel(16, 8).0[0], 150);
    }
}
