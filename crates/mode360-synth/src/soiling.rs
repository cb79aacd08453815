//! Lens soiling: mud spots (opaque brownish blobs with soft, ragged edges), water drops (local
//! inverted refraction with blur and a bright rim) and glare (a radial flare with streaks).
//! Effects are painted in pixel space until the covered fraction of the image reaches a
//! target drawn in `[MIN_TARGET_COVERAGE, MAX_TARGET_COVERAGE]`.
//!
//! * ERP panoramas ([`soil_image`]): effects wrap across the longitude seam; radii are
//!   fractions of the image width.
//! * Fisheye images ([`soil_image_within`]): soiling sits on the lens, so effects stay inside
//!   the pixels the lens sees (the mask; black pixels outside the lens circle stay black),
//!   centres are drawn among those pixels, nothing wraps, coverage is a fraction of the seen
//!   pixels, and radii are fractions of the image's shorter side (one lens circle's
//!   diameter, also for a dual-fisheye image).

use super::noise::{value2, Rng};
use mode360_core::frame::RgbImage;

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
/// Draws of an effect centre inside a fisheye mask before the effect is given up.
const MAX_CENTRE_DRAWS: usize = 64;

/// Where effects may go.
#[derive(Clone, Copy)]
enum Region<'a> {
    /// An ERP panorama: every pixel, columns wrap.
    Panorama,
    /// Only the pixels marked `true` (row-major), no wrapping.
    Within(&'a [bool]),
}

impl Region<'_> {
    fn wraps(&self) -> bool {
        matches!(self, Region::Panorama)
    }

    fn contains(&self, i: usize) -> bool {
        match self {
            Region::Panorama => true,
            Region::Within(mask) => mask[i],
        }
    }
}

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

/// Soils the ERP panorama `img` in place with effects drawn from `rng`; returns what was done.
pub fn soil_image(img: &mut RgbImage, rng: &mut Rng) -> CameraSoiling {
    soil(img, Region::Panorama, rng)
}

/// Soils a fisheye image in place, only where `mask` (row-major, one entry per pixel) is
/// `true`: the pixels the lens sees. Coverage is the fraction of those pixels. A mask of the
/// wrong length, or without any `true`, leaves the image as it is.
pub fn soil_image_within(img: &mut RgbImage, mask: &[bool], rng: &mut Rng) -> CameraSoiling {
    let n = img.width() as usize * img.height() as usize;
    if mask.len() != n || !mask.iter().any(|&m| m) {
        return CameraSoiling::default();
    }
    soil(img, Region::Within(mask), rng)
}

/// An effect centre: anywhere (rows 10..90 %) on a panorama, on a seen pixel of a fisheye.
fn draw_centre(region: Region, w: usize, h: usize, rng: &mut Rng) -> Option<(f64, f64)> {
    match region {
        Region::Panorama => Some((
            rng.range(0.0, w as f64),
            rng.range(0.1 * h as f64, 0.9 * h as f64),
        )),
        Region::Within(mask) => (0..MAX_CENTRE_DRAWS).find_map(|_| {
            let (u, v) = (rng.range(0.0, w as f64), rng.range(0.0, h as f64));
            let (x, y) = ((u as usize).min(w - 1), (v as usize).min(h - 1));
            mask[y * w + x].then_some((u, v))
        }),
    }
}

