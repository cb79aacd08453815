//! Where a run's weights start: the seeded random initialisation ([`SeededVarMap`], so that a
//! fresh run and a resumed one draw the same weights) or fine-tuning start weights
//! ([`load_init_weights`], checked against the run's architecture).

use super::options::TrainError;
use crate::model::{ModelError, SsmodeConfig};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use std::path::Path;

/// Layer sizes of `cfg` (what weights depend on; not the width, name or readout).
fn architecture(cfg: &SsmodeConfig) -> String {
    format!(
        "features {:?} x {:?} -> {}, fine branch {} at 1/{}, {:?} cost over {} spheres, \
         entry stride {}, {} hourglasses of {} channels",
        cfg.feature_channels,
        cfg.feature_blocks,
        cfg.feature_out_channels,
        cfg.fine_channels,
        cfg.cost_downsample,
        cfg.cost,
        cfg.spheres,
        cfg.aggregation_stride,
        cfg.hourglasses,
        cfg.hourglass_channels
    )
}

/// Loads fine-tuning start weights into `varmap` after checking their architecture.
pub(super) fn load_init_weights(
    path: &Path,
    cfg: &SsmodeConfig,
    varmap: &mut VarMap,
) -> Result<(), TrainError> {
    let file_cfg = crate::model::read_config(path)?;
    if architecture(&file_cfg) != architecture(cfg) {
        return Err(TrainError::Option {
            option: "init_weights",
            problem: format!(
                "{} holds a '{}' network ({}), the run trains '{}' ({})",
                path.display(),
                file_cfg.name,
                architecture(&file_cfg),
                cfg.name,
                architecture(cfg)
            ),
        });
    }
    varmap.load(path).map_err(|e| {
        TrainError::Model(ModelError::Weights {
            path: path.display().to_string(),
            problem: format!("loading the start weights: {e}"),
        })
    })
}

/// Sorted named variables of a var map.
pub(super) fn named_vars(varmap: &VarMap) -> Result<Vec<(String, Var)>, TrainError> {
    let data = varmap
        .data()
        .lock()
        .map_err(|_| TrainError::Other("variable map lock poisoned".into()))?;
    let mut v: Vec<(String, Var)> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(v)
}

/// Domain-separation word of the weight-initialization stream.
const INIT_TAG: u64 = 0x1417;

/// A [`VarMap`] backend whose random initializations are a function of a seed (candle's CPU
/// RNG cannot be seeded, and resume exactness is checked against a fresh run). Variable
/// `name` draws from `Rng::new(&[seed, hash(name), INIT_TAG])`: uniform inits directly,
/// normal ones by Box-Muller `mean + stdev sqrt(-2 ln u1) cos(2 pi u2)`, Kaiming with
/// `std = gain / sqrt(fan)` as candle does.
struct SeededVarMap {
    varmap: VarMap,
    seed: u64,
}

/// A variable builder whose new variables land in `varmap`, seeded by `seed`.
pub(super) fn seeded_var_builder(
    varmap: &VarMap,
    seed: u64,
    device: &Device,
) -> VarBuilder<'static> {
    VarBuilder::from_backend(
        Box::new(SeededVarMap {
            varmap: varmap.clone(),
            seed,
        }),
        DType::F32,
        device.clone(),
    )
}

impl SeededVarMap {
    fn draw(&self, shape: &candle_core::Shape, name: &str, init: candle_nn::Init) -> Vec<f32> {
        use crate::synth::noise::{hash_words, Rng};
        use candle_nn::init::NormalOrUniform;
        let n = shape.elem_count();
        let name_hash = hash_words(&name.bytes().map(u64::from).collect::<Vec<_>>());
        let mut rng = Rng::new(&[self.seed, name_hash, INIT_TAG]);
        let mut normal = |mean: f64, stdev: f64| -> Vec<f32> {
            (0..n)
                .map(|_| {
                    let u1 = rng.unit().max(f64::MIN_POSITIVE);
                    let u2 = rng.unit();
                    let z = (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos();
                    (mean + stdev * z) as f32
                })
                .collect()
        };
        match init {
            candle_nn::Init::Const(c) => vec![c as f32; n],
            candle_nn::Init::Randn { mean, stdev } => normal(mean, stdev),
            candle_nn::Init::Uniform { lo, up } => {
                let mut rng = Rng::new(&[self.seed, name_hash, INIT_TAG]);
                (0..n).map(|_| rng.range(lo, up) as f32).collect()
            }
            candle_nn::Init::Kaiming {
                dist,
                fan,
                non_linearity,
            } => {
                let std = non_linearity.gain() / (fan.for_shape(shape).max(1) as f64).sqrt();
                match dist {
                    NormalOrUniform::Uniform => {
                        let bound = 3f64.sqrt() * std;
                        let mut rng = Rng::new(&[self.seed, name_hash, INIT_TAG]);
                        (0..n).map(|_| rng.range(-bound, bound) as f32).collect()
                    }
                    NormalOrUniform::Normal => normal(0.0, std),
                }
            }
        }
    }
}

impl candle_nn::var_builder::SimpleBackend for SeededVarMap {
    fn get(
        &self,
        s: candle_core::Shape,
        name: &str,
        h: candle_nn::Init,
        dtype: DType,
        dev: &Device,
    ) -> candle_core::Result<Tensor> {
        let mut data = self
            .varmap
            .data()
            .lock()
            .map_err(|_| candle_core::Error::Msg("variable map lock poisoned".into()))?;
        if let Some(v) = data.get(name) {
            if v.shape() != &s {
                candle_core::bail!("shape mismatch on {name}: {s:?} <> {:?}", v.shape());
            }
            return Ok(v.as_tensor().clone());
        }
        let values = self.draw(&s, name, h);
        let t = Tensor::from_vec(values, s, dev)?.to_dtype(dtype)?;
        let var = Var::from_tensor(&t)?;
        let out = var.as_tensor().clone();
        data.insert(name.to_string(), var);
        Ok(out)
    }

    fn get_unchecked(
        &self,
        name: &str,
        _dtype: DType,
        _dev: &Device,
    ) -> candle_core::Result<Tensor> {
        candle_core::bail!("variable '{name}' must be created with a shape")
    }

    fn contains_tensor(&self, name: &str) -> bool {
        self.varmap
            .data()
            .lock()
            .map(|d| d.contains_key(name))
            .unwrap_or(false)
    }
}
