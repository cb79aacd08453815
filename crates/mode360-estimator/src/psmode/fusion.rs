//! Stage 2, fusion: the fusion network's weights (shipped, named or none), how the pairs'
//! aligned ranges become one ([`PairFusion`]), the network's input tensors and the most
//! confident pair per pixel used without it.

use super::PairwiseEstimate;
use crate::EstimatorError;
use candle_core::{Device, Tensor};
use mode360_core::geometry::AlignedRange;
use mode360_core::shipped::{self, BuiltinFile};
use mode360_model::model::fusion::{index_and_confidence, pair_input, PAIR_INPUT_CHANNELS};
use mode360_model::model::{Fusion, FusionConfig, FusionHead, ModelError};
use std::path::{Path, PathBuf};

/// The shipped fusion network (stage 2), a [`FusionHead::Select`] network that scores the pairs
/// per pixel and blends their ranges ([`blend`]), found like every shipped file
/// ([`mode360_core::shipped`]); `--fusion-weights` names it. Not PSMODE's default: it gains a
/// few tenths of a point over the pairs' [`consensus`] for a network pass at the output's width
/// (models/README.md, "The select head"), and the consensus needs no weights.
pub const DEFAULT_FUSION_WEIGHTS_PATH: &str = "models/psmode_fusion.safetensors";

/// `--fusion-weights none` (the node's `fusion_weights: none`): no fusion network, the most
/// confident pair per pixel (the paper's "without fusion").
pub const NO_FUSION: &str = "none";

/// `--fusion-weights consensus` (the node's `fusion_weights: consensus`), and the default: no
/// fusion network, per pixel the range the pairs agree on ([`consensus`]). Held out it reads
/// 0.2 to 1.5 points of δ1 more than the most confident pair on every row (models/README.md).
pub const CONSENSUS_FUSION: &str = "consensus";

/// Two pairs agree on a pixel when their ranges differ by less than this factor (the δ1
/// threshold of the metrics).
pub const AGREEMENT_RATIO: f64 = mode360_core::metrics::DELTA_THRESHOLD;

/// The shipped fusion network, built into the binary.
pub const BUILTIN_FUSION_WEIGHTS: &[BuiltinFile] = &[BuiltinFile {
    relative: DEFAULT_FUSION_WEIGHTS_PATH,
    bytes: include_bytes!("../../../../models/psmode_fusion.safetensors"),
}];

/// The fusion weights a setting names: [`NO_FUSION`] none (the most confident pair), `None`
/// (unset) and [`CONSENSUS_FUSION`] the pairs' consensus, returned as [`CONSENSUS_FUSION`]
/// (it names no file), anything else that file, located as [`mode360_core::shipped`] says
/// (so the shipped [`DEFAULT_FUSION_WEIGHTS_PATH`] is found wherever the binary runs).
pub fn fusion_weights_path(setting: Option<&Path>) -> Option<PathBuf> {
    match setting {
        None => Some(PathBuf::from(CONSENSUS_FUSION)),
        Some(p) if p == Path::new(NO_FUSION) => None,
        Some(p) if p == Path::new(CONSENSUS_FUSION) => Some(p.to_path_buf()),
        Some(p) => Some(shipped::locate_path(p, BUILTIN_FUSION_WEIGHTS)),
    }
}

/// How the pairs' aligned ranges become one.
#[derive(Clone, Debug, Default)]
pub enum PairFusion {
    /// Per pixel, the pair with the highest confidence (the paper's "without fusion").
    #[default]
    MostConfident,
    /// Per pixel, the range the pairs agree on ([`consensus`]).
    Consensus,
    /// The trained fusion network (stage 2) on its own grid, resampled to the output.
    Network(Box<Fusion>),
}

