//! Stage 2, fusion: the fusion network's weights (shipped, named or none), how the pairs'
//! aligned ranges become one ([`PairFusion`]), the network's input tensors and the most
//! confident pair per pixel used without it.

use super::PairwiseEstimate;
use crate::EstimatorError;
use candle_core::{Device, Tensor};
use mode360_core::geometry::AlignedRange;
use mode360_core::shipped::{self, BuiltinFile};
use mode360_model::model::fusion::{index_and_confidence, pair_input, PAIR_INPUT_CHANNELS};
use mode360_model::model::{Fusion, FusionConfig, ModelError};
use std::path::{Path, PathBuf};

/// The shipped fusion network (stage 2), found like every shipped file
/// ([`mode360_core::shipped`]). Not PSMODE's default: on held-out cluttered streets it costs
/// more than it gains on clean ones (models/README.md); `--fusion-weights` names it.
pub const DEFAULT_FUSION_WEIGHTS_PATH: &str = "models/psmode_fusion.safetensors";

/// `--fusion-weights none` (the node's `fusion_weights: none`, and the default): no fusion
/// network, the most confident pair per pixel (the paper's "without fusion").
pub const NO_FUSION: &str = "none";

/// The shipped fusion network, built into the binary.
pub const BUILTIN_FUSION_WEIGHTS: &[BuiltinFile] = &[BuiltinFile {
    relative: DEFAULT_FUSION_WEIGHTS_PATH,
    bytes: include_bytes!("../../../../models/psmode_fusion.safetensors"),
}];

/// The fusion weights a setting names: `None` (unset) and [`NO_FUSION`] none, anything else
/// that file, located as [`mode360_core::shipped`] says (so the shipped
/// [`DEFAULT_FUSION_WEIGHTS_PATH`] is found wherever the binary runs).
pub fn fusion_weights_path(setting: Option<&Path>) -> Option<PathBuf> {
    match setting {
        None => None,
        Some(p) if p == Path::new(NO_FUSION) => None,
        Some(p) => Some(shipped::locate_path(p, BUILTIN_FUSION_WEIGHTS)),
    }
}

/// How the pairs' aligned ranges become one.
#[derive(Clone, Debug, Default)]
pub enum PairFusion {
    /// Per pixel, the pair with the highest confidence (the paper's "without fusion").
    #[default]
    MostConfident,
    /// The trained fusion network (stage 2) on its own grid, resampled to the output.
    Network(Box<Fusion>),
}

/// The fusion network's input tensors from stage 1's result on the network's grid:
/// `pairs (1, P, H, W, 2)`, `base (1, H, W, 2)` (the most confident pair) and `rgb (1, H, W, 3)`.
pub fn fusion_tensors(
    cfg: &FusionConfig,
    pairwise: &PairwiseEstimate,
    device: &Device,
) -> Result<(Tensor, Tensor, Tensor), EstimatorError> {
    let grid = pairwise.grid;
    let (h, w) = (grid.height(), grid.width());
    if (h, w) != (cfg.height(), cfg.width) {
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
    let (base_range, base_conf) = most_confident(&pairwise.aligned, grid.len());
    let base = index_and_confidence(cfg, &base_range, &base_conf);
    let tensor_err = |e: candle_core::Error| EstimatorError::Model(ModelError::Candle(e));
    Ok((
        Tensor::from_vec(pairs, (1, p, h, w, PAIR_INPUT_CHANNELS), device).map_err(tensor_err)?,
        Tensor::from_vec(base, (1, h, w, 2), device).map_err(tensor_err)?,
        Tensor::from_vec(pairwise.reference_rgb.clone(), (1, h, w, 3), device)
            .map_err(tensor_err)?,
    ))
}

/// Per output pixel, the aligned pair with the highest confidence (NaN and 0 where none).
pub(super) fn most_confident(aligned: &[AlignedRange], pixels: usize) -> (Vec<f32>, Vec<f32>) {
    let mut range = vec![f32::NAN; pixels];
    let mut conf = vec![0.0f32; pixels];
    for a in aligned {
        for k in 0..pixels {
            if !a.range_m[k].is_nan() && (range[k].is_nan() || a.confidence[k] > conf[k]) {
                range[k] = a.range_m[k];
                conf[k] = a.confidence[k];
            }
        }
    }
    (range, conf)
}
