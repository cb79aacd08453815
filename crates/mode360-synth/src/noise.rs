//! Deterministic hash-based noise: integer hashing, value noise and band-limited fractal sums.
//!
//! Everything here is a pure function of its integer/float inputs, so textures evaluated in
//! world or object coordinates agree between cameras and between runs regardless of threads.

/// SplitMix64 finaliser: a bijective 64-bit mix.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash of a list of words: `h = mix64(h ^ w)` folded over the words.
pub fn hash_words(words: &[u64]) -> u64 {
    words
        .iter()
        .fold(0x5851_F42D_4C95_7F2D, |h, &w| mix64(h ^ w))
}

/// A uniform number in `[0, 1)` from a hash: the top 53 bits over `2^53`.
pub fn unit_from_hash(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A small deterministic random stream (SplitMix64), for generating scene content.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
}

impl Rng {
    pub fn new(seed_words: &[u64]) -> Self {
        Self {
            state: hash_words(seed_words),
        }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.state)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        unit_from_hash(self.next_u64())
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// A uniform index in `0..n` (`n > 0`).
    pub fn index(&mut self, n: usize) -> usize {
        ((self.unit() * n as f64) as usize).min(n.saturating_sub(1))
    }
}

/// Fast 32-bit lattice hash of three integer coordinates and a seed (a PCG-style mix).
#[inline]
pub fn lattice_hash(x: i32, y: i32, z: i32, seed: u32) -> u32 {
    let mut h = seed
        ^ (x as u32).wrapping_mul(0x8DA6_B343)
        ^ (y as u32).wrapping_mul(0xD816_3841)
        ^ (z as u32).wrapping_mul(0xCB1A_B31F);
    h = (h ^ (h >> 16)).wrapping_mul(0x7FEB_352D);
    h = (h ^ (h >> 15)).wrapping_mul(0x846C_A68B);
    h ^ (h >> 16)
}

