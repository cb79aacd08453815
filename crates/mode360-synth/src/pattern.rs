//! High-contrast procedural patterns for the random-objects scenes: solid (3-D) textures in
//! object coordinates, so every camera sees the same colour at a surface point, and random
//! backgrounds at infinity. All are band-limited by the pixel footprint like the street
//! materials: checkers and stripes are box-filtered, noise octaves fade near Nyquist.

use super::colour::{mix, periodic_coverage, Rgb};
use super::noise::{fbm3, lattice_unit, Rng};
use nalgebra::Vector3;

/// Which pattern a [`Pattern`] draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatternKind {
    /// 3-D checkerboard of cubes `scale_m` wide.
    Checker,
    /// Parallel slabs along `dir`, period `scale_m`, half of each in each colour.
    Stripes,
    /// Fractal value noise of wavelength `scale_m`, contrast-stretched between the colours.
    Noise,
    /// Cubes `scale_m` wide, each a random mix of the two colours.
    Cells,
}

/// A two-colour solid texture with fine noise on top (so large cells stay matchable).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pattern {
    pub kind: PatternKind,
    pub a: Rgb,
    pub b: Rgb,
    pub scale_m: f32,
    /// Unit direction across the stripes.
    pub dir: [f32; 3],
    pub seed: u32,
}

/// A random colour: either a saturated hue or a grey, linear RGB in `[0.02, 0.9]`.
pub fn random_colour(rng: &mut Rng) -> Rgb {
    if rng.chance(0.3) {
        let g = rng.range(0.02, 0.9) as f32;
        return [g, g, g];
    }
    let mut c = [0f32; 3];
    for ci in &mut c {
        *ci = rng.range(0.02, 0.9) as f32;
    }
    c
}

/// A random unit vector, uniform on the sphere.
pub fn random_unit(rng: &mut Rng) -> Vector3<f64> {
    let z = rng.range(-1.0, 1.0);
    let a = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vector3::new(r * a.cos(), r * a.sin(), z)
}

/// Luminance-like contrast between two colours (mean absolute channel difference).
fn contrast(a: &Rgb, b: &Rgb) -> f32 {
    (0..3).map(|i| (a[i] - b[i]).abs()).sum::<f32>() / 3.0
}

impl Pattern {
    /// A random pattern with a feature size between `min_scale_m` and `max_scale_m`
    /// (log-uniform) and two colours at least 0.25 apart.
    pub fn random(rng: &mut Rng, min_scale_m: f64, max_scale_m: f64) -> Self {
        let kind = match rng.index(4) {
            0 => PatternKind::Checker,
            1 => PatternKind::Stripes,
            2 => PatternKind::Noise,
            _ => PatternKind::Cells,
        };
        let a = random_colour(rng);
        let mut b = random_colour(rng);
        for _ in 0..8 {
            if contrast(&a, &b) >= 0.25 {
                break;
            }
            b = random_colour(rng);
        }
        let scale = (rng.range(min_scale_m.ln(), max_scale_m.ln())).exp();
        let d = random_unit(rng);
        Self {
            kind,
            a,
            b,
            scale_m: scale as f32,
            dir: [d.x as f32, d.y as f32, d.z as f32],
            seed: (rng.next_u64() >> 32) as u32,
        }
    }

    /// Albedo at object coordinates `p` seen with a footprint of `footprint_m` metres.
    pub fn albedo(&self, p: &Vector3<f64>, footprint_m: f64) -> Rgb {
        let s = f64::from(self.scale_m);
        let fp = footprint_m as f32;
        let q = [p.x as f32, p.y as f32, p.z as f32];
        let t = match self.kind {
            PatternKind::Checker => {
                // E[(-1)^(i+j+k)] over a separable box footprint is the product per axis.
                let sign = |x: f64| 2.0 * periodic_coverage(x, 2.0 * s, 0.0, s, footprint_m) - 1.0;
                (0.5 * (1.0 - sign(p.x) * sign(p.y) * sign(p.z))) as f32
            }
            PatternKind::Stripes => {
                let d = Vector3::new(
                    f64::from(self.dir[0]),
                    f64::from(self.dir[1]),
                    f64::from(self.dir[2]),
                );
                periodic_coverage(p.dot(&d), s, 0.0, 0.5 * s, footprint_m) as f32
            }
            PatternKind::Noise => {
                let v = fbm3(q, self.seed, 1.0 / self.scale_m, 6, fp);
                ((v - 0.5) * 3.0 + 0.5).clamp(0.0, 1.0)
            }
            PatternKind::Cells => {
                let cell = |x: f64| (x / s).floor() as i32;
                let r = lattice_unit(cell(p.x), cell(p.y), cell(p.z), self.seed);
                // Fade to the mean once cells shrink below a few pixels.
                let vis = (1.0 - (footprint_m / s - 0.25) / 0.5).clamp(0.0, 1.0) as f32;
                0.5 + vis * (r - 0.5)
            }
        };
        let c = mix(self.a, self.b, t);
        // Fine grain at a fifth of the feature size keeps flat regions textured.
        let g = fbm3(q, self.seed ^ 0x9A1, 5.0 / self.scale_m, 3, fp);
        let k = 0.75 + 0.5 * g;
        [c[0] * k, c[1] * k, c[2] * k]
    }
}

/// What lies at infinity in a random-objects scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Background {
    /// The street scenes' sky (gradient, clouds, sun).
    Sky,
    /// A pattern on the unit sphere of directions (`scale_m` read as radians).
    Pattern(Pattern),
}

impl Background {
    /// Colour towards unit direction `d`, band-limited by `pixel_angle_rad`.
    pub fn colour(
        &self,
        d: &Vector3<f64>,
        sun: &Vector3<f64>,
        pixel_angle_rad: f64,
        seed: u32,
    ) -> Rgb {
        match self {
            Background::Sky => super::sky::sky(d, sun, pixel_angle_rad, seed),
            Background::Pattern(p) => p.albedo(d, pixel_angle_rad),
        }
    }
}
