//! Reading one pixel's cost curve: winner-take-all with parabolic refinement and the
//! confidence margin to the best hypothesis outside the winner's neighbourhood.

/// Hypotheses within this many indices of the winner are ignored when looking for the
/// runner-up cost of the confidence margin.
pub const CONFIDENCE_EXCLUSION: usize = 2;

/// Result of winner-take-all on one pixel's cost curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurveMinimum {
    /// Fractional hypothesis index after parabolic refinement.
    pub index: f64,
    /// Integer winner.
    pub winner: usize,
    /// `S_2 - S(i*)`, the margin to the best hypothesis outside the exclusion zone.
    pub margin: f32,
}

/// Winner-take-all with parabolic refinement on one cost curve (see the module docs).
/// Ties go to the farther (lower) index; the offset is clamped to half a step.
pub fn refine_minimum(curve: &[f32], refine: bool) -> CurveMinimum {
    let mut winner = 0;
    for (i, &c) in curve.iter().enumerate() {
        if c < curve[winner] {
            winner = i;
        }
    }
    let best = curve.get(winner).copied().unwrap_or(0.0);
    let mut index = winner as f64;
    if refine && winner > 0 && winner + 1 < curve.len() {
        let (l, r) = (curve[winner - 1] as f64, curve[winner + 1] as f64);
        let curvature = l - 2.0 * best as f64 + r;
        if curvature > 0.0 {
            index += ((l - r) / (2.0 * curvature)).clamp(-0.5, 0.5);
        }
    }
    let runner_up = curve
        .iter()
        .enumerate()
        .filter(|(i, _)| i.abs_diff(winner) > CONFIDENCE_EXCLUSION)
        .map(|(_, &c)| c)
        .fold(f32::INFINITY, f32::min);
    let margin = if runner_up.is_finite() {
        (runner_up - best).max(0.0)
    } else {
        0.0
    };
    CurveMinimum {
        index,
        winner,
        margin,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parabola_finds_the_vertex_between_hypotheses() {
        // Samples of (i - 3.3)^2 at i = 0..8.
        let curve: Vec<f32> = (0..8).map(|i| (i as f32 - 3.3).powi(2)).collect();
        let m = refine_minimum(&curve, true);
        assert_eq!(m.winner, 3);
        assert!((m.index - 3.3).abs() < 1e-4, "{}", m.index);
        let plain = refine_minimum(&curve, false);
        assert_eq!(plain.index, 3.0);
        // Runner-up outside +-2: i = 6 (7.29) vs i = 0 (10.89).
        assert!((m.margin - (2.7f32.powi(2) - 0.09)).abs() < 1e-4);
    }
}
