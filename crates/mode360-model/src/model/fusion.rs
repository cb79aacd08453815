//! PSMODE's second stage (paper section 4.2.2): a 2-D network that fuses the pairs' aligned
//! ranges and confidences with the reference panorama into one range and confidence.
//!
//! The paper's U-Net has two encoders (the pairs' depths and confidences; the RGB panorama),
//! a multi-scale fusion of their features and one decoder. Here the pair encoder is shared by
//! the pairs and pooled over them (confidence-weighted mean and maximum), so one set of weights
//! serves rigs of any number of pairs, and the decoder regresses a correction of the most
//! confident pair's estimate (zero at initialization: an untrained network is the
//! most-confident-pair baseline).
//!
//! ```text
//! pairs (B, P, H, W, 3) [index, confidence, parallax] -> pair0, pair1 (shared) (B, P, H, W, Cp)
//!   pooled: conf-weighted mean, max over P; with base (B, H, W, 2)    (B, H, W, 2 Cp + 2)
//! depth encoder: depth0 (s1), depth1 (s2), depth2 (s2)    (B, H/2^k, W/2^k, C_k)
//! rgb (B, H, W, 3) -> rgb0 (s1), rgb1 (s2), rgb2 (s2)     (B, H/2^k, W/2^k, C_k)
//! fuse_k: 1x1 on concat(depth_k, rgb_k)                    (B, H/2^k, W/2^k, C_k)
//! decoder: up2 = fuse2; dec1(concat(up(up2), fuse1)); dec0(concat(up(dec1), fuse0))
//! head: 3x3 -> (delta index, confidence logit)             (B, H, W, 2)
//! index = base index + delta;  range = max_depth exp(-index ln(max_depth / min_depth))
//! ```
//!
//! Index `t = ln(max_depth / r) / ln(max_depth / min_depth)`: 0 at the far plane, 1 at the
//! nearest range (log-depth, as the shipped SSMODE hypotheses). Channels-last throughout.
//!
//! With [`FusionHead::Select`] the decoder does not correct a base estimate: it scores each
//! pair per pixel and the output is the score-weighted mean of the pairs' indices, so it can
//! only choose among (and blend) what the pairs measured, never invent a range:
//!
//! ```text
//! pairs (B, P, H, W, 4): index, confidence, parallax, dev_p = (index_p - base) / δ1 index
//!   (and with `support_input` a fifth channel: support_p = sum_q c_q [|index_p - index_q|
//!   < δ1 index] / sum_q c_q, the confidence-weighted share of the pairs that agree with p)
//! select: 1x1 on concat(pair feature_p, decoder)            (B, P, H, W, 1)
//! score_p = select_p - PRIOR_SHARPNESS |dev_p|
//! w_p = softmax over the pairs with a range (score_p)       (B, P, H, W)
//! index = sum_p w_p index_p;  head: 3x3 -> confidence logit (B, H, W, 1)
//! base = the pairs' consensus (index, confidence)
//! ```

use candle_core::{Result, Tensor};
use candle_nn::VarBuilder;

use super::feature::{upsample_nearest, ErpConv, ResidualBlock};

/// Channels per pair of the fusion input: index, confidence and the pair's parallax there.
pub const PAIR_INPUT_CHANNELS: usize = 3;
/// Channels of the base estimate (the most confident pair): index and confidence.
pub const BASE_CHANNELS: usize = 2;
/// Channels of the RGB panorama.
const RGB_CHANNELS: usize = 3;
/// Head outputs: index correction and confidence logit.
const HEAD_CHANNELS: usize = 2;
/// Encoder levels (full, half, quarter resolution).
pub const LEVELS: usize = 3;
/// The network's grid must divide by this (two stride-2 levels).
pub const SIZE_MULTIPLE: usize = 1 << (LEVELS - 1);
/// Guards the confidence-weighted mean where no pair says anything.
const WEIGHT_EPS: f64 = 1e-6;
/// Planar kernel side.
const KERNEL: usize = 3;
/// A pair without a range at a pixel gets this score (its softmax weight underflows to 0).
const NO_RANGE_SCORE: f64 = -1e4;
/// The select head's prior: a pair's score falls by this much per δ1 interval (a factor 1.25)
/// between its range and the consensus's, so that the untrained head is a soft consensus.
pub const PRIOR_SHARPNESS: f64 = 2.0;
/// `ln 1.25`: one δ1 interval in log range.
const DELTA1_LOG: f64 = 0.223_143_551_314_209_7;
/// The select head's deviation channel is clamped to this many δ1 intervals.
const MAX_DEVIATION: f64 = 8.0;

