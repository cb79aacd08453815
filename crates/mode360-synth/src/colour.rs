//! Colour arithmetic and box-filtered stripe coverage shared by the street materials
//! ([`super::material`]), the object patterns ([`super::pattern`]) and the sky
//! ([`super::sky`]).

/// Linear RGB.
pub type Rgb = [f32; 3];

/// Fraction of the footprint interval `[x - fp/2, x + fp/2]` covered by the stripe
/// `[lo, hi]` repeated with `period` (a box filter of the stripe indicator).
pub fn periodic_coverage(x: f64, period: f64, lo: f64, hi: f64, footprint_m: f64) -> f64 {
    let duty = (hi - lo) / period;
    if footprint_m >= period {
        return duty;
    }
    let xm = x.rem_euclid(period);
    let half = 0.5 * footprint_m.max(1e-9);
    let (a, b) = (xm - half, xm + half);
    let mut covered = 0.0;
    for k in [-1.0, 0.0, 1.0] {
        let (l, h) = (lo + k * period, hi + k * period);
        covered += (b.min(h) - a.max(l)).max(0.0);
    }
    (covered / (b - a)).clamp(0.0, 1.0)
}

/// Coverage of a single stripe `[lo, hi]` over the footprint around `x`.
pub fn stripe_coverage(x: f64, lo: f64, hi: f64, footprint_m: f64) -> f64 {
    let half = 0.5 * footprint_m.max(1e-9);
    ((x + half).min(hi) - (x - half).max(lo)).max(0.0) / (2.0 * half)
}

pub fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

pub fn scale(a: Rgb, s: f32) -> Rgb {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_box_filter() {
        // Fully inside, outside and half-overlapping a stripe [0, 1].
        assert!((stripe_coverage(0.5, 0.0, 1.0, 0.1) - 1.0).abs() < 1e-12);
        assert!(stripe_coverage(2.0, 0.0, 1.0, 0.1).abs() < 1e-12);
        assert!((stripe_coverage(1.0, 0.0, 1.0, 0.2) - 0.5).abs() < 1e-12);
        // A wide footprint over a periodic stripe gives the duty cycle.
        assert!((periodic_coverage(0.3, 2.0, 0.0, 0.5, 10.0) - 0.25).abs() < 1e-12);
        assert!((periodic_coverage(4.25, 2.0, 0.0, 0.5, 0.1) - 1.0).abs() < 1e-12);
    }
}
