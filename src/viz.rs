//! Pictures for people: colour-mapped depth and panorama stacks.

use image::Rgb;
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::glyphs::TextStyle;

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
    let mut img = RgbImage::new(range.width as u32, range.height as u32);
    for (k, px) in img.pixels_mut().enumerate() {
        let d = range.data[k];
        *px = if d.is_finite() && d > 0.0 {
            turbo(depth_to_unit(d, min_depth_m, max_depth_m))
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

/// Height of a depth legend's colour ramp, pixels.
const LEGEND_RAMP_PX: u32 = 12;
/// Space between glyphs and around the labels, pixels.
const GLYPH_GAP_PX: u32 = 2;
/// Depths a legend labels when they fall inside its range, metres.
const LEGEND_TICKS_M: [f32; 12] = [
    0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0,
];
const LEGEND_INK: Rgb<u8> = Rgb([255, 255, 255]);
/// The legend's labels: the 3x5 font at twice its size, white.
const LEGEND_TEXT: TextStyle = TextStyle {
    scale: 2,
    gap_px: GLYPH_GAP_PX,
    ink: LEGEND_INK,
};

/// Position in `[0, 1]` of `depth_m` on the colour map of [`colorize_range`] (0 far, 1 near).
fn depth_to_unit(depth_m: f32, min_depth_m: f32, max_depth_m: f32) -> f32 {
    let (inv_near, inv_far) = (1.0 / min_depth_m, 1.0 / max_depth_m);
    ((1.0 / depth_m - inv_far) / (inv_near - inv_far))
        .clamp(0.0, 1.0)
        .sqrt()
}

/// A depth label: `0.5m`, `20m`, `1000m`.
fn metres_label(depth_m: f32) -> String {
    if depth_m.fract() == 0.0 {
        format!("{depth_m:.0}m")
    } else {
        format!("{depth_m:.1}m")
    }
}

/// A colour bar for [`colorize_range`]'s map, `width` pixels wide: the ramp from
/// `max_depth_m` (left) to `min_depth_m` (right), each column the colour of the depth at that
/// position, with depths in metres printed under their ticks. Stack it under a preview.
pub fn depth_legend(width: u32, min_depth_m: f32, max_depth_m: f32) -> RgbImage {
    let label_h = LEGEND_TEXT.height_px() + 2 * GLYPH_GAP_PX;
    let mut img = RgbImage::new(width, LEGEND_RAMP_PX + label_h);
    let span = width.saturating_sub(1).max(1) as f32;
    for x in 0..width {
        let c = turbo(x as f32 / span);
        for y in 0..LEGEND_RAMP_PX {
            img.put_pixel(x, y, c);
        }
    }
    let mut free_from = 0;
    // Far (left) to near (right), so that labels are placed left to right.
    for depth_m in LEGEND_TICKS_M.into_iter().rev() {
        if depth_m < min_depth_m || depth_m > max_depth_m {
            continue;
        }
        let x = (depth_to_unit(depth_m, min_depth_m, max_depth_m) * span).round() as u32;
        let text = metres_label(depth_m);
        let w = LEGEND_TEXT.width_px(&text);
        let left = x.saturating_sub(w / 2).min(width.saturating_sub(w));
        if left < free_from {
            continue; // would overlap the previous label
        }
        for y in LEGEND_RAMP_PX.saturating_sub(4)..LEGEND_RAMP_PX {
            img.put_pixel(x.min(width - 1), y, LEGEND_INK);
        }
        LEGEND_TEXT.draw(&mut img, left, LEGEND_RAMP_PX + GLYPH_GAP_PX, &text);
        free_from = left + w + 2 * GLYPH_GAP_PX;
    }
    img
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

    #[test]
    fn legend_colours_match_the_depth_map_and_label_in_metres() {
        let (w, near, far) = (512u32, 0.5f32, 1000.0f32);
        let legend = depth_legend(w, near, far);
        assert_eq!(legend.width(), w);
        // The ramp column of 10 m has the colour a 10 m pixel gets, within a column's step.
        let x = (depth_to_unit(10.0, near, far) * (w - 1) as f32).round() as u32;
        let r = FloatImage {
            width: 1,
            height: 1,
            data: vec![10.0],
        };
        let want = *colorize_range(&r, near, far).get_pixel(0, 0);
        let got = *legend.get_pixel(x, 0);
        let diff: i32 = (0..3).map(|c| (want[c] as i32 - got[c] as i32).abs()).sum();
        assert!(diff <= 12, "ramp {got:?} at 10 m, map {want:?}");
        // Far on the left (dark), near on the right (red).
        let far = legend.get_pixel(0, 0);
        assert!(
            far.0.iter().map(|&c| c as u32).sum::<u32>() < 150,
            "{far:?}"
        );
        assert!(legend.get_pixel(w - 1, 0)[0] > legend.get_pixel(w - 1, 0)[2]);
        // Labels: white ink under the ramp, and "10m" drawn around its tick.
        let ink_under = |x0: u32, x1: u32| {
            (x0..x1.min(w))
                .flat_map(|x| (LEGEND_RAMP_PX..legend.height()).map(move |y| (x, y)))
                .filter(|&(x, y)| *legend.get_pixel(x, y) == LEGEND_INK)
                .count()
        };
        let half = LEGEND_TEXT.width_px("10m") / 2 + 1;
        assert!(ink_under(x - half, x + half) >= 20, "no 10 m label");
        assert_eq!(metres_label(0.5), "0.5m");
        assert_eq!(metres_label(1000.0), "1000m");
    }
}