/// What the decoder's head returns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum FusionHead {
    /// A correction of the base estimate's index (the most confident pair), and a confidence.
    #[default]
    Correction,
    /// A score per pair (softmax over the pairs: the output blends the pairs' indices) and a
    /// confidence; the base input is the pairs' consensus.
    Select,
}

/// The fusion network's configuration, stored in its weights file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FusionConfig {
    /// Preset name.
    pub name: String,
    /// Width of the ERP grid the network runs on (height = width / 2).
    pub width: usize,
    /// Range of the index, metres.
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    /// Channels of the shared pair encoder.
    pub pair_channels: usize,
    /// Channels of the encoder and decoder levels, full to quarter resolution.
    pub channels: [usize; LEVELS],
    /// What the head returns (files written before the choice: a correction).
    #[serde(default)]
    pub head: FusionHead,
    /// [`FusionHead::Select`]: the pair encoder also sees each pair's support, the
    /// confidence-weighted share of the pairs whose range is within one δ1 interval of its
    /// own ([`pair_support`]) (files written before the choice: without).
    #[serde(default)]
    pub support_input: bool,
}

/// Why a fusion configuration cannot run.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("fusion config field '{field}': {problem}")]
pub struct FusionConfigError {
    pub field: &'static str,
    pub problem: String,
}

/// The largest accepted width and channel count (a bound on what a weights file may ask).
const MAX_WIDTH: usize = 4096;
const MAX_CHANNELS: usize = 1024;

impl FusionConfig {
    /// The shipped fusion network: 256 wide, 0.5 m to 1000 m like SSMODE's presets.
    pub fn small() -> Self {
        Self {
            name: "small".to_string(),
            width: 256,
            min_depth_m: 0.5,
            max_depth_m: 1000.0,
            pair_channels: 8,
            channels: [16, 24, 32],
            head: FusionHead::Correction,
            support_input: false,
        }
    }

    /// `small` with the [`FusionHead::Select`] head: it weighs the pairs instead of correcting
    /// one.
    pub fn select() -> Self {
        Self {
            name: "select".to_string(),
            head: FusionHead::Select,
            ..Self::small()
        }
    }

    /// For tests: 32 wide, few channels.
    pub fn tiny() -> Self {
        Self {
            name: "tiny".to_string(),
            width: 32,
            pair_channels: 4,
            channels: [4, 6, 8],
            ..Self::small()
        }
    }

    pub fn height(&self) -> usize {
        self.width / 2
    }

    /// Whether the network runs on an ERP grid `width` wide: a correction head only on its
    /// own width; a select head (whose output is a blend of the pairs, scale-free but for its
    /// receptive field) on any width whose height divides by [`SIZE_MULTIPLE`].
    pub fn runs_on(&self, width: usize) -> bool {
        match self.head {
            FusionHead::Correction => width == self.width,
            FusionHead::Select => {
                width.is_multiple_of(2) && (width / 2).is_multiple_of(SIZE_MULTIPLE) && width > 0
            }
        }
    }

    /// `ln(max_depth / min_depth)`: the index's span in log range.
    pub fn log_span(&self) -> f64 {
        (self.max_depth_m / self.min_depth_m).ln()
    }

    /// The index of a range: `ln(max / r) / ln(max / min)` (not clamped).
    pub fn index_of_range(&self, range_m: f64) -> f64 {
        (self.max_depth_m / range_m).ln() / self.log_span()
    }

    /// The range of an index: `max exp(-t ln(max / min))`.
    pub fn range_of_index(&self, index: f64) -> f64 {
        self.max_depth_m * (-index * self.log_span()).exp()
    }

