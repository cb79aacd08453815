//! Pictures for people: colour-mapped depth and panorama stacks.

use image::Rgb;
use mode360_core::frame::{FloatImage, RgbImage};

/// Turbo colour map (Google's polynomial approximation), `t` in [0, 1] from blue to red.
pub fn turbo(t: f32) -> Rgb<u8> {
    let t = t.clamp(0.0, 1.0) as f64;
    let r = 0.13572138
        + t * (4.61539260
            + t * (-42.66032258 + t * (132.13108234 + t * (-152.94239396 + t * 59.28637943))));
    let g = 0.09140261
        + t * (2.19418839
            + t * (4.84296658 + t * (-14.18503333 + t * (4.27729857 + t * 2.82956604))));
    let b = 0.10667330
        + t * (12.64194608
            + t * (-60.58204836 + t * (110.36276771 + t * (-89.90310912 + t * 27.34824973))));
    let c = |x: f64| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    Rgb([c(r), c(g), c(b)])
}

/// Colour-maps range by inverse depth between `min_depth_m` (red) and `max_depth_m` (dark
/// blue), the way disparity is usually shown; invalid pixels are black.
pub fn colorize_range(range: &FloatImage, min_depth_m: f32, max_depth_m: f32) -> RgbImage {
    let (inv_near, inv_far) = (1.0 / min_depth_m, 1.0 / max_depth_m);
    let mut img = RgbImage::new(range.width as u32, range.height as u32);
    for (k, px) in img.pixels_mut().enumerate() {
        let d = range.data[k];
        *px = if d.is_finite() && d > 0.0 {
            turbo(((1.0 / d - inv_far) / (inv_near - inv_far)).sqrt())
        } else {
            Rgb([0, 0, 0])
        };
    }
    img
}

/// Stacks images vertically (all must share a width; narrower ones are left-aligned).
pub fn stack_vertical(images: &[RgbImage]) -> RgbImage {
    let width = images.iter().map(|i| i.width()).max().unwrap_or(0);
    let height = images.iter().map(|i| i.height()).sum();
    let mut out = RgbImage::new(width, height);
    let mut y0 = 0;
    for img in images {
        for (x, y, p) in img.enumerate_pixels() {
            out.put_pixel(x, y0 + y, *p);
        }
        y0 += img.height();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_is_red_far_is_blue_invalid_is_black() {
        let r = FloatImage {
            width: 4,
            height: 1,
            data: vec![1.0, 1000.0, f32::NAN, 100.0],
        };
        let img = colorize_range(&r, 1.0, 1000.0);
        let near = img.get_pixel(0, 0);
        let far = img.get_pixel(1, 0);
        assert!(near[0] > near[2], "near should be red: {near:?}");
        let mid = img.get_pixel(3, 0);
        assert!(mid[2] > mid[0], "100 m should be blue: {mid:?}");
        assert!(
            far.0.iter().map(|&c| c as u32).sum::<u32>() < 150,
            "max depth is dark: {far:?}"
        );
        assert_eq!(*img.get_pixel(2, 0), Rgb([0, 0, 0]));
        assert_eq!(stack_vertical(&[img.clone(), img]).height(), 2);
    }
}
