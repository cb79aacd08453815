//! Regression heads: cost `(B, D, H/4, W/4)` -> trilinear upsampling to `(B, N, H, W)` ->
//! softmax over the `N` hypotheses -> soft-argmin in inverse depth:
//!
//! ```text
//! p_i = softmax_i(cost_i),   k = sum_i p_i i / (N - 1),   range = 1 / (inv_far + k (inv_near - inv_far))
//! (hypotheses uniform in log depth: range = exp(ln far + k (ln near - ln far)))
//! ```
//!
//! with hypotheses uniform in inverse depth (index 0 the farthest). The paper's eq. 7 takes the
//! expected depth `sum_i p_i rho_i` instead; over 0.5 m to 1000 m that is dominated by the far
//! spheres, so the expectation is taken where the hypotheses are uniform. The confidence is the
//! probability mass within `CONFIDENCE_RADIUS` hypotheses of the argmax (PSMODE).
//!
//! Far-plane readout: the mean of a distribution piled against the end of the hypothesis
//! range is biased inwards, and at the far end a bias of a hundredth of a hypothesis step is
//! hundreds of metres (with 64 hypotheses over 0.5 to 1000 m, index 1 is already 31 m). So a
//! pixel with `p_0 >= far_plane_probability` (the far plane holds most of the mass, as for
//! the sky) is read out as the far plane itself, `max_depth_m`, like the ground truth encodes
//! the sky. Only the range is affected; the index the loss trains is the plain expectation.
//!
//! The far field ([`RangeReadout::far_counts`], from [`mode360_core::geometry::FarField`]): where
//! the rig cannot tell the farthest `K(p)` hypotheses from the far plane (a short baseline, a
//! ray along the baseline), the matching cost is flat over them and the probability spreads
//! across them; its mean lands tens of metres in front of the sky. So the test sums them:
//! `sum_{i < K(p)} p_i >= far_plane_probability`.
//!
//! Near mode: the expectation of a distribution with two modes, a near obstacle's and the
//! background's, lands between them or on the background (a pole narrower than a cost cell, a
//! near object the aggregation smeared into what stands behind it). So a pixel reads its
//! nearest mode instead where that mode holds enough probability and is markedly nearer:
//!
//! ```text
//! m = the largest i (the nearest) with p_i >= p_{i-1}, p_i >= p_{i+1} and sum_{|j - i| <= r} p_j >= near_mode_probability
//! k_near = sum_{|j - m| <= r} p_j j / sum_{|j - m| <= r} p_j,   range_near = range(k_near)
//! range = range_near   where range_near <= NEAR_MODE_MAX_RANGE_M and NEAR_MODE_RATIO range_near < range
//! ```
//!
//! with `r` = [`CONFIDENCE_RADIUS`]; `range` is the expectation's or the far plane's. Like the
//! far-plane test it moves the range only, never the index the loss trains.

use candle_core::{DType, Result, Tensor};
use candle_nn::VarBuilder;
use rayon::prelude::*;

use super::hourglass::Conv3d;
use super::readout::NEAR_MODE_OFF;
use super::softmax_stats::{softmax_in_place, SoftmaxSums};
use crate::model::ops::{
    resample_linear_axis, soft_argmin_index, upsample_trilinear, LinearAxisMap,
};
use mode360_core::geometry::{DepthHypotheses, HypothesisSpacing};

/// Hypotheses either side of the argmax counted in the confidence.
pub const CONFIDENCE_RADIUS: f64 = 2.0;
/// Hypothesis axis of `(B, N, H, W)`.
const HYPOTHESIS_AXIS: usize = 1;

/// The hypotheses within [`CONFIDENCE_RADIUS`] of hypothesis `i` of `n`.
fn window(i: usize, n: usize) -> std::ops::Range<usize> {
    let radius = CONFIDENCE_RADIUS as usize;
    i.saturating_sub(radius)..(i + radius + 1).min(n)
}
/// The near mode replaces the range only where it is more than this many times nearer (the
/// near pass's ratio, `estimator::near_pass`).
pub const NEAR_MODE_RATIO: f32 = 1.25;
/// The near mode is read only within this range, metres: the best of 1.5, 3, 10 and 30 m on
/// the validation seed (at 30 m the 0.3 m vertical pair lost 3.6 points of δ1, its
/// structures at 10 to 30 m read too near; models/README.md, "The near mode").
pub const NEAR_MODE_MAX_RANGE_M: f32 = 10.0;

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
        let y = self.conv0.forward_then(x, UNIT, None, true)?;
        self.conv1.forward_then(&y, UNIT, None, false)?.squeeze(4)
    }
}

/// How a pixel's range is read from its distribution besides the expectation: the far-plane
/// test and the near mode (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct RangeReadout<'a> {
    /// Probability on the far field at which a pixel reads the far plane (above 1: never).
    pub probability: f64,
    /// Per output pixel (row-major, `H W`, shared by the batch), the hypotheses counted from
    /// the far plane that the rig cannot tell from it; `None`: the far plane alone.
    pub far_counts: Option<&'a [u16]>,
    /// Probability a mode's window must hold for the near mode (above 1: off).
    pub near_mode_probability: f64,
}