    pub fn validate(&self) -> std::result::Result<(), FusionConfigError> {
        let err = |field, problem: String| Err(FusionConfigError { field, problem });
        let rows = self.width / 2;
        if self.width == 0
            || self.width > MAX_WIDTH
            || !self.width.is_multiple_of(2)
            || !rows.is_multiple_of(SIZE_MULTIPLE)
        {
            return err(
                "width",
                format!(
                    "{} must be even, at most {MAX_WIDTH}, with a height divisible by {SIZE_MULTIPLE}",
                    self.width
                ),
            );
        }
        if !(self.min_depth_m > 0.0
            && self.max_depth_m > self.min_depth_m
            && self.max_depth_m.is_finite())
        {
            return err(
                "min_depth_m",
                format!(
                    "need 0 < min_depth_m < max_depth_m, got {} and {}",
                    self.min_depth_m, self.max_depth_m
                ),
            );
        }
        for (field, c) in [
            ("pair_channels", self.pair_channels),
            ("channels", self.channels[0]),
            ("channels", self.channels[1]),
            ("channels", self.channels[2]),
        ] {
            if c == 0 || c > MAX_CHANNELS {
                return err(field, format!("{c} must be in 1..={MAX_CHANNELS}"));
            }
        }
        Ok(())
    }
}

/// What [`Fusion::forward`] returns, each `(B, H, W)`.
#[derive(Clone, Debug)]
pub struct FusionOutput {
    /// Index (unclamped in training; clamped to [0, 1] by [`Fusion::range_m`]).
    pub index: Tensor,
    /// Confidence logit.
    pub confidence_logit: Tensor,
    /// [`FusionHead::Select`]: each pair's weight `(B, P, H, W)` (summing to 1 over the pairs
    /// with a range); `None` for a correction head.
    pub pair_weights: Option<Tensor>,
}

/// The network. Variable names: `pair{0,1}`, `depth{k}`, `rgb{k}`, `fuse{k}`, `dec{0,1}`,
/// `head`, and `select` with [`FusionHead::Select`].
#[derive(Clone, Debug)]
pub struct Fusion {
    cfg: FusionConfig,
    pair: [ErpConv; 2],
    depth: Vec<ResidualBlock>,
    rgb: Vec<ResidualBlock>,
    fuse: Vec<ErpConv>,
    dec: Vec<ResidualBlock>,
    head: ErpConv,
    select: Option<ErpConv>,
}

impl Fusion {
    pub fn new(cfg: &FusionConfig, vb: VarBuilder) -> Result<Self> {
        cfg.validate().map_err(candle_core::Error::wrap)?;
        let (cp, c) = (cfg.pair_channels, cfg.channels);
        // the select head also sees each pair's deviation from the consensus (and its support)
        let pair_in = match cfg.head {
            FusionHead::Correction => PAIR_INPUT_CHANNELS,
            FusionHead::Select => PAIR_INPUT_CHANNELS + 1 + usize::from(cfg.support_input),
        };
        let pair = [
            ErpConv::new(pair_in, cp, KERNEL, 1, 1, vb.pp("pair0"))?,
            ErpConv::new(cp, cp, KERNEL, 1, 1, vb.pp("pair1"))?,
        ];
        let mut depth = Vec::with_capacity(LEVELS);
        let mut rgb = Vec::with_capacity(LEVELS);
        let mut fuse = Vec::with_capacity(LEVELS);
        for k in 0..LEVELS {
            let stride = if k == 0 { 1 } else { 2 };
            let (d_in, r_in) = if k == 0 {
                (2 * cp + BASE_CHANNELS, RGB_CHANNELS)
            } else {
                (c[k - 1], c[k - 1])
            };
            depth.push(ResidualBlock::new(
                d_in,
                c[k],
                stride,
                1,
                vb.pp(format!("depth{k}")),
            )?);
            rgb.push(ResidualBlock::new(
                r_in,
                c[k],
                stride,
                1,
                vb.pp(format!("rgb{k}")),
            )?);
            fuse.push(ErpConv::new(
                2 * c[k],
                c[k],
                1,
                1,
                1,
                vb.pp(format!("fuse{k}")),
            )?);
        }
        let dec = vec![
            ResidualBlock::new(c[1] + c[0], c[0], 1, 1, vb.pp("dec0"))?,
            ResidualBlock::new(c[2] + c[1], c[1], 1, 1, vb.pp("dec1"))?,
        ];
        let (head, select) = match cfg.head {
            FusionHead::Correction => (
                ErpConv::zeros(c[0], HEAD_CHANNELS, KERNEL, vb.pp("head"))?,
                None,
            ),
            // zero scores at initialization: the plain mean of the pairs' indices
            FusionHead::Select => (
                ErpConv::zeros(c[0], 1, KERNEL, vb.pp("head"))?,
                Some(ErpConv::zeros(cp + c[0], 1, 1, vb.pp("select"))?),
            ),
        };
        Ok(Self {
            cfg: cfg.clone(),
            pair,
            depth,
            rgb,
            fuse,
            dec,
            head,
            select,
        })
    }