/// The fusion network's input tensors from stage 1's result on the network's grid:
/// `pairs (1, P, H, W, 3)`, `base (1, H, W, 2)` (the most confident pair, or the pairs'
/// [`consensus`] for a [`FusionHead::Select`] network) and `rgb (1, H, W, 3)`.
pub fn fusion_tensors(
    cfg: &FusionConfig,
    pairwise: &PairwiseEstimate,
    device: &Device,
) -> Result<(Tensor, Tensor, Tensor), EstimatorError> {
    let grid = pairwise.grid;
    let (h, w) = (grid.height(), grid.width());
    if !cfg.runs_on(w) {
        return Err(EstimatorError::BadConfig {
            field: "fusion".to_string(),
            problem: format!(
                "stage 1 ran on {w}x{h}, the fusion network needs {}x{}",
                cfg.width,
                cfg.height()
            ),
        });
    }
    let p = pairwise.aligned.len();
    if pairwise.parallax_m.len() != p || pairwise.reference_rgb.len() != grid.len() * 3 {
        return Err(EstimatorError::BadConfig {
            field: "fusion".to_string(),
            problem: "stage 1 ran without the fusion's inputs (parallax, reference panorama)"
                .to_string(),
        });
    }
    let pairs: Vec<f32> = pairwise
        .aligned
        .iter()
        .zip(&pairwise.parallax_m)
        .flat_map(|(a, p)| pair_input(cfg, &a.range_m, &a.confidence, p))
        .collect();
    let (base_range, base_conf) = match cfg.head {
        FusionHead::Correction => most_confident(&pairwise.aligned, grid.len()),
        FusionHead::Select => {
            let max_range_m = cfg.max_depth_m as f32;
            let (mut range, conf) = consensus(&pairwise.aligned, grid.len(), max_range_m);
            // the consensus writes the far plane as +Inf: index 0 with its confidence
            for r in range.iter_mut().filter(|r| r.is_infinite()) {
                *r = max_range_m;
            }
            (range, conf)
        }
    };
    let base = index_and_confidence(cfg, &base_range, &base_conf);
    let tensor_err = |e: candle_core::Error| EstimatorError::Model(ModelError::Candle(e));
    Ok((
        Tensor::from_vec(pairs, (1, p, h, w, PAIR_INPUT_CHANNELS), device).map_err(tensor_err)?,
        Tensor::from_vec(base, (1, h, w, 2), device).map_err(tensor_err)?,
        Tensor::from_vec(pairwise.reference_rgb.clone(), (1, h, w, 3), device)
            .map_err(tensor_err)?,
    ))
}

/// Per output pixel, the range the pairs agree on, with ranges capped at `max_range_m` (a
/// pair reading the sky agrees with one reading the far field):
///
/// ```text
/// agree(i, j)  = |ln r_i - ln r_j| < ln AGREEMENT_RATIO
/// support(i)   = sum of c_j over the pairs j that agree with i
/// m            = the pair of most support (ties: the more confident)
/// ln r         = sum c_j ln r_j / sum c_j   over the pairs j that agree with m
/// c            = max c_j over them * (their support / sum of every pair's c)
/// ```
///
/// A range at `max_range_m` comes out as `+Inf` (REP 117); NaN and 0 where no pair has a range.
/// Where one pair errs and the others agree the majority wins, where the most confident pair
/// would take the error (network confidences saturate at 0.9 to 0.99 on every pair).
pub(super) fn consensus(
    aligned: &[AlignedRange],
    pixels: usize,
    max_range_m: f32,
) -> (Vec<f32>, Vec<f32>) {
    let tolerance = AGREEMENT_RATIO.ln() as f32;
    let ln_max = max_range_m.ln();
    let mut range = vec![f32::NAN; pixels];
    let mut conf = vec![0.0f32; pixels];
    // (ln range, confidence) of the pairs with a range at the pixel
    let mut votes: Vec<(f32, f32)> = Vec::with_capacity(aligned.len());
    for k in 0..pixels {
        votes.clear();
        votes.extend(aligned.iter().filter_map(|a| {
            let r = a.range_m[k];
            (!r.is_nan() && r > 0.0).then(|| (r.min(max_range_m).ln(), a.confidence[k].max(0.0)))
        }));
        let agree = |l: f32| votes.iter().filter(move |(m, _)| (m - l).abs() < tolerance);
        // each vote's support once, then the best (support, confidence)
        let Some((mode, _)) = votes
            .iter()
            .map(|&(l, c)| (l, (agree(l).map(|(_, c)| c).sum::<f32>(), c)))
            .max_by(|a, b| a.1.partial_cmp(&b.1).unwrap_or(std::cmp::Ordering::Equal))
        else {
            continue;
        };
        let (mut weight, mut sum, mut best) = (0.0f32, 0.0f32, 0.0f32);
        for &(l, c) in agree(mode) {
            weight += c;
            sum += c * l;
            best = best.max(c);
        }
        let total: f32 = votes.iter().map(|(_, c)| c).sum();
        let ln_r = if weight > 0.0 { sum / weight } else { mode };
        range[k] = if ln_r >= ln_max {
            f32::INFINITY
        } else {
            ln_r.exp()
        };
        conf[k] = if total > 0.0 {
            best * weight / total
        } else {
            0.0
        };
    }
    (range, conf)
}

/// Per output pixel, the pairs' ranges blended in log range by a [`FusionHead::Select`]
/// network's weights, `weights` `(H, W, P)` on the same grid (resampled from the network's):
///
/// ```text
/// ln r = sum_p w_p ln min(r_p, max) / sum_p w_p   over the pairs p with a range there
/// ```
///
/// `+Inf` at the far plane; the most confident pair where the weights of the pairs with a
/// range there vanish; NaN where no pair has one.
pub(super) fn blend(
    aligned: &[AlignedRange],
    weights: &[f32],
    pixels: usize,
    max_range_m: f32,
) -> Vec<f32> {
    let p = aligned.len();
    let ln_max = max_range_m.ln();
    (0..pixels)
        .map(|k| {
            let (mut sum, mut weight) = (0.0f32, 0.0f32);
            for (j, a) in aligned.iter().enumerate() {
                let r = a.range_m[k];
                if !r.is_nan() && r > 0.0 {
                    let w = weights[k * p + j].max(0.0);
                    sum += w * r.min(max_range_m).ln();
                    weight += w;
                }
            }
            if weight <= WEIGHT_FLOOR {
                return most_confident_at(aligned, k).map_or(f32::NAN, |(r, _)| r);
            }
            let ln_r = sum / weight;
            if ln_r >= ln_max {
                f32::INFINITY
            } else {
                ln_r.exp()
            }
        })
        .collect()
}

