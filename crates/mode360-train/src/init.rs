//! Where a run's weights start: the seeded random initialisation ([`SeededVarMap`], so that a
//! fresh run and a resumed one draw the same weights) or fine-tuning start weights
//! ([`load_init_weights`], checked against the run's architecture).

use super::options::TrainError;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use mode360_model::model::fine_head::FINE_HEAD_PREFIX;
use mode360_model::model::{ModelError, SsmodeConfig};
use std::path::Path;

/// Layer sizes of `cfg` (what weights depend on; not the width, name or readout).
fn architecture(cfg: &SsmodeConfig) -> String {
    format!(
        "features {:?} x {:?} -> {}, fine branch {} at 1/{}, {:?} cost over {} spheres, \
         entry stride {}, {} hourglasses of {} channels, photometric cost channel {}, \
         fine head of {} channels",
        cfg.feature_channels,
        cfg.feature_blocks,
        cfg.feature_out_channels,
        cfg.fine_channels,
        cfg.cost_downsample,
        cfg.cost,
        cfg.spheres,
        cfg.aggregation_stride,
        cfg.hourglasses,
        cfg.hourglass_channels,
        cfg.photometric_cost,
        cfg.fine_head_channels
    )
}

/// The aggregation's entry convolution, the one layer that the photometric cost channel
/// widens.
const ENTRY_CONV_WEIGHT: &str = "aggregation.dres0.0.weight";
/// Input-channel axis of a 3-D convolution weight `(3, 3, 3, Cin, Cout)`.
const CONV3D_INPUT_AXIS: usize = 3;

/// Whether `file` is `cfg` without its photometric cost channel: its weights start a run of
/// `cfg` with the entry convolution widened by zeros ([`load_widened`]).
fn widens_to(file: &SsmodeConfig, cfg: &SsmodeConfig) -> bool {
    cfg.photometric_cost
        && !file.photometric_cost
        && architecture(&SsmodeConfig {
            photometric_cost: true,
            ..file.clone()
        }) == architecture(cfg)
}

/// Whether `file` is `cfg` without its fine head ([`mode360_model::model::fine_head`]): its
/// weights start a run of `cfg` with the head freshly initialized, whose output layer starts
/// at zero ([`load_widened`] with `new_fine_head`).
fn adds_fine_head(file: &SsmodeConfig, cfg: &SsmodeConfig) -> bool {
    cfg.fine_head_channels > 0
        && file.fine_head_channels == 0
        && architecture(&SsmodeConfig {
            fine_head_channels: cfg.fine_head_channels,
            ..file.clone()
        }) == architecture(cfg)
}

/// Loads `path` into `varmap`, widening the entry convolution by zero weights for the
/// channels the file lacks, and with `new_fine_head` keeping the fresh initialization of the
/// fine head's variables the file lacks: at the start the network computes what the file's
/// network did, and training brings the new channel or head in.
fn load_widened(path: &Path, varmap: &mut VarMap, new_fine_head: bool) -> Result<(), TrainError> {
    let weights_err = |problem: String| {
        TrainError::Model(ModelError::Weights {
            path: path.display().to_string(),
            problem,
        })
    };
    let file = candle_core::safetensors::load(path, &Device::Cpu)
        .map_err(|e| weights_err(format!("loading the start weights: {e}")))?;
    let data = varmap
        .data()
        .lock()
        .map_err(|_| TrainError::Other("variable map lock poisoned".into()))?;
    let head_prefix = format!("{FINE_HEAD_PREFIX}.");
    for (name, var) in data.iter() {
        let fresh = new_fine_head && name.starts_with(&head_prefix);
        let Some(t) = file.get(name) else {
            if fresh {
                continue;
            }
            return Err(weights_err(format!("no tensor '{name}'")));
        };
        let want = var.as_tensor().dims().to_vec();
        let t = if name == ENTRY_CONV_WEIGHT && t.dims() != want.as_slice() {
            let mut extra = want.clone();
            extra[CONV3D_INPUT_AXIS] = want[CONV3D_INPUT_AXIS]
                .checked_sub(t.dims().get(CONV3D_INPUT_AXIS).copied().unwrap_or(0))
                .ok_or_else(|| weights_err(format!("'{name}' is wider than the network's")))?;
            let zeros = Tensor::zeros(extra, t.dtype(), t.device())?;
            Tensor::cat(&[t, &zeros], CONV3D_INPUT_AXIS)?
        } else {
            t.clone()
        };
        if t.dims() != want.as_slice() {
            return Err(weights_err(format!(
                "'{name}' is {:?}, the network needs {want:?}",
                t.dims()
            )));
        }
        var.set(&t.to_device(var.device())?)?;
    }
    Ok(())
}

