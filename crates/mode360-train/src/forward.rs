//! One sample through the network: the per-rig sweep-table cache ([`SamplingCache`]), the
//! forward pass with its loss ([`forward_sample`]) and the validation pass over the held-out
//! set ([`validation_pass`]); gradient accumulation over a batch ([`accumulate_grads`]).

use super::data::TrainSample;
use super::init::named_vars;
use super::log::ValRecord;
use super::loss::LossConfig;
use super::options::TrainError;
use candle_core::backprop::GradStore;
use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use mode360_core::metrics::{depth_metrics, FrameAverage};
use mode360_model::model::{Ssmode, SsmodeConfig, SweepSampling};

/// Sweep tables of the most recently used rigs (the Deep360 rig of validation and part of
/// training, and a pool of random rigs, see [`super::rig_pool`]), least recently used evicted.
pub(super) struct SamplingCache {
    cached: Vec<(mode360_core::geometry::Rig, SweepSampling)>,
    capacity: usize,
}

/// Rigs kept in the sampling cache at least (the Deep360 rig and the current sample's).
pub(super) const MIN_SAMPLING_CACHE_RIGS: usize = 2;

impl Default for SamplingCache {
    fn default() -> Self {
        Self::with_capacity(MIN_SAMPLING_CACHE_RIGS)
    }
}

impl SamplingCache {
    /// A cache of `capacity` rigs (at least [`MIN_SAMPLING_CACHE_RIGS`]).
    pub(super) fn with_capacity(capacity: usize) -> Self {
        Self {
            cached: Vec::new(),
            capacity: capacity.max(MIN_SAMPLING_CACHE_RIGS),
        }
    }

    pub(super) fn get(
        &mut self,
        rig: &mode360_core::geometry::Rig,
        cfg: &SsmodeConfig,
    ) -> Result<&SweepSampling, TrainError> {
        if let Some(pos) = self.cached.iter().position(|(r, _)| r == rig) {
            // Most recently used last.
            let hit = self.cached.remove(pos);
            self.cached.push(hit);
        } else {
            let s = SweepSampling::new(rig, cfg)?;
            if self.cached.len() >= self.capacity {
                self.cached.remove(0);
            }
            self.cached.push((rig.clone(), s));
        }
        let last = self.cached.len() - 1;
        Ok(&self.cached[last].1)
    }
}

/// Forward pass and loss of one sample.
pub(super) struct SampleResult {
    pub(super) loss: Tensor,
    pub(super) range_m: Tensor,
}

/// Which forward pass [`forward_sample`] runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pass {
    /// Only the final stage, for validation.
    Validate,
    /// Every hourglass regressed, for the stacked loss.
    Train,
    /// The final stage with gradients into the fine head alone
    /// ([`Ssmode::forward_fine_head_only`]).
    TrainFineHead,
}

pub(super) fn forward_sample(
    model: &Ssmode,
    sampling: &SweepSampling,
    sample: &TrainSample,
    loss_cfg: &LossConfig,
    device: &Device,
    pass: Pass,
) -> Result<SampleResult, TrainError> {
    let images = sample
        .images
        .iter()
        .map(|t| t.to_device(device))
        .collect::<Result<Vec<_>, _>>()?;
    let out = match pass {
        Pass::Validate => model.forward(&images, sampling, false)?,
        Pass::Train => model.forward(&images, sampling, true)?,
        Pass::TrainFineHead => model.forward_fine_head_only(&images, sampling)?,
    };
    let target = loss_cfg.target_labelled(&[(&sample.range_m, sample.labels.as_ref())], device)?;
    let loss = loss_cfg.loss(&out.inverse_depth_stages, &target)?;
    let range_m = out
        .stages
        .last()
        .cloned()
        .ok_or_else(|| TrainError::Other("network returned no stages".into()))?;
    Ok(SampleResult { loss, range_m })
}

/// Mean loss and frame-averaged metrics over the validation set.
pub(super) fn validation_pass(
    model: &Ssmode,
    cfg: &SsmodeConfig,
    samples: &[TrainSample],
    cache: &mut SamplingCache,
    loss_cfg: &LossConfig,
    device: &Device,
    step: usize,
) -> Result<ValRecord, TrainError> {
    let mut avg = FrameAverage::default();
    let mut loss_sum = 0.0;
    for s in samples {
        let sampling = cache.get(&s.rig, cfg)?;
        let r = forward_sample(model, sampling, s, loss_cfg, device, Pass::Validate)?;
        loss_sum += f64::from(r.loss.to_dtype(DType::F32)?.to_scalar::<f32>()?);
        let pred: Vec<f32> = r.range_m.flatten_all()?.to_vec1()?;
        let m = depth_metrics(&pred, &s.range_m.data, cfg.max_depth_m)
            .map_err(|e| TrainError::Other(format!("validation metrics: {e}")))?;
        avg.push(m, None);
    }
    Ok(ValRecord {
        step,
        loss: loss_sum / samples.len().max(1) as f64,
        metrics: avg.depth(),
        peak_rss_mib: super::log::peak_rss_mib(),
    })
}

/// `acc + g` over the variables of `varmap` (`g` alone for the first sample of a batch).
pub(super) fn accumulate_grads(
    acc: Option<GradStore>,
    g: GradStore,
    varmap: &VarMap,
) -> Result<GradStore, TrainError> {
    Ok(match acc {
        None => g,
        Some(mut acc) => {
            for (_, var) in named_vars(varmap)? {
                if let Some(new) = g.get(var.as_tensor()) {
                    let sum = match acc.get(var.as_tensor()) {
                        Some(old) => (old + new)?,
                        None => new.clone(),
                    };
                    acc.insert(var.as_tensor(), sum);
                }
            }
            acc
        }
    })
}