impl<'a> RangeReadout<'a> {
    /// The test on the far plane alone, without the near mode.
    pub fn far_plane_only(probability: f64) -> Self {
        Self {
            probability,
            far_counts: None,
            near_mode_probability: NEAR_MODE_OFF,
        }
    }

    /// Whether the near mode is on.
    fn near_mode_on(&self) -> bool {
        self.near_mode_probability <= 1.0
    }

    /// `range_m` with the near mode of the pixel's probabilities `p` (unnormalized: each
    /// divided by `sum`) applied (see the module docs); `range_m` itself when it is off.
    fn with_near_mode(
        &self,
        p: &[f32],
        sum: f32,
        range_m: f32,
        hypotheses: &DepthHypotheses,
    ) -> f32 {
        if !self.near_mode_on() {
            return range_m;
        }
        let n = p.len();
        let threshold = self.near_mode_probability as f32 * sum;
        // the nearest local maximum (index 0 is the farthest) whose window holds enough
        let mode = (0..n).rev().find(|&i| {
            let peak = (i + 1 >= n || p[i] >= p[i + 1]) && (i == 0 || p[i] >= p[i - 1]);
            peak && p[window(i, n)].iter().sum::<f32>() >= threshold
        });
        let Some(m) = mode else {
            return range_m;
        };
        let (mut mass, mut moment) = (0f32, 0f32);
        for j in window(m, n) {
            mass += p[j];
            moment += p[j] * j as f32;
        }
        let k = moment / mass / (n - 1) as f32;
        let near_m = hypotheses.depth_at_normalized(f64::from(k)) as f32;
        if near_m <= NEAR_MODE_MAX_RANGE_M && NEAR_MODE_RATIO * near_m < range_m {
            near_m
        } else {
            range_m
        }
    }

    /// Hypotheses in pixel `k`'s far field (at least 1, at most `n`).
    fn count(&self, k: usize, n: usize) -> usize {
        self.far_counts
            .and_then(|c| c.get(k))
            .map_or(1, |&c| usize::from(c).clamp(1, n))
    }