    pub fn config(&self) -> &FusionConfig {
        &self.cfg
    }

    /// `pairs (B, P, H, W, 3)` (index, confidence, both 0 where a pair says nothing, and the
    /// pair's parallax in metres, [`PairView::parallax_on`]),
    /// `base (B, H, W, 2)` (index and confidence: the most confident pair's, or the pairs'
    /// consensus with [`FusionHead::Select`]), `rgb (B, H, W, 3)` in [0, 1], all on the
    /// network's grid.
    pub fn forward(&self, pairs: &Tensor, base: &Tensor, rgb: &Tensor) -> Result<FusionOutput> {
        let (b, p, h, w, c) = pairs.dims5()?;
        if c != PAIR_INPUT_CHANNELS || h * 2 != w || !self.cfg.runs_on(w) || p == 0 {
            candle_core::bail!(
                "Fusion::forward: pairs {:?}, expected (B, P >= 1, {}, {}, {PAIR_INPUT_CHANNELS})",
                pairs.dims(),
                self.cfg.height(),
                self.cfg.width
            );
        }
        // (B, P, H, W, 1): each pair's deviation from the base in δ1 intervals (select head)
        let deviation = match self.cfg.head {
            FusionHead::Correction => None,
            FusionHead::Select => {
                let base_index = base.narrow(3, 0, 1)?.unsqueeze(1)?;
                let d = pairs.narrow(4, 0, 1)?.broadcast_sub(&base_index)?;
                let d = (d * (self.cfg.log_span() / DELTA1_LOG))?;
                Some(d.clamp(-MAX_DEVIATION, MAX_DEVIATION)?)
            }
        };
        // (B P, H, W, C) -> (B P, H, W, Cp) -> (B, P, H, W, Cp)
        let x = match &deviation {
            None => pairs.reshape((b * p, h, w, c))?,
            Some(d) if self.cfg.support_input => {
                let support = pair_support(&self.cfg, pairs)?.unsqueeze(4)?;
                Tensor::cat(&[pairs, d, &support], 4)?.reshape((b * p, h, w, c + 2))?
            }
            Some(d) => Tensor::cat(&[pairs, d], 4)?.reshape((b * p, h, w, c + 1))?,
        };
        let x = self.pair[0].forward(&x)?.relu()?;
        let f = self.pair[1].forward(&x)?.relu()?;
        let f = f.reshape((b, p, h, w, self.cfg.pair_channels))?;
        // (B, P, H, W, 1)
        let conf = pairs.narrow(4, 1, 1)?;
        // (B, P, H, W, 2) -> (B, H, W, 2): the base estimate is index and confidence
        let wsum = (conf.sum_keepdim(1)? + WEIGHT_EPS)?;
        // (B, H, W, Cp) each
        let mean = f
            .broadcast_mul(&conf)?
            .sum_keepdim(1)?
            .broadcast_div(&wsum)?
            .squeeze(1)?;
        let max = f.max_keepdim(1)?.squeeze(1)?;
        // (B, H, W, 2 Cp + 2)
        let pooled = Tensor::cat(&[&mean, &max, base], 3)?;
        let mut d = pooled;
        let mut r = rgb.clone();
        let mut fused = Vec::with_capacity(LEVELS);
        for k in 0..LEVELS {
            d = self.depth[k].forward(&d)?;
            r = self.rgb[k].forward(&r)?;
            // (B, H/2^k, W/2^k, C_k)
            fused.push(self.fuse[k].forward(&Tensor::cat(&[&d, &r], 3)?)?.relu()?);
        }
        // decoder, quarter -> full resolution
        let mut up = fused[LEVELS - 1].clone();
        for k in (0..LEVELS - 1).rev() {
            let x = Tensor::cat(&[&upsample_nearest(&up, 2)?, &fused[k]], 3)?;
            up = self.dec[k].forward(&x)?;
        }
        let (Some(select), Some(deviation)) = (&self.select, deviation) else {
            // (B, H, W, 2)
            let out = self.head.forward(&up)?;
            let delta = out.narrow(3, 0, 1)?.squeeze(3)?;
            let base_index = base.narrow(3, 0, 1)?.squeeze(3)?;
            return Ok(FusionOutput {
                index: (base_index + delta)?,
                confidence_logit: out.narrow(3, 1, 1)?.squeeze(3)?,
                pair_weights: None,
            });
        };
        // (B, P, H, W, C0): the decoder's features beside each pair's
        let c0 = self.cfg.channels[0];
        let ctx = up.unsqueeze(1)?.broadcast_as((b, p, h, w, c0))?;
        let x = Tensor::cat(&[&f, &ctx], 4)?.reshape((b * p, h, w, self.cfg.pair_channels + c0))?;
        // (B, P, H, W)
        let prior = (deviation.squeeze(4)?.abs()? * (-PRIOR_SHARPNESS))?;
        let score = (select.forward(&x)?.reshape((b, p, h, w))? + prior)?;
        let has_range = conf.squeeze(4)?.gt(0.0)?;
        let score =
            has_range.where_cond(&score, &score.ones_like()?.affine(0.0, NO_RANGE_SCORE)?)?;
        let weights = candle_nn::ops::softmax(&score, 1)?;
        // (B, H, W)
        let index = (pairs.narrow(4, 0, 1)?.squeeze(4)? * &weights)?.sum(1)?;
        Ok(FusionOutput {
            index,
            confidence_logit: self.head.forward(&up)?.squeeze(3)?,
            pair_weights: Some(weights),
        })
    }

