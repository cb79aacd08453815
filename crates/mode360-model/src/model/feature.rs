//! Spherical feature extraction (paper section 4.1), shared by all cameras.
//!
//! ```text
//! image (B, H, W, 3) -> firstconv: 3x3 s2, 3x3             (B, H/2, W/2, c0)
//!   layer1: residual blocks                                  (B, H/2, W/2, c0)
//!   layer2: residual blocks, first with stride 2             (B, H/4, W/4, c1)
//!   layer3: residual blocks, dilation 2                      (B, H/4, W/4, c2)
//!   layer4: residual blocks of spherical convolutions        (B, H/4, W/4, c3)
//!   fuse: concat(layer2, layer3, layer4) -> 3x3 -> 1x1       (B, H/4, W/4, Cf)
//! ```
//!
//! With a cost volume finer than the trunk (`cost_downsample` s of 1 or 2), a fine branch
//! gives the sweep matching features at `H/s x W/s`, where a cell is small enough to see
//! parallax:
//!
//! ```text
//! image (B, H, W, 3) -> fine: 3x3 stride s, 3x3             (B, H/s, W/s, Cfine)
//! trunk (B, H/4, W/4, Cf) -> nearest x(4/s)                (B, H/s, W/s, Cf)
//! matching: concat -> 3x3 -> 1x1                            (B, H/s, W/s, Cf)
//! ```
//!
//! Planar convolutions pad the ERP circularly in longitude and with zeros at the poles.

use candle_core::{Module, Result, Tensor};
use candle_nn::{Init, VarBuilder};

use crate::model::ops::{add_bias, conv3d};

use super::config::{SsmodeConfig, FEATURE_DOWNSAMPLE};
use super::sphere_conv::{SphereConv, SphereConvTable};

/// Planar kernel side.
const KERNEL: usize = 3;
/// Dilation of the third stage.
const STAGE3_DILATION: usize = 2;
/// Stride of the downsampling convolutions.
const DOWNSAMPLE_STRIDE: usize = 2;

/// Pads `x (B, H, W, C)` by `pad` pixels: circular along W (longitude), zeros along H.
pub fn erp_pad(x: &Tensor, pad: usize) -> Result<Tensor> {
    if pad == 0 {
        return Ok(x.clone());
    }
    let w = x.dim(2)?;
    let left = x.narrow(2, w - pad, pad)?;
    let right = x.narrow(2, 0, pad)?;
    // (B, H, W + 2 pad, C) -> (B, H + 2 pad, W + 2 pad, C)
    Tensor::cat(&[&left, x, &right], 2)?.pad_with_zeros(1, pad, pad)
}