/// Lattice value in `[0, 1)`.
#[inline]
pub fn lattice_unit(x: i32, y: i32, z: i32, seed: u32) -> f32 {
    (lattice_hash(x, y, z, seed) >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// `floor` without a libm call (baseline x86-64 has no rounding instruction); exact for
/// `|x| < 2^31`.
#[inline]
pub fn fast_floor(x: f32) -> i32 {
    let i = x as i32;
    if (i as f32) > x {
        i - 1
    } else {
        i
    }
}

/// Quintic fade `6t^5 - 15t^4 + 10t^3`.
#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline]
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// 2-D value noise in `[0, 1)`, continuous, one lattice cell per unit.
#[inline]
pub fn value2(x: f32, y: f32, seed: u32) -> f32 {
    let (ix, iy) = (fast_floor(x), fast_floor(y));
    let (tx, ty) = (fade(x - ix as f32), fade(y - iy as f32));
    let a = lattice_unit(ix, iy, 0, seed);
    let b = lattice_unit(ix + 1, iy, 0, seed);
    let c = lattice_unit(ix, iy + 1, 0, seed);
    let d = lattice_unit(ix + 1, iy + 1, 0, seed);
    lerp(lerp(a, b, tx), lerp(c, d, tx), ty)
}

/// 3-D value noise in `[0, 1)`.
#[inline]
pub fn value3(x: f32, y: f32, z: f32, seed: u32) -> f32 {
    let (ix, iy, iz) = (fast_floor(x), fast_floor(y), fast_floor(z));
    let (tx, ty, tz) = (
        fade(x - ix as f32),
        fade(y - iy as f32),
        fade(z - iz as f32),
    );
    let l = |dx: i32, dy: i32, dz: i32| lattice_unit(ix + dx, iy + dy, iz + dz, seed);
    let z0 = lerp(
        lerp(l(0, 0, 0), l(1, 0, 0), tx),
        lerp(l(0, 1, 0), l(1, 1, 0), tx),
        ty,
    );
    let z1 = lerp(
        lerp(l(0, 0, 1), l(1, 0, 1), tx),
        lerp(l(0, 1, 1), l(1, 1, 1), tx),
        ty,
    );
    lerp(z0, z1, tz)
}

/// Octaves whose lattice frequency times the footprint exceeds this are dropped ...
pub const NYQUIST_CUTOFF: f32 = 0.5;
/// ... and faded out linearly from this ratio on.
pub const NYQUIST_FADE_START: f32 = 0.25;

/// Weight of an octave of lattice frequency `freq` (cycles per metre) for a pixel footprint of
/// `footprint_m` metres: 1 below `NYQUIST_FADE_START`, 0 above `NYQUIST_CUTOFF`, linear between.
#[inline]
pub fn octave_weight(freq: f32, footprint_m: f32) -> f32 {
    let r = freq * footprint_m;
    ((NYQUIST_CUTOFF - r) / (NYQUIST_CUTOFF - NYQUIST_FADE_START)).clamp(0.0, 1.0)
}

/// Band-limited 2-D fractal sum centred on 0.5: octave `k` has frequency `base_freq 2^k` and
/// amplitude `2^-k`; octaves too fine for the footprint are replaced by their mean (0.5).
/// Result normalised to `[0, 1]`.
pub fn fbm2(x: f32, y: f32, seed: u32, base_freq: f32, octaves: u32, footprint_m: f32) -> f32 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut freq = base_freq;
    let mut amp = 1.0;
    for k in 0..octaves {
        let w = octave_weight(freq, footprint_m);
        if w > 0.0 {
            let n = value2(x * freq, y * freq, seed.wrapping_add(k * 0x9E37));
            sum += amp * (0.5 + w * (n - 0.5));
        } else {
            sum += amp * 0.5;
        }
        norm += amp;
        freq *= 2.0;
        amp *= 0.5;
    }
    sum / norm
}

/// Band-limited 3-D fractal sum, like [`fbm2`].
pub fn fbm3(p: [f32; 3], seed: u32, base_freq: f32, octaves: u32, footprint_m: f32) -> f32 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut freq = base_freq;
    let mut amp = 1.0;
    for k in 0..octaves {
        let w = octave_weight(freq, footprint_m);
        if w > 0.0 {
            let n = value3(
                p[0] * freq,
                p[1] * freq,
                p[2] * freq,
                seed.wrapping_add(k * 0x9E37),
            );
            sum += amp * (0.5 + w * (n - 0.5));
        } else {
            sum += amp * 0.5;
        }
        norm += amp;
        freq *= 2.0;
        amp *= 0.5;
    }
    sum / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_noise_is_continuous_and_in_range() {
        let mut max_step = 0.0f32;
        for i in 0..2000 {
            let x = i as f32 * 0.001;
            let a = value2(x, 0.3, 7);
            let b = value2(x + 0.001, 0.3, 7);
            assert!((0.0..1.0).contains(&a));
            max_step = max_step.max((a - b).abs());
        }
        assert!(max_step < 0.01, "step {max_step}");
    }

    #[test]
    fn band_limit_removes_fine_octaves() {
        // With a huge footprint every octave is faded to its mean.
        let v = fbm2(1.3, 2.7, 1, 1.0, 5, 100.0);
        assert!((v - 0.5).abs() < 1e-6);
        let w = fbm2(1.3, 2.7, 1, 1.0, 5, 0.0);
        assert!((w - 0.5).abs() > 1e-4);
    }

    #[test]
    fn rng_is_deterministic() {
        let mut a = Rng::new(&[1, 2]);
        let mut b = Rng::new(&[1, 2]);
        let mut c = Rng::new(&[1, 3]);
        let (x, y, z) = (a.next_u64(), b.next_u64(), c.next_u64());
        assert_eq!(x, y);
        assert_ne!(x, z);
    }
}