    /// `(B, H, W)` range in metres from an output's index, clamped to the configured range.
    pub fn range_m(&self, out: &FusionOutput) -> Result<Tensor> {
        let span = self.cfg.log_span();
        (out.index.clamp(0.0, 1.0)? * (-span))?.exp()? * self.cfg.max_depth_m
    }

    /// `(B, H, W)` confidence in [0, 1].
    pub fn confidence(&self, out: &FusionOutput) -> Result<Tensor> {
        candle_nn::ops::sigmoid(&out.confidence_logit)
    }
}

/// Each pair's support `(B, P, H, W)` from `pairs (B, P, H, W, >= 2)` (index, confidence):
///
/// ```text
/// support_p = sum_q c_q [|index_p - index_q| ln(max / min) < ln 1.25] / (sum_q c_q + eps)
/// ```
///
/// The confidence-weighted share of the pairs that agree with pair `p` within one δ1
/// interval (`p` itself included), in [0, 1]; a pair without a range (confidence 0) adds
/// nothing to the others' support.
pub fn pair_support(cfg: &FusionConfig, pairs: &Tensor) -> Result<Tensor> {
    pairs.dims5()?;
    // (B, P, H, W) each
    let index = pairs.narrow(4, 0, 1)?.squeeze(4)?;
    let conf = pairs.narrow(4, 1, 1)?.squeeze(4)?;
    // (B, P, P, H, W): [p, q] = |index_p - index_q|
    let gap = index
        .unsqueeze(2)?
        .broadcast_sub(&index.unsqueeze(1)?)?
        .abs()?;
    let agree = gap
        .lt(DELTA1_LOG / cfg.log_span())?
        .to_dtype(pairs.dtype())?;
    // (B, P, H, W)
    let agreeing = agree.broadcast_mul(&conf.unsqueeze(1)?)?.sum(2)?;
    let total = (conf.sum_keepdim(1)? + WEIGHT_EPS)?;
    agreeing.broadcast_div(&total)
}

/// Per pixel of one pair's aligned estimate, `[index, confidence]` (both 0 where the range is
/// NaN), interleaved.
pub fn index_and_confidence(cfg: &FusionConfig, range_m: &[f32], confidence: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(range_m.len() * 2);
    for (&r, &c) in range_m.iter().zip(confidence) {
        if r.is_finite() && r > 0.0 {
            let t = cfg.index_of_range(f64::from(r)).clamp(0.0, 1.0) as f32;
            out.extend([t, c.clamp(0.0, 1.0)]);
        } else {
            out.extend([0.0, 0.0]);
        }
    }
    out
}