/// A planar conv with ERP padding, channels-last: `k x k`, stride, dilation, bias; weight
/// `(1, k, k, Cin, Cout)` run by the fast `conv3d` kernel on a depth-1 volume. A dilated conv
/// (stride 1) is the plain conv applied to the `d x d` polyphase sub-images (space to batch),
/// which also keeps the longitude wrap exact for widths divisible by `d`.
#[derive(Clone, Debug)]
pub struct ErpConv {
    weight: Tensor,
    bias: Tensor,
    kernel: usize,
    stride: usize,
    dilation: usize,
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
        if dilation == 0 || stride == 0 || (dilation > 1 && stride > 1) {
            candle_core::bail!(
                "ErpConv {}: stride {stride} with dilation {dilation} is not supported",
                vb.prefix()
            );
        }
        let fan_in = kernel * kernel * c_in;
        let bound = (6.0 / fan_in as f64).sqrt();
        let weight = vb.get_with_hints(
            (1, kernel, kernel, c_in, c_out),
            "weight",
            Init::Uniform {
                lo: -bound,
                up: bound,
            },
        )?;
        let bias = vb.get_with_hints(c_out, "bias", Init::Const(0.0))?;
        Ok(Self {
            weight,
            bias,
            kernel,
            stride,
            dilation,
        })
    }

    /// A `kernel x kernel` conv, stride 1, whose weight and bias start at zero (a head whose
    /// output starts at 0).
    pub fn zeros(c_in: usize, c_out: usize, kernel: usize, vb: VarBuilder) -> Result<Self> {
        let weight =
            vb.get_with_hints((1, kernel, kernel, c_in, c_out), "weight", Init::Const(0.0))?;
        let bias = vb.get_with_hints(c_out, "bias", Init::Const(0.0))?;
        Ok(Self {
            weight,
            bias,
            kernel,
            stride: 1,
            dilation: 1,
        })
    }

    /// Undilated conv: `(B, H, W, Cin)` -> `(B, H / stride, W / stride, Cout)`.
    fn forward_plain(&self, x: &Tensor) -> Result<Tensor> {
        // (B, 1, H + 2p, W + 2p, Cin)
        let padded = erp_pad(x, self.kernel / 2)?.unsqueeze(1)?;
        // (B, 1, Ho, Wo, Cout)
        let y = conv3d(
            &padded,
            &self.weight,
            [1, self.stride, self.stride],
            [0, 0, 0],
        )?;
        add_bias(&y.squeeze(1)?, &self.bias)
    }

    /// `(B, H, W, Cin)` -> `(B, H / stride, W / stride, Cout)`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let d = self.dilation;
        if d == 1 {
            return self.forward_plain(x);
        }
        let (b, h, w, c) = x.dims4()?;
        if !h.is_multiple_of(d) || !w.is_multiple_of(d) {
            candle_core::bail!("ErpConv: {w}x{h} is not divisible by the dilation {d}");
        }
        // (B, H/d, d, W/d, d, C) -> (B, d, d, H/d, W/d, C) -> (B d d, H/d, W/d, C)
        let phases = x
            .reshape((b, h / d, d, w / d, d, c))?
            .permute((0, 2, 4, 1, 3, 5))?
            .contiguous()?
            .reshape((b * d * d, h / d, w / d, c))?;
        let y = self.forward_plain(&phases)?;
        let c_out = y.dim(3)?;
        // (B, d, d, H/d, W/d, Co) -> (B, H/d, d, W/d, d, Co) -> (B, H, W, Co)
        y.reshape((b, d, d, h / d, w / d, c_out))?
            .permute((0, 3, 1, 4, 2, 5))?
            .contiguous()?
            .reshape((b, h, w, c_out))
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

    /// `(B, H, W, Cin)` -> `(B, H / stride, W / stride, Cout)`.
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

/// Nearest-neighbour upsampling by an integer `factor`: `(B, H, W, C)` -> `(B, f H, f W, C)`
/// (a broadcast, so the gradient sums each block).
pub fn upsample_nearest(x: &Tensor, factor: usize) -> Result<Tensor> {
    if factor == 1 {
        return Ok(x.clone());
    }
    let (b, h, w, c) = x.dims4()?;
    x.reshape((b, h, 1, w, 1, c))?
        .broadcast_as((b, h, factor, w, factor, c))?
        .reshape((b, h * factor, w * factor, c))
}

/// The fine matching branch (see the module docs). Variables `fine.{0,1}`, `matching.{0,1}`.
#[derive(Clone, Debug)]
pub struct FineBranch {
    fine: [ErpConv; 2],
    matching: [ErpConv; 2],
    /// Trunk resolution over cost resolution (`4 / s`).
    upsample: usize,
}

impl FineBranch {
    pub fn new(cfg: &SsmodeConfig, fine_vb: VarBuilder, matching_vb: VarBuilder) -> Result<Self> {
        let cf = cfg.fine_channels;
        let c = cfg.feature_out_channels;
        let s = cfg.cost_downsample;
        Ok(Self {
            fine: [
                ErpConv::new(3, cf, KERNEL, s, 1, fine_vb.pp("0"))?,
                ErpConv::new(cf, cf, KERNEL, 1, 1, fine_vb.pp("1"))?,
            ],
            matching: [
                ErpConv::new(cf + c, cf, KERNEL, 1, 1, matching_vb.pp("0"))?,
                ErpConv::new(cf, cfg.matching_channels(), 1, 1, 1, matching_vb.pp("1"))?,
            ],
            upsample: FEATURE_DOWNSAMPLE / s,
        })
    }

    /// `image (B, H, W, 3)` centred, trunk features `(B, H/4, W/4, Cf)` -> matching features
    /// `(B, H/s, W/s, Cf)`.
    pub fn forward(&self, image: &Tensor, trunk: &Tensor) -> Result<Tensor> {
        // (B, H/s, W/s, Cfine)
        let x = self.fine[0].forward(image)?.relu()?;
        let x = self.fine[1].forward(&x)?.relu()?;
        // (B, H/s, W/s, Cfine + Cf)
        let cat = Tensor::cat(&[&x, &upsample_nearest(trunk, self.upsample)?], 3)?;
        let y = self.matching[0].forward(&cat)?.relu()?;
        self.matching[1].forward(&y)
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
    fine: Option<FineBranch>,
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
        let fine = if cfg.has_fine_branch() {
            Some(FineBranch::new(cfg, vb.pp("fine"), vb.pp("matching"))?)
        } else {
            None
        };
        Ok(Self {
            firstconv,
            layer1,
            layer2,
            layer3,
            layer4,
            fuse,
            fine,
        })
    }