fn soil(img: &mut RgbImage, region: Region, rng: &mut Rng) -> CameraSoiling {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let (area_px, scale_px) = match region {
        Region::Panorama => (w * h, w),
        Region::Within(mask) => (mask.iter().filter(|&&m| m).count(), w.min(h)),
    };
    let target = rng.range(MIN_TARGET_COVERAGE, MAX_TARGET_COVERAGE);
    let mut covered = vec![false; w * h];
    let mut n_covered = 0usize;
    let mut effects = Vec::new();
    let mut report = CameraSoiling::default();
    let mut attempts = 0usize;
    while (n_covered as f64) < target * area_px as f64 && attempts < MAX_EFFECTS {
        attempts += 1;
        let pick = rng.unit();
        let (kind, radii) = if pick < 0.5 {
            (SoilingKind::Mud, MUD_RADIUS)
        } else if pick < 0.88 || report.glares > 0 {
            (SoilingKind::WaterDrop, DROP_RADIUS)
        } else {
            (SoilingKind::Glare, GLARE_RADIUS)
        };
        let Some((centre_u, centre_v)) = draw_centre(region, w, h, rng) else {
            continue;
        };
        let e = Effect {
            kind,
            centre_u,
            centre_v,
            radius_px: rng.range(radii.min_frac, radii.max_frac) * scale_px as f64,
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
        for_each_pixel(&e, w, h, region, |x, y, du, dv| {
            if e.alpha(du, dv) >= COVERAGE_ALPHA_THRESHOLD as f64 && !covered[y * w + x] {
                covered[y * w + x] = true;
                n_covered += 1;
            }
        });
        effects.push(e);
    }
    let src = img.clone();
    for e in &effects {
        apply(e, img, &src, region);
    }
    report.coverage = n_covered as f64 / area_px as f64;
    report
}

/// Calls `f(x, y, du, dv)` for every pixel of `region` within the effect's reach; columns
/// wrap on a panorama.
fn for_each_pixel(
    e: &Effect,
    w: usize,
    h: usize,
    region: Region,
    mut f: impl FnMut(usize, usize, f64, f64),
) {
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
            if !region.wraps() && (xi < 0 || xi >= w as i64) {
                continue;
            }
            let x = xi.rem_euclid(w as i64) as usize;
            if !region.contains(y * w + x) {
                continue;
            }
            let du = xi as f64 + 0.5 - e.centre_u;
            f(x, y, du, dv);
        }
    }
}

fn sample(src: &RgbImage, u: f64, v: f64, wrap: bool) -> [f64; 3] {
    let (w, h) = (src.width() as i64, src.height() as i64);
    let x = if wrap {
        (u.floor() as i64).rem_euclid(w)
    } else {
        (u.floor() as i64).clamp(0, w - 1)
    } as u32;
    let y = (v.floor() as i64).clamp(0, h - 1) as u32;
    let p = src.get_pixel(x, y).0;
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

fn apply(e: &Effect, img: &mut RgbImage, src: &RgbImage, region: Region) {
    let (w, h) = (img.width() as usize, img.height() as usize);
    for_each_pixel(e, w, h, region, |x, y, du, dv| {
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
                    let s = sample(src, su + ou, sv + ov, region.wraps());
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

    #[test]
    fn fisheye_soiling_stays_inside_the_lens_circle() {
        let (w, h) = (160usize, 160usize);
        let (c, r) = (79.5, 70.0);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                (x - c).hypot(y - c) <= r
            })
            .collect();
        let inside = mask.iter().filter(|&&m| m).count() as f64;
        for seed in 0..20u64 {
            let mut img = RgbImage::from_fn(w as u32, h as u32, |x, y| {
                if mask[y as usize * w + x as usize] {
                    image::Rgb([100, 120, 140])
                } else {
                    image::Rgb([0, 0, 0])
                }
            });
            let before = img.clone();
            let r = soil_image_within(&mut img, &mask, &mut Rng::new(&[seed]));
            assert!(
                (0.05..=0.20).contains(&r.coverage),
                "seed {seed}: coverage {}",
                r.coverage
            );
            let mut changed_inside = 0usize;
            for (i, (a, b)) in img.pixels().zip(before.pixels()).enumerate() {
                if !mask[i] {
                    assert_eq!(a.0, [0, 0, 0], "seed {seed}: pixel {i} outside the lens");
                } else if a != b {
                    changed_inside += 1;
                }
            }
            assert!(
                changed_inside as f64 / inside >= r.coverage * 0.8,
                "seed {seed}: changed {changed_inside} of {inside}, coverage {}",
                r.coverage
            );
        }
    }
}