/// Per pixel of one pair's aligned estimate, the fusion input `[index, confidence, parallax]`
/// interleaved ([`index_and_confidence`] and the pair's parallax in metres).
pub fn pair_input(
    cfg: &FusionConfig,
    range_m: &[f32],
    confidence: &[f32],
    parallax_m: &[f32],
) -> Vec<f32> {
    let ic = index_and_confidence(cfg, range_m, confidence);
    let mut out = Vec::with_capacity(range_m.len() * PAIR_INPUT_CHANNELS);
    for (pair, &p) in ic.chunks_exact(2).zip(parallax_m) {
        out.extend([pair[0], pair[1], p]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    /// A tensor's values, flattened.
    fn values(t: &Tensor) -> Vec<f32> {
        t.flatten_all().unwrap().to_vec1().unwrap()
    }

    #[test]
    fn an_untrained_network_returns_the_most_confident_pair() {
        let cfg = FusionConfig::tiny();
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = Fusion::new(&cfg, vb).unwrap();
        let (h, w) = (cfg.height(), cfg.width);
        let n = h * w;
        let ranges: Vec<f32> = (0..n).map(|k| 1.0 + (k % 50) as f32).collect();
        let conf = vec![0.7f32; n];
        let one = pair_input(&cfg, &ranges, &conf, &vec![0.5; n]);
        let pairs =
            Tensor::from_vec([one.clone(), one].concat(), (1, 2, h, w, 3), &Device::Cpu).unwrap();
        let base = index_and_confidence(&cfg, &ranges, &conf);
        let base = Tensor::from_vec(base, (1, h, w, 2), &Device::Cpu).unwrap();
        let rgb = Tensor::zeros((1, h, w, 3), DType::F32, &Device::Cpu).unwrap();
        let out = net.forward(&pairs, &base, &rgb).unwrap();
        let range = values(&net.range_m(&out).unwrap());
        for (a, b) in range.iter().zip(&ranges) {
            assert!((a - b).abs() < 1e-3 * b, "{a} vs {b}");
        }
        let c = values(&net.confidence(&out).unwrap());
        assert!(c.iter().all(|&v| (v - 0.5).abs() < 1e-6));
        // a wrong grid is refused
        let wrong = Tensor::zeros((1, 2, h, w + 2, 3), DType::F32, &Device::Cpu).unwrap();
        assert!(net.forward(&wrong, &base, &rgb).is_err());
    }

    #[test]
    fn an_untrained_select_head_is_a_soft_consensus_of_the_pairs_with_a_range() {
        let cfg = FusionConfig {
            head: FusionHead::Select,
            ..FusionConfig::tiny()
        };
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = Fusion::new(&cfg, vb).unwrap();
        let (h, w) = (cfg.height(), cfg.width);
        let n = h * w;
        // pairs at 4, 4.4 and 40 m, the third without a range on the first half of the
        // pixels; the base (consensus) at 4.2 m
        let at = |r: f32| vec![r; n];
        let mut third = at(40.0);
        third[..n / 2].fill(f32::NAN);
        let par = vec![0.5; n];
        let ranges = [4.0f64, 4.4, 40.0];
        let inputs: Vec<f32> = [at(4.0), at(4.4), third]
            .iter()
            .flat_map(|r| pair_input(&cfg, r, &vec![0.8; n], &par))
            .collect();
        let pairs = Tensor::from_vec(inputs, (1, 3, h, w, 3), &Device::Cpu).unwrap();
        let base = index_and_confidence(&cfg, &at(4.2), &at(0.9));
        let base = Tensor::from_vec(base, (1, h, w, 2), &Device::Cpu).unwrap();
        let rgb = Tensor::zeros((1, h, w, 3), DType::F32, &Device::Cpu).unwrap();
        let out = net.forward(&pairs, &base, &rgb).unwrap();
        let range = values(&net.range_m(&out).unwrap());
        // w_p ~ exp(-PRIOR_SHARPNESS |ln r_p - ln 4.2| / ln 1.25), blended in log range
        let expected = |count: usize| {
            let wts: Vec<f64> = ranges[..count]
                .iter()
                .map(|r| {
                    let dev = ((r / 4.2f64).ln() / DELTA1_LOG).abs().min(MAX_DEVIATION);
                    (-PRIOR_SHARPNESS * dev).exp()
                })
                .collect();
            let sum: f64 = wts.iter().sum();
            let ln: f64 = wts
                .iter()
                .zip(&ranges)
                .map(|(w, r)| w * r.ln())
                .sum::<f64>()
                / sum;
            (ln.exp() as f32, wts[count - 1] / sum)
        };
        let ((two, _), (three, far_weight)) = (expected(2), expected(3));
        assert!(
            far_weight < 1e-4,
            "the pair 10 times farther weighs {far_weight}"
        );
        for (k, r) in range.iter().enumerate() {
            let want = if k < n / 2 { two } else { three };
            assert!((r - want).abs() < 1e-3 * want, "pixel {k}: {r} vs {want}");
        }
        let weights = out.pair_weights.unwrap();
        assert_eq!(weights.dims(), &[1, 3, h, w]);
        let w2: Vec<f32> = weights
            .narrow(1, 2, 1)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        assert!(w2[..n / 2].iter().all(|&v| v == 0.0));
        assert!(w2[n / 2..]
            .iter()
            .all(|&v| (f64::from(v) - far_weight).abs() < 1e-6));
        // a correction file without the field still reads as a correction head
        let json = serde_json::to_string(&FusionConfig::small()).unwrap();
        let old = json
            .replace(",\"head\":\"correction\"", "")
            .replace(",\"support_input\":false", "");
        assert!(!old.contains("support_input") && !old.contains("head"));
        let old: FusionConfig = serde_json::from_str(&old).unwrap();
        assert_eq!(old, FusionConfig::small());
    }

    #[test]
    fn a_pairs_support_is_the_confidence_weighted_share_that_agrees_with_it() {
        let cfg = FusionConfig::tiny();
        // one pixel, four pairs: 4 m (c 0.8), 4.4 m (c 0.4, within 1.25 of 4), 40 m (c 0.8),
        // and a pair without a range (c 0, index 0)
        let mut input = Vec::new();
        for (r, c) in [(4.0f32, 0.8f32), (4.4, 0.4), (40.0, 0.8), (f32::NAN, 0.0)] {
            input.extend(pair_input(&cfg, &[r], &[c], &[0.5]));
        }
        let pairs = Tensor::from_vec(input, (1, 4, 1, 1, 3), &Device::Cpu).unwrap();
        let support = values(&pair_support(&cfg, &pairs).unwrap());
        let total = 0.8 + 0.4 + 0.8;
        let want = [1.2 / total, 1.2 / total, 0.8 / total, 0.0];
        for (got, want) in support.iter().zip(want) {
            assert!((got - want).abs() < 1e-5, "{support:?} vs {want:?}");
        }
        // with the support channel the untrained select head is still the prior's consensus
        let with = FusionConfig {
            head: FusionHead::Select,
            support_input: true,
            ..FusionConfig::tiny()
        };
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = Fusion::new(&with, vb).unwrap();
        let pair0 = varmap.data().lock().unwrap()["pair0.weight"]
            .dims()
            .to_vec();
        assert!(pair0.contains(&(PAIR_INPUT_CHANNELS + 2)), "{pair0:?}");
        let (h, w) = (with.height(), with.width);
        let n = h * w;
        let inputs: Vec<f32> = [4.0f32, 4.4]
            .iter()
            .flat_map(|&r| pair_input(&with, &vec![r; n], &vec![0.8; n], &vec![0.5; n]))
            .collect();
        let pairs = Tensor::from_vec(inputs, (1, 2, h, w, 3), &Device::Cpu).unwrap();
        let base = index_and_confidence(&with, &vec![4.0; n], &vec![0.9; n]);
        let base = Tensor::from_vec(base, (1, h, w, 2), &Device::Cpu).unwrap();
        let rgb = Tensor::zeros((1, h, w, 3), DType::F32, &Device::Cpu).unwrap();
        let range = values(
            &net.range_m(&net.forward(&pairs, &base, &rgb).unwrap())
                .unwrap(),
        );
        // weights 1 and exp(-2 ln 1.1 / ln 1.25) on 4 and 4.4 m, blended in log range
        let w1 = (-PRIOR_SHARPNESS * (1.1f64).ln() / DELTA1_LOG).exp();
        let want = ((4.0f64.ln() + w1 * 4.4f64.ln()) / (1.0 + w1)).exp() as f32;
        assert!(
            range.iter().all(|r| (r - want).abs() < 1e-3 * want),
            "{want}"
        );
    }

    #[test]
    fn index_and_range_invert() {
        let cfg = FusionConfig::small();
        for r in [0.5, 1.3, 20.0, 999.0] {
            let t = cfg.index_of_range(r);
            assert!((cfg.range_of_index(t) - r).abs() < 1e-9 * r);
        }
        assert!(cfg.index_of_range(cfg.max_depth_m).abs() < 1e-12);
        assert!((cfg.index_of_range(cfg.min_depth_m) - 1.0).abs() < 1e-12);
        let bad = FusionConfig {
            width: 30,
            ..FusionConfig::tiny()
        };
        assert_eq!(bad.validate().unwrap_err().field, "width");
    }
}