    /// images `(B, H, W, 3)` in [0, 1] -> matching features `(B, H/s, W/s, Cf)` channels-last,
    /// `s` the config's `cost_downsample` (4: the trunk's own output).
    pub fn forward(&self, images: &Tensor, sphere_table: &SphereConvTable) -> Result<Tensor> {
        // (B, H, W, 3), centred
        let centred = images.affine(2.0, -1.0)?;
        // (B, H/2, W/2, c0)
        let mut x = self.firstconv[0].forward(&centred)?.relu()?;
        x = self.firstconv[1].forward(&x)?.relu()?;
        for block in &self.layer1 {
            x = block.forward(&x)?;
        }
        // (B, H/4, W/4, c1)
        for block in &self.layer2 {
            x = block.forward(&x)?;
        }
        let stage2 = x.clone();
        // (B, H/4, W/4, c2)
        for block in &self.layer3 {
            x = block.forward(&x)?;
        }
        let stage3 = x.clone();
        // (B, H/4, W/4, c3)
        for block in &self.layer4 {
            x = block.forward(&x, sphere_table)?;
        }
        // (B, H/4, W/4, c1 + c2 + c3) -> (B, H/4, W/4, Cf)
        let cat = Tensor::cat(&[&stage2, &stage3, &x], 3)?;
        let f = self.fuse[0].forward(&cat)?.relu()?;
        let trunk = self.fuse[1].forward(&f)?;
        match &self.fine {
            // (B, H/s, W/s, Cf)
            Some(fine) => fine.forward(&centred, &trunk),
            None => Ok(trunk),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    /// Direct loops: `y[v, u, o] = b[o] + sum_{i, j, c} w[i, j, c, o] x[v + d(i-1), (u + d(j-1)) mod W, c]`
    /// with zero rows outside the image.
    fn reference(
        x: &[f32],
        w: &[f32],
        b: &[f32],
        dims: (usize, usize, usize, usize),
        d: i64,
    ) -> Vec<f32> {
        let (h, wd, c, o) = dims;
        let mut y = vec![0.0; h * wd * o];
        for v in 0..h as i64 {
            for u in 0..wd as i64 {
                for oc in 0..o {
                    let mut acc = b[oc];
                    for i in 0..KERNEL as i64 {
                        for j in 0..KERNEL as i64 {
                            let vv = v + d * (i - 1);
                            if vv < 0 || vv >= h as i64 {
                                continue;
                            }
                            let uu = (u + d * (j - 1)).rem_euclid(wd as i64);
                            for ci in 0..c {
                                let xi = ((vv as usize * wd) + uu as usize) * c + ci;
                                let wi = ((i as usize * KERNEL + j as usize) * c + ci) * o + oc;
                                acc += w[wi] * x[xi];
                            }
                        }
                    }
                    y[((v as usize * wd) + u as usize) * o + oc] = acc;
                }
            }
        }
        y
    }

    #[test]
    fn erp_conv_matches_direct_loops_with_wrap_and_dilation() {
        const H: usize = 4;
        const W: usize = 8;
        const C: usize = 2;
        const O: usize = 3;
        for dilation in [1usize, 2] {
            let varmap = VarMap::new();
            let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
            let conv = ErpConv::new(C, O, KERNEL, 1, dilation, vb.pp("c")).expect("conv");
            let data: Vec<f32> = (0..H * W * C)
                .map(|k| ((k * 37) % 11) as f32 - 5.0)
                .collect();
            let x = Tensor::from_vec(data.clone(), (1, H, W, C), &Device::Cpu).unwrap();
            let y: Vec<f32> = conv
                .forward(&x)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap();
            let w: Vec<f32> = conv.weight.flatten_all().unwrap().to_vec1().unwrap();
            let b: Vec<f32> = conv.bias.to_vec1().unwrap();
            let expected = reference(&data, &w, &b, (H, W, C, O), dilation as i64);
            assert_eq!(y.len(), expected.len());
            for (k, (a, e)) in y.iter().zip(&expected).enumerate() {
                assert!(
                    (a - e).abs() < 1e-4,
                    "dilation {dilation}, element {k}: {a} vs {e}"
                );
            }
        }
    }
}
