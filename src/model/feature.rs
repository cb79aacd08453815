//! Spherical feature extraction (paper section 4.1), shared by all cameras.
//!
//! ```text
//! image (B, H, W, 3) -> firstconv: 3x3 s2, 3x3             (B, c0, H/2, W/2)
//!   layer1: residual blocks                                  (B, c0, H/2, W/2)
//!   layer2: residual blocks, first with stride 2             (B, c1, H/4, W/4)
//!   layer3: residual blocks, dilation 2                      (B, c2, H/4, W/4)
//!   layer4: residual blocks of spherical convolutions        (B, H/4, W/4, c3)
//!   fuse: concat(layer2, layer3, layer4) -> 3x3 -> 1x1       (B, H/4, W/4, Cf)
//! ```
//!
//! Planar convolutions pad the ERP circularly in longitude and with zeros at the poles.

use candle_core::{Module, Result, Tensor};
use candle_nn::{Conv2d, Conv2dConfig, VarBuilder};

use super::config::SsmodeConfig;
use super::sphere_conv::{SphereConv, SphereConvTable};

/// Planar kernel side.
const KERNEL: usize = 3;
/// Dilation of the third stage.
const STAGE3_DILATION: usize = 2;
/// Stride of the downsampling convolutions.
const DOWNSAMPLE_STRIDE: usize = 2;

/// Pads `x (B, C, H, W)` by `pad` pixels: circular along W (longitude), zeros along H.
pub fn erp_pad(x: &Tensor, pad: usize) -> Result<Tensor> {
    if pad == 0 {
        return Ok(x.clone());
    }
    let w = x.dim(3)?;
    let left = x.narrow(3, w - pad, pad)?;
    let right = x.narrow(3, 0, pad)?;
    // (B, C, H, W + 2 pad) -> (B, C, H + 2 pad, W + 2 pad)
    Tensor::cat(&[&left, x, &right], 3)?.pad_with_zeros(2, pad, pad)
}

/// A planar conv with ERP padding: `k x k`, stride, dilation, bias.
#[derive(Clone, Debug)]
pub struct ErpConv {
    conv: Conv2d,
    pad: usize,
}

impl ErpConv {
    pub fn new(
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        dilation: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        let cfg = Conv2dConfig {
            padding: 0,
            stride,
            dilation,
            groups: 1,
            cudnn_fwd_algo: None,
        };
        Ok(Self {
            conv: candle_nn::conv2d(c_in, c_out, kernel, cfg, vb)?,
            pad: dilation * (kernel / 2),
        })
    }

    /// `(B, Cin, H, W)` -> `(B, Cout, H / stride, W / stride)`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.conv.forward(&erp_pad(x, self.pad)?)
    }
}

/// A residual block: `relu(conv2(relu(conv1(x))) + skip(x))`, skip a strided 1x1 conv when the
/// shape changes.
#[derive(Clone, Debug)]
pub struct ResidualBlock {
    conv1: ErpConv,
    conv2: ErpConv,
    downsample: Option<ErpConv>,
}

impl ResidualBlock {
    pub fn new(
        c_in: usize,
        c_out: usize,
        stride: usize,
        dilation: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        let downsample = if stride != 1 || c_in != c_out {
            Some(ErpConv::new(
                c_in,
                c_out,
                1,
                stride,
                1,
                vb.pp("downsample"),
            )?)
        } else {
            None
        };
        Ok(Self {
            conv1: ErpConv::new(c_in, c_out, KERNEL, stride, dilation, vb.pp("conv1"))?,
            conv2: ErpConv::new(c_out, c_out, KERNEL, 1, dilation, vb.pp("conv2"))?,
            downsample,
        })
    }

    /// `(B, Cin, H, W)` -> `(B, Cout, H / stride, W / stride)`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let y = self.conv2.forward(&self.conv1.forward(x)?.relu()?)?;
        let skip = match &self.downsample {
            Some(d) => d.forward(x)?,
            None => x.clone(),
        };
        (y + skip)?.relu()
    }
}

/// A residual block of two spherical convolutions, channels-last, linear skip when
/// `Cin != Cout`.
#[derive(Clone, Debug)]
pub struct SphereBlock {
    conv1: SphereConv,
    conv2: SphereConv,
    projection: Option<candle_nn::Linear>,
}

impl SphereBlock {
    pub fn new(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        let projection = if c_in != c_out {
            Some(candle_nn::linear(c_in, c_out, vb.pp("projection"))?)
        } else {
            None
        };
        Ok(Self {
            conv1: SphereConv::new(c_in, c_out, vb.pp("conv1"))?,
            conv2: SphereConv::new(c_out, c_out, vb.pp("conv2"))?,
            projection,
        })
    }

