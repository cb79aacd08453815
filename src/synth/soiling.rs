//! Lens soiling on ERP images: mud spots (opaque brownish blobs with soft, ragged edges),
//! water drops (local inverted refraction with blur and a bright rim) and glare (a radial
//! flare with streaks). Effects are painted in pixel space until the covered fraction of the
//! image reaches a target drawn in `[MIN_TARGET_COVERAGE, MAX_TARGET_COVERAGE]`.

use super::noise::{value2, Rng};
use crate::frame::RgbImage;

/// A pixel counts as soiled when the effect's opacity there reaches this.
pub const COVERAGE_ALPHA_THRESHOLD: f32 = 0.25;
/// Coverage targets are drawn in this range; a single effect covers at most about 3% of
/// the image, so the final coverage stays within 5..20%.
pub const MIN_TARGET_COVERAGE: f64 = 0.07;
pub const MAX_TARGET_COVERAGE: f64 = 0.16;
/// A range of effect radii as fractions of the image width.
#[derive(Clone, Copy, Debug)]
struct RadiusRange {
    min_frac: f64,
    max_frac: f64,
}
const MUD_RADIUS: RadiusRange = RadiusRange {
    min_frac: 0.02,
    max_frac: 0.055,
};
const DROP_RADIUS: RadiusRange = RadiusRange {
    min_frac: 0.012,
    max_frac: 0.035,
};
const GLARE_RADIUS: RadiusRange = RadiusRange {
    min_frac: 0.03,
    max_frac: 0.05,
};
/// Safety bound on the number of effects per image.
const MAX_EFFECTS: usize = 400;

/// Kinds of soiling effects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SoilingKind {
    Mud,
    WaterDrop,
    Glare,
}

#[derive(Clone, Copy, Debug)]
struct Effect {
    kind: SoilingKind,
    centre_u: f64,
    centre_v: f64,
    radius_px: f64,
    seed: u32,
    /// Mud: opacity; glare: peak intensity.
    strength: f64,
    tint: [f32; 3],
}

/// What soiling did to one camera's image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraSoiling {
    /// Fraction of pixels whose soiling opacity reaches [`COVERAGE_ALPHA_THRESHOLD`].
    pub coverage: f64,
    pub mud_spots: usize,
    pub water_drops: usize,
    pub glares: usize,
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Effect {
    /// Reach of the effect in pixels around its centre.
    fn reach_px(&self) -> f64 {
        match self.kind {
            SoilingKind::Glare => self.radius_px * 3.0,
            _ => self.radius_px * 1.25,
        }
    }

    /// Opacity at offset `(du, dv)` pixels from the centre.
    fn alpha(&self, du: f64, dv: f64) -> f64 {
        let d = (du * du + dv * dv).sqrt();
        let r = self.radius_px;
        match self.kind {
            SoilingKind::Mud => {
                let ragged = 0.78
                    + 0.45 * value2((du / r * 2.5) as f32, (dv / r * 2.5) as f32, self.seed) as f64;
                self.strength * (1.0 - smoothstep(0.75, 1.0, d / (r * ragged)))
            }
            SoilingKind::WaterDrop => 1.0 - smoothstep(0.85, 1.0, d / r),
            SoilingKind::Glare => {
                let core = (-(d / r) * (d / r)).exp();
                let ang = dv.atan2(du);
                // Six streaks with a slowly decaying tail.
                let streak = (ang * 3.0).cos().abs().powf(40.0) * (-d / (2.5 * r)).exp();
                (self.strength * (core + 0.8 * streak)).min(1.0)
            }
        }
    }
}

/// Soils `img` in place with effects drawn from `rng`; returns what was done.
pub fn soil_image(img: &mut RgbImage, rng: &mut Rng) -> CameraSoiling {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let target = rng.range(MIN_TARGET_COVERAGE, MAX_TARGET_COVERAGE);
    let mut covered = vec![false; w * h];
    let mut n_covered = 0usize;
    let mut effects = Vec::new();
    let mut report = CameraSoiling::default();
    while (n_covered as f64) < target * (w * h) as f64 && effects.len() < MAX_EFFECTS {
        let pick = rng.unit();
        let (kind, radii) = if pick < 0.5 {
            (SoilingKind::Mud, MUD_RADIUS)
        } else if pick < 0.88 || report.glares > 0 {
            (SoilingKind::WaterDrop, DROP_RADIUS)
        } else {
            (SoilingKind::Glare, GLARE_RADIUS)
        };
        let e = Effect {
            kind,
            centre_u: rng.range(0.0, w as f64),
            centre_v: rng.range(0.1 * h as f64, 0.9 * h as f64),
            radius_px: rng.range(radii.min_frac, radii.max_frac) * w as f64,
            seed: (rng.next_u64() >> 32) as u32,
            strength: match kind {
                SoilingKind::Mud => rng.range(0.85, 1.0),
                _ => rng.range(0.8, 1.0),
            },
            tint: [
                rng.range(0.22, 0.36) as f32,
                rng.range(0.15, 0.24) as f32,
                rng.range(0.08, 0.13) as f32,
            ],
        };
        match kind {
            SoilingKind::Mud => report.mud_spots += 1,
            SoilingKind::WaterDrop => report.water_drops += 1,
            SoilingKind::Glare => report.glares += 1,
        }
        for_each_pixel(&e, w, h, |x, y, du, dv| {
            if e.alpha(du, dv) >= COVERAGE_ALPHA_THRESHOLD as f64 && !covered[y * w + x] {
                covered[y * w + x] = true;
                n_covered += 1;
            }
        });
        effects.push(e);
    }
    let src = img.clone();
    for e in &effects {
        apply(e, img, &src);
    }
    report.coverage = n_covered as f64 / (w * h) as f64;
    report
}

