//! Each camera's best turn: a pattern search for `rig refine`, a few Newton steps for the
//! node's drift check.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::check::{scored_pairs, RotationCheck};
use super::frame::CheckFrame;
use super::{CameraCorrection, RotationCheckConfig, MIN_TEXTURED_CELLS};
use mode360_estimator::EstimatorError;

impl RotationCheck {
    /// The best correction of every camera over `frames` (at least one).
    pub fn corrections(
        &self,
        frames: &[CheckFrame],
    ) -> Result<Vec<CameraCorrection>, EstimatorError> {
        let zero = Vector3::zeros();
        let exclusions = frames.iter().any(|f| !f.ranges_without_m.is_empty());
        let shared = if exclusions {
            None
        } else {
            Some(self.prepare(frames, 0)?)
        };
        let corrections = (0..self.rig.cameras.len())
            .into_par_iter()
            .map(|c| {
                let own;
                let prepared = match &shared {
                    Some(p) => p,
                    None => {
                        own = self.prepare(frames, c)?;
                        &own
                    }
                };
                let cells = self.cells(frames, prepared, c);
                let count = scored_pairs(&cells);
                let score =
                    |w: &Vector3<f64>| self.agreement(frames, &prepared.fixed, &cells, c, w);
                let before = score(&zero);
                let (w, after) = if count >= MIN_TEXTURED_CELLS {
                    pattern_search(&score, before, &self.cfg)
                } else {
                    (zero, before)
                };
                Ok(self.correction(c, w, before, after, count))
            })
            .collect::<Result<Vec<_>, EstimatorError>>()?;
        Ok(corrections)
    }
    /// A quick estimate of every camera's correction (the node's drift check): from `w = 0`,
    /// `iterations` diagonal Newton steps on the agreement, each from central differences of
    /// `step_deg` along the rig axes (7 evaluations a step; a step is clamped to 2 `step_deg`
    /// per axis, and where the agreement is not concave it moves uphill by `step_deg`). While
    /// a step still hits that clamp, more steps follow, until the correction could reach
    /// `max_correction_deg` (so a knock larger than `2 iterations step_deg` is not read short).
    pub fn quick_corrections(
        &self,
        frames: &[CheckFrame],
        iterations: usize,
        step_deg: f64,
    ) -> Result<Vec<CameraCorrection>, EstimatorError> {
        let prepared = self.prepare(frames, 0)?;
        let h = step_deg.to_radians();
        let max = self.cfg.max_correction_deg.to_radians();
        Ok((0..self.rig.cameras.len())
            .into_par_iter()
            .map(|c| {
                let cells = self.cells(frames, &prepared, c);
                let count = scored_pairs(&cells);
                let score =
                    |w: &Vector3<f64>| self.agreement(frames, &prepared.fixed, &cells, c, w);
                let mut w = Vector3::zeros();
                let before = score(&w);
                let mut at_w = before;
                if count >= MIN_TEXTURED_CELLS {
                    let most = iterations + (max / (2.0 * h)).ceil() as usize;
                    let mut clamped = true;
                    for i in 0..most {
                        if i >= iterations && !clamped {
                            break;
                        }
                        clamped = false;
                        let mut next = w;
                        for axis in 0..3 {
                            let (mut minus, mut plus) = (w, w);
                            minus[axis] -= h;
                            plus[axis] += h;
                            let (sm, sp) = (score(&minus), score(&plus));
                            let slope = (sp - sm) / (2.0 * h);
                            let curvature = (sp - 2.0 * at_w + sm) / (h * h);
                            next[axis] += if curvature < 0.0 {
                                let newton = -slope / curvature;
                                clamped |= newton.abs() > 2.0 * h;
                                newton.clamp(-2.0 * h, 2.0 * h)
                            } else {
                                h * slope.signum()
                            };
                        }
                        if next.norm() > max {
                            next *= max / next.norm();
                        }
                        let at_next = score(&next);
                        if at_next <= at_w {
                            break;
                        }
                        w = next;
                        at_w = at_next;
                    }
                }
                self.correction(c, w, before, at_w, count)
            })
            .collect())
    }
}

/// Maximizes `score` from `w = 0` (where it is `at_zero`): moves along the rig axes by
/// `step` while that improves, halves the step otherwise; then one parabola per axis
/// through the last step. Returns the best `w` and its score.
fn pattern_search(
    score: &dyn Fn(&Vector3<f64>) -> f64,
    at_zero: f64,
    cfg: &RotationCheckConfig,
) -> (Vector3<f64>, f64) {
    let max = cfg.max_correction_deg.to_radians();
    let min_step = cfg.min_step_deg.to_radians();
    let mut best = Vector3::zeros();
    let mut best_score = at_zero;
    let mut step = cfg.initial_step_deg.to_radians();
    while step >= min_step {
        let mut moved = false;
        for axis in 0..3 {
            for sign in [-1.0, 1.0] {
                let mut candidate = best;
                candidate[axis] += sign * step;
                if candidate.norm() > max {
                    continue;
                }
                let s = score(&candidate);
                if s > best_score {
                    best = candidate;
                    best_score = s;
                    moved = true;
                }
            }
        }
        if !moved {
            step *= 0.5;
        }
    }
    // Sub-step refinement: the vertex of the parabola through -h, 0, +h along each axis.
    let h = 2.0 * step;
    let mut refined = best;
    for axis in 0..3 {
        let mut minus = best;
        minus[axis] -= h;
        let mut plus = best;
        plus[axis] += h;
        let (sm, sp) = (score(&minus), score(&plus));
        let curvature = sm - 2.0 * best_score + sp;
        if curvature < 0.0 {
            let offset = 0.5 * h * (sm - sp) / curvature;
            refined[axis] += offset.clamp(-h, h);
        }
    }
    let refined_score = score(&refined);
    if refined_score > best_score && refined.norm() <= max {
        (refined, refined_score)
    } else {
        (best, best_score)
    }
}
