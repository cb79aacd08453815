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
}

/// The network. Variable names: `pair{0,1}`, `depth{k}`, `rgb{k}`, `fuse{k}`, `dec{0,1}`,
/// `head`.
#[derive(Clone, Debug)]
pub struct Fusion {
    cfg: FusionConfig,
    pair: [ErpConv; 2],
    depth: Vec<ResidualBlock>,
    rgb: Vec<ResidualBlock>,
    fuse: Vec<ErpConv>,
    dec: Vec<ResidualBlock>,
    head: ErpConv,
}

impl Fusion {
    pub fn new(cfg: &FusionConfig, vb: VarBuilder) -> Result<Self> {
        cfg.validate().map_err(candle_core::Error::wrap)?;
        let (cp, c) = (cfg.pair_channels, cfg.channels);
        let pair = [
            ErpConv::new(PAIR_INPUT_CHANNELS, cp, KERNEL, 1, 1, vb.pp("pair0"))?,
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
        let head = ErpConv::zeros(c[0], HEAD_CHANNELS, KERNEL, vb.pp("head"))?;
        Ok(Self {
            cfg: cfg.clone(),
            pair,
            depth,
            rgb,
            fuse,
            dec,
            head,
        })
    }

    pub fn config(&self) -> &FusionConfig {
        &self.cfg
    }

    /// `pairs (B, P, H, W, 3)` (index, confidence, both 0 where a pair says nothing, and the
    /// pair's parallax in metres, [`PairView::parallax_on`]),
    /// `base (B, H, W, 2)` (the most confident pair's index and confidence), `rgb (B, H, W, 3)`
    /// in [0, 1], all on the network's grid.
    pub fn forward(&self, pairs: &Tensor, base: &Tensor, rgb: &Tensor) -> Result<FusionOutput> {
        let (b, p, h, w, c) = pairs.dims5()?;
        if c != PAIR_INPUT_CHANNELS || (h, w) != (self.cfg.height(), self.cfg.width) || p == 0 {
            candle_core::bail!(
                "Fusion::forward: pairs {:?}, expected (B, P >= 1, {}, {}, {PAIR_INPUT_CHANNELS})",
                pairs.dims(),
                self.cfg.height(),
                self.cfg.width
            );
        }
        // (B P, H, W, 2) -> (B P, H, W, Cp) -> (B, P, H, W, Cp)
        let x = pairs.reshape((b * p, h, w, c))?;
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
        // (B, H, W, 2)
        let out = self.head.forward(&up)?;
        let delta = out.narrow(3, 0, 1)?.squeeze(3)?;
        let base_index = base.narrow(3, 0, 1)?.squeeze(3)?;
        Ok(FusionOutput {
            index: (base_index + delta)?,
            confidence_logit: out.narrow(3, 1, 1)?.squeeze(3)?,
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
        let range: Vec<f32> = net
            .range_m(&out)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        for (a, b) in range.iter().zip(&ranges) {
            assert!((a - b).abs() < 1e-3 * b, "{a} vs {b}");
        }
        let c: Vec<f32> = net
            .confidence(&out)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        assert!(c.iter().all(|&v| (v - 0.5).abs() < 1e-6));
        // a wrong grid is refused
        let wrong = Tensor::zeros((1, 2, h, w + 2, 3), DType::F32, &Device::Cpu).unwrap();
        assert!(net.forward(&wrong, &base, &rgb).is_err());
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