/// Calls `f(x, y, du, dv)` for every pixel within the effect's reach; columns wrap.
fn for_each_pixel(e: &Effect, w: usize, h: usize, mut f: impl FnMut(usize, usize, f64, f64)) {
    let reach = e.reach_px();
    let y0 = (e.centre_v - reach).floor().max(0.0) as usize;
    let y1 = ((e.centre_v + reach).ceil() as usize).min(h.saturating_sub(1));
    let x_lo = (e.centre_u - reach).floor() as i64;
    let x_hi = (e.centre_u + reach).ceil() as i64;
    let span = (x_hi - x_lo + 1).min(w as i64);
    for y in y0..=y1 {
        let dv = y as f64 + 0.5 - e.centre_v;
        for k in 0..span {
            let xi = x_lo + k;
            let du = xi as f64 + 0.5 - e.centre_u;
            f(xi.rem_euclid(w as i64) as usize, y, du, dv);
        }
    }
}

fn sample(src: &RgbImage, u: f64, v: f64) -> [f64; 3] {
    let (w, h) = (src.width() as i64, src.height() as i64);
    let x = (u.floor() as i64).rem_euclid(w) as u32;
    let y = (v.floor() as i64).clamp(0, h - 1) as u32;
    let p = src.get_pixel(x, y).0;
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

fn apply(e: &Effect, img: &mut RgbImage, src: &RgbImage) {
    let (w, h) = (img.width() as usize, img.height() as usize);
    for_each_pixel(e, w, h, |x, y, du, dv| {
        let a = e.alpha(du, dv);
        if a <= 0.0 {
            return;
        }
        let cur = img.get_pixel(x as u32, y as u32).0;
        let cur = [cur[0] as f64, cur[1] as f64, cur[2] as f64];
        let out = match e.kind {
            SoilingKind::Mud => {
                let grain =
                    0.75 + 0.5 * value2((du * 0.3) as f32, (dv * 0.3) as f32, e.seed ^ 1) as f64;
                let mud = e.tint.map(|c| c as f64 * 255.0 * grain);
                [0, 1, 2].map(|i| cur[i] * (1.0 - a) + mud[i] * a)
            }
            SoilingKind::WaterDrop => {
                // The drop acts as a small inverted lens: it shows a blurred, flipped view of a
                // wider area around it, with a bright rim.
                let (su, sv) = (e.centre_u - 1.6 * du, e.centre_v - 1.6 * dv);
                let mut acc = [0.0; 3];
                for (ou, ov) in [(0.0, 0.0), (1.5, 0.0), (-1.5, 0.0), (0.0, 1.5), (0.0, -1.5)] {
                    let s = sample(src, su + ou, sv + ov);
                    for i in 0..3 {
                        acc[i] += s[i] / 5.0;
                    }
                }
                let d = (du * du + dv * dv).sqrt() / e.radius_px;
                let rim = smoothstep(0.6, 0.92, d) * (1.0 - smoothstep(0.92, 1.0, d));
                let refr = acc.map(|c| c * 0.9 + 25.0 + 90.0 * rim);
                [0, 1, 2].map(|i| cur[i] * (1.0 - a) + refr[i] * a)
            }
            SoilingKind::Glare => [0, 1, 2].map(|i| cur[i] + (255.0 - cur[i]) * a * 0.95),
        };
        img.put_pixel(
            x as u32,
            y as u32,
            image::Rgb(out.map(|c| c.round().clamp(0.0, 255.0) as u8)),
        );
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_within_bounds_and_changes_pixels() {
        for seed in 0..40u64 {
            let mut img = RgbImage::from_pixel(256, 128, image::Rgb([100, 120, 140]));
            let before = img.clone();
            let mut rng = Rng::new(&[seed]);
            let r = soil_image(&mut img, &mut rng);
            assert!(
                (0.05..=0.20).contains(&r.coverage),
                "coverage {}",
                r.coverage
            );
            let changed = img
                .pixels()
                .zip(before.pixels())
                .filter(|(a, b)| a != b)
                .count() as f64
                / (256.0 * 128.0);
            // Soft edges change a few more pixels than the counted coverage.
            assert!(
                changed >= r.coverage * 0.8,
                "changed {changed} coverage {}",
                r.coverage
            );
        }
    }
}