    /// `(B, H, W, Cin)` -> `(B, H, W, Cout)`.
    pub fn forward(&self, x: &Tensor, table: &SphereConvTable) -> Result<Tensor> {
        let y = self.conv1.forward(x, table)?.relu()?;
        let y = self.conv2.forward(&y, table)?;
        let skip = match &self.projection {
            Some(p) => p.forward(x)?,
            None => x.clone(),
        };
        (y + skip)?.relu()
    }
}

/// The per-camera spherical feature extractor.
#[derive(Clone, Debug)]
pub struct FeatureExtractor {
    firstconv: [ErpConv; 2],
    layer1: Vec<ResidualBlock>,
    layer2: Vec<ResidualBlock>,
    layer3: Vec<ResidualBlock>,
    layer4: Vec<SphereBlock>,
    fuse: [ErpConv; 2],
}

fn stage(
    c_in: usize,
    c_out: usize,
    blocks: usize,
    first_stride: usize,
    dilation: usize,
    vb: VarBuilder,
) -> Result<Vec<ResidualBlock>> {
    (0..blocks.max(1))
        .map(|i| {
            let (ci, s) = if i == 0 {
                (c_in, first_stride)
            } else {
                (c_out, 1)
            };
            ResidualBlock::new(ci, c_out, s, dilation, vb.pp(i.to_string()))
        })
        .collect()
}

impl FeatureExtractor {
    pub fn new(cfg: &SsmodeConfig, vb: VarBuilder) -> Result<Self> {
        let [c0, c1, c2, c3] = cfg.feature_channels;
        let [b1, b2, b3, b4] = cfg.feature_blocks;
        let vfc = vb.pp("firstconv");
        let firstconv = [
            ErpConv::new(3, c0, KERNEL, DOWNSAMPLE_STRIDE, 1, vfc.pp("0"))?,
            ErpConv::new(c0, c0, KERNEL, 1, 1, vfc.pp("1"))?,
        ];
        let layer1 = stage(c0, c0, b1, 1, 1, vb.pp("layer1"))?;
        let layer2 = stage(c0, c1, b2, DOWNSAMPLE_STRIDE, 1, vb.pp("layer2"))?;
        let layer3 = stage(c1, c2, b3, 1, STAGE3_DILATION, vb.pp("layer3"))?;
        let v4 = vb.pp("layer4");
        let layer4 = (0..b4.max(1))
            .map(|i| {
                let ci = if i == 0 { c2 } else { c3 };
                SphereBlock::new(ci, c3, v4.pp(i.to_string()))
            })
            .collect::<Result<Vec<_>>>()?;
        let vf = vb.pp("fuse");
        let fused_in = c1 + c2 + c3;
        let fuse = [
            ErpConv::new(
                fused_in,
                cfg.feature_out_channels * 2,
                KERNEL,
                1,
                1,
                vf.pp("0"),
            )?,
            ErpConv::new(
                cfg.feature_out_channels * 2,
                cfg.feature_out_channels,
                1,
                1,
                1,
                vf.pp("1"),
            )?,
        ];
        Ok(Self {
            firstconv,
            layer1,
            layer2,
            layer3,
            layer4,
            fuse,
        })
    }

    /// images `(B, H, W, 3)` in [0, 1] -> features `(B, H/4, W/4, Cf)` channels-last.
    pub fn forward(&self, images: &Tensor, sphere_table: &SphereConvTable) -> Result<Tensor> {
        // (B, 3, H, W), centred
        let x = images
            .permute((0, 3, 1, 2))?
            .contiguous()?
            .affine(2.0, -1.0)?;
        // (B, c0, H/2, W/2)
        let mut x = self.firstconv[0].forward(&x)?.relu()?;
        x = self.firstconv[1].forward(&x)?.relu()?;
        for block in &self.layer1 {
            x = block.forward(&x)?;
        }
        // (B, c1, H/4, W/4)
        for block in &self.layer2 {
            x = block.forward(&x)?;
        }
        let stage2 = x.clone();
        // (B, c2, H/4, W/4)
        for block in &self.layer3 {
            x = block.forward(&x)?;
        }
        let stage3 = x.clone();
        // (B, H/4, W/4, c3)
        let mut y = x.permute((0, 2, 3, 1))?.contiguous()?;
        for block in &self.layer4 {
            y = block.forward(&y, sphere_table)?;
        }
        let stage4 = y.permute((0, 3, 1, 2))?;
        // (B, c1 + c2 + c3, H/4, W/4) -> (B, Cf, H/4, W/4)
        let cat = Tensor::cat(&[&stage2, &stage3, &stage4], 1)?;
        let f = self.fuse[0].forward(&cat)?.relu()?;
        let f = self.fuse[1].forward(&f)?;
        // (B, H/4, W/4, Cf)
        f.permute((0, 2, 3, 1))?.contiguous()
    }
}