/// Below this the blend's weights say nothing (resampling can leave a pair's weight on a
/// pixel where another pair has the range).
const WEIGHT_FLOOR: f32 = 1e-6;

/// Per output pixel, the aligned pair with the highest confidence (NaN and 0 where none).
pub(super) fn most_confident(aligned: &[AlignedRange], pixels: usize) -> (Vec<f32>, Vec<f32>) {
    (0..pixels)
        .map(|k| most_confident_at(aligned, k).unwrap_or((f32::NAN, 0.0)))
        .unzip()
}

/// At pixel `k`, the (range, confidence) of the aligned pair with the highest confidence, the
/// first of equals; `None` where no pair has a range.
fn most_confident_at(aligned: &[AlignedRange], k: usize) -> Option<(f32, f32)> {
    aligned
        .iter()
        .map(|a| (a.range_m[k], a.confidence[k]))
        .filter(|(r, _)| !r.is_nan())
        .fold(None, |best, (r, c)| match best {
            Some((_, bc)) if c <= bc => best,
            _ => Some((r, c)),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_most_confident_pair_wins_each_pixel() {
        let a = AlignedRange {
            range_m: vec![1.0, f32::NAN, 3.0],
            confidence: vec![0.9, 0.0, 0.2],
        };
        let b = AlignedRange {
            range_m: vec![2.0, 5.0, 4.0],
            confidence: vec![0.5, 0.1, 0.6],
        };
        let (r, c) = most_confident(&[a, b], 3);
        assert_eq!(r, vec![1.0, 5.0, 4.0]);
        assert_eq!(c, vec![0.9, 0.1, 0.6]);
    }

    #[test]
    fn the_blend_weighs_the_pairs_with_a_range_in_log_range() {
        let pair = |range_m: Vec<f32>| AlignedRange {
            confidence: vec![0.5; range_m.len()],
            range_m,
        };
        // pixel 0: weights 3:1 on 2 m and 32 m; pixel 1: the weighted pair has no range, so
        // the other one's 5 m; pixel 2: both at or past the far plane; pixel 3: no range
        let pairs = [
            pair(vec![2.0, f32::NAN, f32::INFINITY, f32::NAN]),
            pair(vec![32.0, 5.0, 2000.0, f32::NAN]),
        ];
        let weights = [0.75, 0.25, 1.0, 0.0, 0.5, 0.5, 0.5, 0.5];
        let r = blend(&pairs, &weights, 4, 1000.0);
        // exp(0.75 ln 2 + 0.25 ln 32) = 2^(0.75 + 1.25) = 4
        assert!((r[0] - 4.0).abs() < 1e-4, "{}", r[0]);
        assert_eq!(
            r[1], 5.0,
            "the weights vanish there: the most confident pair"
        );
        assert_eq!(r[2], f32::INFINITY);
        assert!(r[3].is_nan());
    }

    #[test]
    fn the_pairs_that_agree_outvote_the_most_confident_one() {
        // pixel 0: one confident pair at 10 m, two at 4 and 4.2 m (within 1.25 of each other)
        // pixel 1: no pair has a range
        // pixel 2: the sky and 2 km (both past the 1 km cap, so they agree) against 5 m
        let pair = |range_m: Vec<f32>, confidence: Vec<f32>| AlignedRange {
            range_m,
            confidence,
        };
        let pairs = [
            pair(vec![10.0, f32::NAN, f32::INFINITY], vec![0.99, 0.0, 0.9]),
            pair(vec![4.0, f32::NAN, 2000.0], vec![0.9, 0.0, 0.8]),
            pair(vec![4.2, f32::NAN, 5.0], vec![0.9, 0.0, 0.95]),
        ];
        let (r, c) = consensus(&pairs, 3, 1000.0);
        // the confidence-weighted mean of ln 4 and ln 4.2 (equal weights): sqrt(4 * 4.2)
        assert!((r[0] - (4.0f32 * 4.2).sqrt()).abs() < 1e-4, "{}", r[0]);
        assert!((c[0] - 0.9 * 1.8 / 2.79).abs() < 1e-6, "{}", c[0]);
        assert!(r[1].is_nan());
        assert_eq!(c[1], 0.0);
        assert_eq!(r[2], f32::INFINITY);
        assert!((c[2] - 0.9 * 1.7 / 2.65).abs() < 1e-6, "{}", c[2]);
        // the most confident pair would have taken 10 m and 5 m
        let (r, _) = most_confident(&pairs, 3);
        assert_eq!((r[0], r[2]), (10.0, 5.0));
    }
}
