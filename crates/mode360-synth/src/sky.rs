//! The sky at infinity: a horizon-to-zenith gradient, band-limited clouds, a textured veil
//! and the sun disk.

use super::colour::{mix, scale, Rgb};
use super::noise::{fbm2, fbm3};
use nalgebra::Vector3;

/// The sky at infinity along unit direction `d`: a horizon-to-zenith gradient, procedural
/// clouds on a cloud plane, and the sun disk. `pixel_angle_rad` band-limits the clouds.
pub fn sky(d: &Vector3<f64>, sun: &Vector3<f64>, pixel_angle_rad: f64, seed: u32) -> Rgb {
    let up = d.z.max(0.0) as f32;
    let mut c = mix(HORIZON_SKY, ZENITH_SKY, up.powf(SKY_GRADIENT_EXPONENT));
    // Clouds: fractal noise on the plane z = 1 (coordinates d.xy / d.z, clamped near the
    // horizon); the footprint there grows like pixel_angle / d.z^2.
    let dz = d.z.max(0.04);
    let (cx, cy) = (d.x / dz, d.y / dz);
    let fp = (pixel_angle_rad / (dz * dz)) as f32;
    let density = fbm2(cx as f32, cy as f32, seed ^ 0x41, 0.8, 7, fp);
    let wisps = fbm2(
        cx as f32 * 3.0,
        cy as f32 * 3.0,
        seed ^ 0x42,
        1.0,
        4,
        fp * 3.0,
    );
    let cover = ((density - 0.38) * 3.0 + (wisps - 0.5) * 0.8).clamp(0.0, 1.0);
    let shade = 0.75 + 0.35 * wisps;
    c = mix(c, [shade, shade, shade * 1.02], cover * 0.9);
    // A thin high veil keeps even clear patches textured (photometric matching needs it).
    // Noise on the unit sphere of directions: isotropic in angle, no horizon singularity,
    // band-limited by the pixel's angular size.
    let veil = fbm3(
        [d.x as f32, d.y as f32, d.z as f32],
        seed ^ 0x43,
        SKY_VEIL_BASE_FREQ,
        6,
        pixel_angle_rad as f32,
    );
    c = scale(c, 0.8 + 0.4 * veil);
    // Haze near the horizon and the sun.
    let cos_sun = d.dot(sun) as f32;
    let glow = cos_sun.max(0.0).powf(64.0) * 0.6;
    let disk = if cos_sun > SUN_DISK_COS { 6.0 } else { 0.0 };
    [
        c[0] + glow + disk,
        c[1] + glow * 0.9 + disk,
        c[2] + glow * 0.7 + disk,
    ]
}

/// Sky colour at the horizon (also the fog colour) and at the zenith, linear RGB; the
/// gradient is `mix(horizon, zenith, max(d_z, 0)^SKY_GRADIENT_EXPONENT)`.
pub const HORIZON_SKY: Rgb = [0.75, 0.82, 0.92];
pub const ZENITH_SKY: Rgb = [0.22, 0.42, 0.8];
const SKY_GRADIENT_EXPONENT: f32 = 0.6;
/// Lowest frequency of the sky veil, cycles per unit of direction (about per radian).
const SKY_VEIL_BASE_FREQ: f32 = 6.0;

/// Cosine of the sun disk's angular radius (about 0.6 degrees, a little larger than the real
/// sun so it covers a few pixels).
pub const SUN_DISK_COS: f32 = 0.999_945;