    fn check(&self, height: usize, width: usize) -> Result<()> {
        match self.far_counts {
            Some(c) if c.len() != height * width => Err(candle_core::Error::Msg(format!(
                "far-field counts cover {} pixels, the output has {height}x{width}",
                c.len()
            ))),
            _ => Ok(()),
        }
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

/// Upsamples `cost (B, D, h, w)` to `(B, N, height, width)` and regresses range and index,
/// with the far-plane readout `far` (see the module docs).
pub fn regress(
    cost: &Tensor,
    hypotheses: &DepthHypotheses,
    height: usize,
    width: usize,
    far: RangeReadout,
) -> Result<Regression> {
    far.check(height, width)?;
    let n = hypotheses.count();
    let device = cost.device();
    // (B, N, H, W)
    let up = upsample_trilinear(cost, n, height, width)?;
    // (B, H, W): the expected index, the only output a loss reads (one op each way)
    let inverse_depth_index = soft_argmin_index(&up)?;
    // (B, N, H, W), without a gradient: the far-plane test and the confidence read it
    let probabilities = candle_nn::ops::softmax(&up.detach(), HYPOTHESIS_AXIS)?;
    // Range from the expected inverse depth, `1 / (inv_far + k (inv_near - inv_far))`, not the
    // expected depth of eq. 7: with hypotheses from 0.5 m to 1000 m uniform in inverse depth,
    // 1 % of probability on the farthest sphere alone would add 10 m to every pixel's range.
    let soft_range_m = range_of_index(&inverse_depth_index, hypotheses)?;
    // (B, H, W): probability of the far field
    let far_mass = match far.far_counts {
        None => probabilities
            .narrow(HYPOTHESIS_AXIS, 0, 1)?
            .squeeze(HYPOTHESIS_AXIS)?,
        Some(_) => {
            let pixels = height * width;
            let mut mask = vec![0f32; n * pixels];
            for k in 0..pixels {
                for i in 0..far.count(k, n) {
                    mask[i * pixels + k] = 1.0;
                }
            }
            // (1, N, H, W)
            let mask = Tensor::from_vec(mask, (1, n, height, width), device)?;
            probabilities
                .detach()
                .broadcast_mul(&mask)?
                .sum(HYPOTHESIS_AXIS)?
        }
    };
    let max_depth = Tensor::full(hypotheses.depth_m(0.0) as f32, far_mass.shape(), device)?;
    let mut range_m = far_mass
        .ge(far.probability)?
        .where_cond(&max_depth, &soft_range_m)?;
    if far.near_mode_on() {
        // (B, H, W), pixel by pixel on the host as in `regress_inference`
        let dims = range_m.dims().to_vec();
        let pixels = height * width;
        let p = probabilities.flatten_all()?.to_vec1::<f32>()?;
        let mut ranges = range_m.flatten_all()?.to_vec1::<f32>()?;
        let mut column = vec![0f32; n];
        for (q, range) in ranges.iter_mut().enumerate() {
            let (bi, k) = (q / pixels, q % pixels);
            for (i, c) in column.iter_mut().enumerate() {
                *c = p[(bi * n + i) * pixels + k];
            }
            *range = far.with_near_mode(&column, 1.0, *range, hypotheses);
        }
        range_m = Tensor::from_vec(ranges, dims, device)?;
    }
    Ok(Regression {
        range_m,
        inverse_depth_index,
        probabilities,
    })
}

/// Range (m) of the expected normalized index `k` (`(B, H, W)`), differentiable: uniform in
/// inverse depth `1 / (inv_far + k (inv_near - inv_far))`, uniform in log depth
/// `exp(ln far + k (ln near - ln far))`.
fn range_of_index(k: &Tensor, hypotheses: &DepthHypotheses) -> Result<Tensor> {
    let n = hypotheses.count();
    let (far, near) = (hypotheses.depth_m(0.0), hypotheses.depth_m((n - 1) as f64));
    match hypotheses.spacing() {
        HypothesisSpacing::InverseDepth => k.affine(1.0 / near - 1.0 / far, 1.0 / far)?.recip(),
        HypothesisSpacing::LogDepth => k.affine(near.ln() - far.ln(), far.ln())?.exp(),
    }
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

/// What [`regress_inference`] returns, each `(B, H, W)`.
#[derive(Clone, Debug)]
pub struct InferenceRegression {
    pub range_m: Tensor,
    pub inverse_depth_index: Tensor,
    pub confidence: Tensor,
}

/// [`regress`] and [`confidence`] fused for inference (no gradient): the cost is upsampled in
/// `H` and `W` as a tensor, then one pass per pixel interpolates its `N` hypotheses from the `D`
/// spheres, takes the softmax, the expected index, the argmax and the mass near it, without
/// materialising the `(B, N, H, W)` volume. Same values as the unfused path (to rounding).
pub fn regress_inference(
    cost: &Tensor,
    hypotheses: &DepthHypotheses,
    height: usize,
    width: usize,
    far: RangeReadout,
) -> Result<InferenceRegression> {
    far.check(height, width)?;
    let n = hypotheses.count();
    let (b, d, _, _) = cost.dims4()?;
    // (B, D, h, w) -> (B, D, h, W) -> (B, D, H, W)
    let spatial = resample_linear_axis(&resample_linear_axis(cost, 3, width)?, 2, height)?;
    let data = spatial.flatten_all()?.to_vec1::<f32>()?;
    let axis = LinearAxisMap::new(d, n)?;
    let pixels = height * width;
    let mut index = vec![0f32; b * pixels];
    let mut conf = vec![0f32; b * pixels];
    let mut range = vec![0f32; b * pixels];
    let far_m = hypotheses.depth_m(0.0) as f32;
    index
        .par_chunks_mut(width)
        .zip(conf.par_chunks_mut(width))
        .zip(range.par_chunks_mut(width))
        .enumerate()
        .for_each(|(row, ((index_row, conf_row), range_row))| {
            let (bi, v) = (row / height, row % height);
            // (W, D): this row's sphere costs, pixel-major
            let mut spheres = vec![0f32; width * d];
            for k in 0..d {
                let src = &data[(bi * d + k) * pixels + v * width..][..width];
                for (u, &c) in src.iter().enumerate() {
                    spheres[u * d + k] = c;
                }
            }
            let mut p = vec![0f32; n];
            let (lo, hi, lam) = (
                axis.lower_indices(),
                axis.upper_indices(),
                axis.upper_weights(),
            );
            for u in 0..width {
                let s = &spheres[u * d..(u + 1) * d];
                for (i, c) in p.iter_mut().enumerate() {
                    *c = (1.0 - lam[i]) * s[lo[i] as usize] + lam[i] * s[hi[i] as usize];
                }
                // p_i = e_i / sum; the argmax of the probabilities, first of equals (as the
                // unfused path): costs a rounding error apart can have equal probabilities
                let SoftmaxSums {
                    sum,
                    moment: expected,
                    argmax: arg,
                } = softmax_in_place(&mut p);
                let inv_sum = 1.0 / sum;
                let near: f32 = p[window(arg, n)].iter().sum();
                let k = expected * inv_sum / (n - 1) as f32;
                index_row[u] = k;
                conf_row[u] = near * inv_sum;
                let far_mass: f32 = p[..far.count(v * width + u, n)].iter().sum();
                let range = if f64::from(far_mass * inv_sum) >= far.probability {
                    far_m
                } else {
                    hypotheses.depth_at_normalized(f64::from(k)) as f32
                };
                range_row[u] = far.with_near_mode(&p, sum, range, hypotheses);
            }
        });
    let device = cost.device();
    let range_m = Tensor::from_vec(range, (b, height, width), device)?;
    let inverse_depth_index = Tensor::from_vec(index, (b, height, width), device)?;
    let confidence = Tensor::from_vec(conf, (b, height, width), device)?;
    Ok(InferenceRegression {
        range_m,
        inverse_depth_index,
        confidence,
    })
}
