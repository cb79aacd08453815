//! A 3x5 pixel font for the few labels the pictures carry (depth legends, the axes of training
//! curves): digits, capital letters, `m` (metres), `.`, `,`, `-`, `%`, `:`, `/` and
//! parentheses, drawn at an integer scale with no font file. A space, or any other character,
//! leaves a blank.

use crate::frame::RgbImage;
use image::Rgb;

/// Glyph width and height in font pixels.
pub const GLYPH_W: u32 = 3;
pub const GLYPH_H: u32 = 5;

/// How text is drawn: each font pixel `scale` x `scale` image pixels, `gap_px` between glyphs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextStyle {
    pub scale: u32,
    pub gap_px: u32,
    pub ink: Rgb<u8>,
}

impl TextStyle {
    /// Height of a line of text, pixels.
    pub fn height_px(&self) -> u32 {
        GLYPH_H * self.scale
    }

    /// Width of `text`, pixels.
    pub fn width_px(&self, text: &str) -> u32 {
        let n = text.chars().count() as u32;
        n * GLYPH_W * self.scale + n.saturating_sub(1) * self.gap_px
    }

    /// Draws `text` with its top-left corner at `(x0, y0)`, clipped to the image; characters
    /// without a glyph leave a blank.
    pub fn draw(&self, img: &mut RgbImage, x0: u32, y0: u32, text: &str) {
        let mut x = x0;
        for c in text.chars() {
            if let Some(rows) = glyph(c) {
                for (r, bits) in (0u32..).zip(rows) {
                    for col in (0..GLYPH_W).filter(|col| bits & (1 << (GLYPH_W - 1 - col)) != 0) {
                        for dy in 0..self.scale {
                            for dx in 0..self.scale {
                                let (px, py) =
                                    (x + col * self.scale + dx, y0 + r * self.scale + dy);
                                if px < img.width() && py < img.height() {
                                    img.put_pixel(px, py, self.ink);
                                }
                            }
                        }
                    }
                }
            }
            x += GLYPH_W * self.scale + self.gap_px;
        }
    }
}

/// The capital letters A to Z, rows top first, bit 2 the left column.
const LETTERS: [[u8; 5]; 26] = [
    [2, 5, 7, 5, 5], // A
    [6, 5, 6, 5, 6], // B
    [3, 4, 4, 4, 3], // C
    [6, 5, 5, 5, 6], // D
    [7, 4, 6, 4, 7], // E
    [7, 4, 6, 4, 4], // F
    [3, 4, 5, 5, 3], // G
    [5, 5, 7, 5, 5], // H
    [7, 2, 2, 2, 7], // I
    [1, 1, 1, 5, 2], // J
    [5, 5, 6, 5, 5], // K
    [4, 4, 4, 4, 7], // L
    [5, 7, 7, 5, 5], // M
    [6, 5, 5, 5, 5], // N
    [2, 5, 5, 5, 2], // O
    [6, 5, 6, 4, 4], // P
    [2, 5, 5, 6, 3], // Q
    [6, 5, 6, 5, 5], // R
    [3, 4, 2, 1, 6], // S
    [7, 2, 2, 2, 2], // T
    [5, 5, 5, 5, 7], // U
    [5, 5, 5, 5, 2], // V
    [5, 5, 7, 7, 5], // W
    [5, 5, 2, 5, 5], // X
    [5, 5, 2, 2, 2], // Y
    [7, 1, 2, 4, 7], // Z
];

/// Rows of a 3x5 glyph, top first, bit 2 the left column.
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        '%' => [5, 1, 2, 4, 5],
        'm' => [0, 0, 7, 7, 5],
        ',' => [0, 0, 0, 2, 4],
        ':' => [0, 2, 0, 2, 0],
        '/' => [1, 1, 2, 4, 4],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        'A'..='Z' => LETTERS[(c as u8 - b'A') as usize],
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_glyph_is_distinct_and_a_space_is_blank() {
        let chars: Vec<char> = ('0'..='9')
            .chain('A'..='Z')
            .chain("m.,-%:/()".chars())
            .collect();
        let glyphs: Vec<[u8; 5]> = chars.iter().map(|&c| glyph(c).unwrap()).collect();
        for (i, a) in glyphs.iter().enumerate() {
            assert!(a.iter().all(|&row| row < 8), "{} is 3 wide", chars[i]);
            for (j, b) in glyphs.iter().enumerate().skip(i + 1) {
                assert_ne!(a, b, "{} and {} look alike", chars[i], chars[j]);
            }
        }
        assert_eq!(glyph(' '), None);
        assert_eq!(glyph('q'), None);
    }

    #[test]
    fn text_covers_its_width_and_the_glyphs_pixels() {
        let style = TextStyle {
            scale: 2,
            gap_px: 2,
            ink: Rgb([255, 0, 0]),
        };
        assert_eq!(style.width_px("10m"), 3 * 6 + 2 * 2);
        let mut img = RgbImage::new(40, 12);
        style.draw(&mut img, 1, 1, "1-");
        let inked = img.pixels().filter(|p| **p == style.ink).count();
        // '1' has 8 font pixels, '-' 3; each 2x2
        assert_eq!(inked, (8 + 3) * 4);
        // nothing right of the text's width
        assert!((0..12)
            .all(|y| (1 + style.width_px("1-")..40).all(|x| img.get_pixel(x, y).0 == [0; 3])));
    }
}