/// Loads fine-tuning start weights into `varmap` after checking their architecture.
pub(super) fn load_init_weights(
    path: &Path,
    cfg: &SsmodeConfig,
    varmap: &mut VarMap,
) -> Result<(), TrainError> {
    let file_cfg = mode360_model::model::read_config(path)?;
    if widens_to(&file_cfg, cfg) {
        return load_widened(path, varmap, false);
    }
    if adds_fine_head(&file_cfg, cfg) {
        return load_widened(path, varmap, true);
    }
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
        use candle_nn::init::NormalOrUniform;
        use mode360_synth::noise::{hash_words, Rng};
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

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_model::model::{Ssmode, SweepSampling};

    /// Random images in [0, 1], one `(1, H, W, 3)` tensor per camera.
    fn images(cfg: &SsmodeConfig, cameras: usize) -> Vec<Tensor> {
        use mode360_synth::noise::Rng;
        let mut rng = Rng::new(&[7, 0x1417]);
        let n = cfg.height() * cfg.width * 3;
        (0..cameras)
            .map(|_| {
                let v: Vec<f32> = (0..n).map(|_| rng.unit() as f32).collect();
                Tensor::from_vec(v, (1, cfg.height(), cfg.width, 3), &Device::Cpu).unwrap()
            })
            .collect()
    }

    /// Saves a `narrow_cfg` network, starts a `wide_cfg` one from it and checks that the
    /// entry convolution gained `added` zero input channels and the output did not change.
    fn check_widening(narrow_cfg: &SsmodeConfig, wide_cfg: &SsmodeConfig, added: usize) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("narrow.safetensors");
        let narrow_map = VarMap::new();
        let narrow =
            Ssmode::new(narrow_cfg, seeded_var_builder(&narrow_map, 3, &Device::Cpu)).unwrap();
        mode360_model::model::save_weights(&narrow_map, narrow_cfg, &path).unwrap();

        let mut wide_map = VarMap::new();
        let wide = Ssmode::new(wide_cfg, seeded_var_builder(&wide_map, 9, &Device::Cpu)).unwrap();
        load_init_weights(&path, wide_cfg, &mut wide_map).unwrap();
        let entry = wide_map.data().lock().unwrap()[ENTRY_CONV_WEIGHT]
            .as_tensor()
            .clone();
        let c = narrow_cfg.cost_volume_channels();
        assert_eq!(entry.dims()[CONV3D_INPUT_AXIS], c + added);
        let new_channels: Vec<f32> = entry
            .narrow(CONV3D_INPUT_AXIS, c, added)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        assert!(new_channels.iter().all(|&w| w == 0.0));

        let rig = mode360_io::deep360::deep360_rig().unwrap();
        let imgs = images(narrow_cfg, rig.cameras.len());
        let run = |model: &Ssmode, cfg: &SsmodeConfig| -> Vec<f32> {
            let sampling = SweepSampling::new(&rig, cfg).unwrap();
            let out = model.forward(&imgs, &sampling, false).unwrap();
            out.stages[0].flatten_all().unwrap().to_vec1().unwrap()
        };
        let a = run(&narrow, narrow_cfg);
        let b = run(&wide, wide_cfg);
        let max_diff = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs() / x.abs().max(1.0))
            .fold(0.0f32, f32::max);
        assert!(max_diff < 1e-5, "relative difference {max_diff}");
    }

    #[test]
    fn widened_start_weights_compute_what_the_file_network_did() {
        check_widening(
            &SsmodeConfig::tiny_parallax(),
            &SsmodeConfig::tiny_zncc(),
            1,
        );
    }

    #[test]
    fn start_weights_without_the_fine_head_compute_what_the_file_network_did() {
        let plain = SsmodeConfig::tiny_zncc();
        let fine = SsmodeConfig {
            fine_head_channels: 2,
            ..plain.clone()
        };
        assert!(adds_fine_head(&plain, &fine));
        assert!(!adds_fine_head(&fine, &plain));
        // the head gets no tensors from the file and its output layer starts at zero
        check_widening(&plain, &fine, 0);
    }

    #[test]
    fn widening_goes_one_way() {
        assert!(widens_to(
            &SsmodeConfig::tiny_parallax(),
            &SsmodeConfig::tiny_zncc()
        ));
        assert!(!widens_to(
            &SsmodeConfig::tiny_zncc(),
            &SsmodeConfig::tiny_parallax()
        ));
    }

    #[test]
    fn other_architectures_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tiny.safetensors");
        let cfg = SsmodeConfig::tiny();
        let map = VarMap::new();
        Ssmode::new(&cfg, seeded_var_builder(&map, 3, &Device::Cpu)).unwrap();
        mode360_model::model::save_weights(&map, &cfg, &path).unwrap();
        let mut wide_map = VarMap::new();
        let wide_cfg = SsmodeConfig::tiny_zncc();
        Ssmode::new(&wide_cfg, seeded_var_builder(&wide_map, 9, &Device::Cpu)).unwrap();
        let err = load_init_weights(&path, &wide_cfg, &mut wide_map)
            .unwrap_err()
            .to_string();
        assert!(err.contains("'tiny'") && err.contains("tiny_zncc"), "{err}");
    }
}
