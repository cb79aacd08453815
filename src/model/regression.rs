//! Regression heads: cost `(B, D, H/4, W/4)` -> trilinear upsampling to `(B, N, H, W)` ->
//! softmax over the `N` hypotheses -> soft-argmin in inverse depth:
//!
//! ```text
//! p_i = softmax_i(cost_i),   k = sum_i p_i i / (N - 1),   range = 1 / (inv_far + k (inv_near - inv_far))
//! ```
//!
//! with hypotheses uniform in inverse depth (index 0 the farthest). The paper's eq. 7 takes the
//! expected depth `sum_i p_i rho_i` instead; over 0.5 m to 1000 m that is dominated by the far
//! spheres, so the expectation is taken where the hypotheses are uniform. The confidence is the
//! probability mass within `CONFIDENCE_RADIUS` hypotheses of the argmax (PSMODE).

use candle_core::{DType, Result, Tensor};
use candle_nn::VarBuilder;

use super::hourglass::Conv3d;
use crate::geometry::InverseDepthHypotheses;
use crate::model::ops::upsample_trilinear;

/// Hypotheses either side of the argmax counted in the confidence.
pub const CONFIDENCE_RADIUS: f64 = 2.0;
/// Hypothesis axis of `(B, N, H, W)`.
const HYPOTHESIS_AXIS: usize = 1;

/// `classif`: conv `Ch -> Ch`, ReLU, conv `Ch -> 1` (no bias: the softmax ignores a constant).
#[derive(Clone, Debug)]
pub struct RegressionHead {
    conv0: Conv3d,
    conv1: Conv3d,
}

impl RegressionHead {
    pub fn new(c: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            conv0: Conv3d::new(c, c, vb.pp("conv0"))?,
            conv1: Conv3d::new_no_bias(c, 1, vb.pp("conv1"))?,
        })
    }

    /// `(B, D, H, W, Ch)` -> cost `(B, D, H, W)`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        const UNIT: [usize; 3] = [1, 1, 1];
        let y = self.conv0.forward(x, UNIT)?.relu()?;
        self.conv1.forward(&y, UNIT)?.squeeze(4)
    }
}

/// One stage's regression result.
#[derive(Clone, Debug)]
pub struct Regression {
    /// `(B, H, W)` range in metres.
    pub range_m: Tensor,
    /// `(B, H, W)` expected normalized hypothesis index in [0, 1].
    pub inverse_depth_index: Tensor,
    /// `(B, N, H, W)` softmax over hypotheses.
    pub probabilities: Tensor,
}

/// Upsamples `cost (B, D, h, w)` to `(B, N, height, width)` and regresses range and index.
pub fn regress(
    cost: &Tensor,
    hypotheses: &InverseDepthHypotheses,
    height: usize,
    width: usize,
) -> Result<Regression> {
    let n = hypotheses.count();
    let device = cost.device();
    // (B, N, H, W)
    let up = upsample_trilinear(cost, n, height, width)?;
    let probabilities = candle_nn::ops::softmax(&up, HYPOTHESIS_AXIS)?;
    let index: Vec<f32> = (0..n).map(|i| i as f32 / (n - 1) as f32).collect();
    // (1, N, 1, 1)
    let index = Tensor::from_vec(index, (1, n, 1, 1), device)?;
    // (B, H, W)
    let inverse_depth_index = probabilities.broadcast_mul(&index)?.sum(HYPOTHESIS_AXIS)?;
    // Range from the expected inverse depth, `1 / (inv_far + k (inv_near - inv_far))`, not the
    // expected depth of eq. 7: with hypotheses from 0.5 m to 1000 m uniform in inverse depth,
    // 1 % of probability on the farthest sphere alone would add 10 m to every pixel's range.
    let inv_far = hypotheses.inverse_depth(0.0);
    let inv_near = hypotheses.inverse_depth((n - 1) as f64);
    let range_m = inverse_depth_index
        .affine(inv_near - inv_far, inv_far)?
        .recip()?;
    Ok(Regression {
        range_m,
        inverse_depth_index,
        probabilities,
    })
}

/// `(B, N, H, W)` probabilities -> `(B, H, W)` mass within [`CONFIDENCE_RADIUS`] hypotheses of
/// the argmax (no gradient).
pub fn confidence(probabilities: &Tensor) -> Result<Tensor> {
    let p = probabilities.detach();
    let n = p.dim(HYPOTHESIS_AXIS)?;
    // (B, 1, H, W)
    let argmax = p.argmax_keepdim(HYPOTHESIS_AXIS)?.to_dtype(DType::F32)?;
    // (1, N, 1, 1)
    let index = Tensor::arange(0f32, n as f32, p.device())?.reshape((1, n, 1, 1))?;
    let near = index
        .broadcast_sub(&argmax)?
        .abs()?
        .le(CONFIDENCE_RADIUS)?
        .to_dtype(DType::F32)?;
    (p * near)?.sum(HYPOTHESIS_AXIS)
}
