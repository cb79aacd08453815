//! SSMODE's learned logit prior ([`SsmodeConfig::logit_prior`], a departure from the paper):
//! a bias per hypothesis and latitude added to every stage's matching cost before the softmax,
//! so that where the views give no evidence the network can answer what the scenes make likely
//! there (the sky above, the ground below) instead of the middle of its range.
//!
//! A 3-D convolution is the same at every sphere and latitude, so without it a flat cost curve
//! (the zenith of a vertical camera pair, on the pair's baseline, where no depth moves a point
//! in either view; a textureless floor) gives the mean hypothesis: about 30 m. The sweep breaks
//! such ties with a fixed far prior; this one is learned, and only shifts a curve that the
//! evidence leaves flat: a peaked cost outweighs it. It is the same for every scene, so it
//! carries nothing of what a panorama looks like.
//!
//! For aggregated sphere `d` of `D'` and cost row `v` of `h'` (the regression head's grid):
//!
//! ```text
//! cost'(d, v, u) = cost(d, v, u) + LOGIT_PRIOR_SCALE * theta(d, k(v))
//! ```
//!
//! with `theta` the `(D', LATITUDE_BINS)` variable `logit_prior` (zeros at the start, so a
//! network that gains it computes what it computed before) resampled linearly along latitude
//! to the `h'` rows (`align_corners = false`: bins span equal latitude bands), so the prior
//! does not depend on the width the network runs at. Under Adam a variable moves about the
//! learning rate per step whatever its gradient, so the scale sets how fast the prior can
//! grow: a few logit units within a thousand steps.
//!
//! [`SsmodeConfig::logit_prior`]: super::config::SsmodeConfig::logit_prior

use candle_core::{Result, Tensor};
use candle_nn::{Init, VarBuilder};

use crate::model::ops::{resample_linear_axis, OpsError};

/// Latitude bands of the prior, pole to pole (about 11° each).
pub const LATITUDE_BINS: usize = 16;
/// Factor between the variable and the bias it adds (the prior's learning-rate multiplier).
pub const LOGIT_PRIOR_SCALE: f64 = 25.0;
/// Hypothesis axis of the cost `(B, D', h', w')`.
const SPHERE_AXIS: usize = 1;
/// Latitude (row) axis of the prior `(D', bins)` once broadcast as `(1, D', bins, 1)`.
const ROW_AXIS: usize = 2;

/// The learned prior `logit_prior (D', LATITUDE_BINS)`.
#[derive(Clone, Debug)]
pub struct LogitPrior {
    logit_prior: Tensor,
}

impl LogitPrior {
    /// The prior over `spheres` aggregated spheres (zeros when new).
    pub fn new(spheres: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            logit_prior: vb.get_with_hints(
                (spheres, LATITUDE_BINS),
                "logit_prior",
                Init::Const(0.0),
            )?,
        })
    }

    /// `cost (B, D', h', w')` plus the prior, resampled to its `h'` rows.
    pub fn forward(&self, cost: &Tensor) -> Result<Tensor> {
        let (_, spheres, rows, _) = cost.dims4()?;
        let (prior_spheres, _) = self.logit_prior.dims2()?;
        if spheres != prior_spheres {
            return Err(OpsError::Shape {
                op: "LogitPrior::forward",
                what: format!("cost over {spheres} spheres, prior over {prior_spheres}"),
            }
            .into());
        }
        // (D', bins) -> (1, D', bins, 1) -> (1, D', h', 1)
        let prior = self
            .logit_prior
            .unsqueeze(0)?
            .unsqueeze(3)?
            .affine(LOGIT_PRIOR_SCALE, 0.0)?;
        let prior = resample_linear_axis(&prior, ROW_AXIS, rows)?;
        debug_assert_eq!(prior.dim(SPHERE_AXIS)?, spheres);
        cost.broadcast_add(&prior)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn a_new_prior_changes_nothing_and_a_set_one_adds_by_latitude() -> Result<()> {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let prior = LogitPrior::new(3, vb)?;
        let cost = Tensor::arange(0f32, 3.0 * 4.0 * 2.0, &Device::Cpu)?.reshape((1, 3, 4, 2))?;
        let same = prior.forward(&cost)?;
        assert_eq!(
            same.flatten_all()?.to_vec1::<f32>()?,
            cost.flatten_all()?.to_vec1::<f32>()?
        );
        // theta = 1 on the top half of the bins of sphere 1: rows 0 and 1 of 4 gain the scale.
        let mut theta = vec![0f32; 3 * LATITUDE_BINS];
        for k in 0..LATITUDE_BINS / 2 {
            theta[LATITUDE_BINS + k] = 1.0;
        }
        let data = varmap
            .data()
            .lock()
            .map_err(|_| candle_core::Error::Msg("lock".into()))?;
        let var = data
            .get("logit_prior")
            .ok_or(candle_core::Error::Msg("no var".into()))?;
        var.set(&Tensor::from_vec(theta, (3, LATITUDE_BINS), &Device::Cpu)?)?;
        drop(data);
        let out = prior.forward(&cost)?.sub(&cost)?;
        let out: Vec<Vec<Vec<f32>>> = out.squeeze(0)?.to_vec3()?;
        let scale = LOGIT_PRIOR_SCALE as f32;
        for (d, rows) in out.iter().enumerate() {
            for (v, row) in rows.iter().enumerate() {
                let expected = if d == 1 && v < 2 { scale } else { 0.0 };
                for &x in row {
                    assert!((x - expected).abs() < 1e-4, "sphere {d} row {v}: {x}");
                }
            }
        }
        Ok(())
    }
}
