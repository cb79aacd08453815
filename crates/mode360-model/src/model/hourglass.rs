//! 3-D stacked hourglass cost aggregation (PSMNet style), channels-last.
//!
//! ```text
//! volume (B, D, H, W, C') -> dres0: 2 convs (the first with stride s; the seam wrap of p / s
//!                            columns between them) -> dres1: residual pair (B, D/s, H/s, W'/s, Ch)
//! hourglass k: conv1 s2 -> conv2 -> conv3 s2 -> conv4                      (B, D/4, H/4, W/4, 2 Ch)
//!              conv5 deconv x2 (+ conv2 output) -> conv6 deconv x2 (+ input) (B, D, H, W, Ch)
//! ```

use candle_core::{Result, Tensor};
use candle_nn::{Init, VarBuilder};

use super::config::SsmodeConfig;
use super::seam::wrap_longitude;
use crate::model::ops::{
    add_bias, conv3d, conv3d_fused, conv_transpose3d, conv_transpose3d_x2_fused, is_inference,
    Epilogue,
};

/// Kernel side of every 3-D convolution.
pub const KERNEL_3D: usize = 3;
const PAD: [usize; 3] = [1, 1, 1];
const UNIT: [usize; 3] = [1, 1, 1];
const STRIDE2: [usize; 3] = [2, 2, 2];
/// Output spheres of the entry convolution per slab in [`CostAggregation::forward_slabs`]: at
/// stride 2, 17 spheres of the cost volume at a time (20 MiB of the 9-channel volume at 256
/// against 108 MiB for all 96).
pub const SLAB_OUTPUT_SPHERES: usize = 8;
/// `op = 2 D - (2 D - 1)` for an exact x2 upsampling of even targets.
const OUTPUT_PADDING: [usize; 3] = [1, 1, 1];

/// A 3x3x3 convolution (or transposed convolution) with bias, weight `(3, 3, 3, Cin, Cout)`.
#[derive(Clone, Debug)]
pub struct Conv3d {
    weight: Tensor,
    bias: Option<Tensor>,
}

impl Conv3d {
    pub fn new(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        let mut conv = Self::new_no_bias(c_in, c_out, vb.clone())?;
        conv.bias = Some(vb.get_with_hints(c_out, "bias", Init::Const(0.0))?);
        Ok(conv)
    }

    /// Without bias (for a layer followed by a shift-invariant softmax, whose bias would get
    /// no gradient).
    pub fn new_no_bias(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        let fan_in = KERNEL_3D.pow(3) * c_in;
        let bound = (6.0 / fan_in as f64).sqrt();
        let weight = vb.get_with_hints(
            (KERNEL_3D, KERNEL_3D, KERNEL_3D, c_in, c_out),
            "weight",
            Init::Uniform {
                lo: -bound,
                up: bound,
            },
        )?;
        Ok(Self { weight, bias: None })
    }

    /// `(B, D, H, W, Cin)` -> `(B, D/s, H/s, W/s, Cout)`.
    pub fn forward(&self, x: &Tensor, stride: [usize; 3]) -> Result<Tensor> {
        self.add_bias(conv3d(x, &self.weight, stride, PAD)?)
    }

    /// `relu?(forward(x, stride) + residual)`, by the fused kernel when nothing is tracked.
    pub fn forward_then(
        &self,
        x: &Tensor,
        stride: [usize; 3],
        residual: Option<&Tensor>,
        relu: bool,
    ) -> Result<Tensor> {
        if is_inference(x, &self.weight) {
            let epilogue = self.epilogue(residual, relu);
            return conv3d_fused(x, &self.weight, stride, PAD, epilogue);
        }
        Self::finish(self.forward(x, stride)?, residual, relu)
    }

    /// Inference's `relu?(forward(x, stride))` with `padding` instead of 1 on every side (the
    /// fused kernel; for [`CostAggregation::forward_slabs`], whose slabs carry their own
    /// neighbouring spheres).
    pub(crate) fn forward_padded(
        &self,
        x: &Tensor,
        stride: [usize; 3],
        padding: [usize; 3],
        relu: bool,
    ) -> Result<Tensor> {
        conv3d_fused(x, &self.weight, stride, padding, self.epilogue(None, relu))
    }

    /// `relu?(forward_up(x) + residual)`, by the fused kernel when nothing is tracked.
    pub fn forward_up_then(
        &self,
        x: &Tensor,
        residual: Option<&Tensor>,
        relu: bool,
    ) -> Result<Tensor> {
        if is_inference(x, &self.weight) {
            let epilogue = self.epilogue(residual, relu);
            return conv_transpose3d_x2_fused(x, &self.weight, epilogue);
        }
        Self::finish(self.forward_up(x)?, residual, relu)
    }

    fn epilogue<'a>(&'a self, residual: Option<&'a Tensor>, relu: bool) -> Epilogue<'a> {
        Epilogue {
            bias: self.bias.as_ref(),
            residual,
            relu,
        }
    }

    fn finish(y: Tensor, residual: Option<&Tensor>, relu: bool) -> Result<Tensor> {
        let y = match residual {
            Some(r) => (y + r)?,
            None => y,
        };
        if relu {
            y.relu()
        } else {
            Ok(y)
        }
    }

    fn add_bias(&self, y: Tensor) -> Result<Tensor> {
        match &self.bias {
            Some(b) => add_bias(&y, b),
            None => Ok(y),
        }
    }

    /// Transposed, x2: `(B, D, H, W, Cin)` -> `(B, 2D, 2H, 2W, Cout)`.
    pub fn forward_up(&self, x: &Tensor) -> Result<Tensor> {
        self.add_bias(conv_transpose3d(
            x,
            &self.weight,
            STRIDE2,
            PAD,
            OUTPUT_PADDING,
        )?)
    }
}

/// One hourglass.
#[derive(Clone, Debug)]
pub struct Hourglass {
    conv1: Conv3d,
    conv2: Conv3d,
    conv3: Conv3d,
    conv4: Conv3d,
    conv5: Conv3d,
    conv6: Conv3d,
}

impl Hourglass {
    pub fn new(c: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            conv1: Conv3d::new(c, 2 * c, vb.pp("conv1"))?,
            conv2: Conv3d::new(2 * c, 2 * c, vb.pp("conv2"))?,
            conv3: Conv3d::new(2 * c, 2 * c, vb.pp("conv3"))?,
            conv4: Conv3d::new(2 * c, 2 * c, vb.pp("conv4"))?,
            conv5: Conv3d::new(2 * c, 2 * c, vb.pp("conv5"))?,
            conv6: Conv3d::new(2 * c, c, vb.pp("conv6"))?,
        })
    }

    /// `(B, D, H, W, C)` -> `(B, D, H, W, C)`; D, H, W multiples of 4.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        // (B, D/2, H/2, W/2, 2C)
        let out = self.conv1.forward_then(x, STRIDE2, None, true)?;
        let pre = self.conv2.forward_then(&out, UNIT, None, true)?;
        // (B, D/4, H/4, W/4, 2C)
        let out = self.conv3.forward_then(&pre, STRIDE2, None, true)?;
        let out = self.conv4.forward_then(&out, UNIT, None, true)?;
        // (B, D/2, H/2, W/2, 2C)
        let post = self.conv5.forward_up_then(&out, Some(&pre), true)?;
        // (B, D, H, W, C)
        self.conv6.forward_up_then(&post, Some(x), false)
    }
}

/// `dres0`, `dres1` and the stacked hourglasses; returns every hourglass output. `dres0.0`
/// enters with the config's `aggregation_stride` along D, H and W.
#[derive(Clone, Debug)]
pub struct CostAggregation {
    dres0: [Conv3d; 2],
    dres1: [Conv3d; 2],
    hourglasses: Vec<Hourglass>,
    entry_stride: [usize; 3],
}

impl CostAggregation {
    pub fn new(cfg: &SsmodeConfig, vb: VarBuilder) -> Result<Self> {
        let c = cfg.hourglass_channels;
        let c_in = cfg.cost_volume_channels();
        Ok(Self {
            dres0: [
                Conv3d::new(c_in, c, vb.pp("dres0.0"))?,
                Conv3d::new(c, c, vb.pp("dres0.1"))?,
            ],
            dres1: [
                Conv3d::new(c, c, vb.pp("dres1.0"))?,
                Conv3d::new(c, c, vb.pp("dres1.1"))?,
            ],
            hourglasses: (0..cfg.hourglasses)
                .map(|k| Hourglass::new(c, vb.pp(format!("hourglass{k}"))))
                .collect::<Result<_>>()?,
            entry_stride: [cfg.aggregation_stride; 3],
        })
    }

    /// volume `(B, D, H, W, C')` -> one `(B, D/s, H/s, (W + 2 p)/s, Ch)` per hourglass, `s` the
    /// entry stride, `p` = `seam_pad_cells`: after the entry convolution `p / s` columns from
    /// across the longitude seam are copied to each side ([`super::seam`]), so every later
    /// layer aggregates the seam with its true neighbours (the entry convolution's own zero
    /// padding reaches one column).
    pub fn forward(&self, volume: &Tensor, seam_pad_cells: usize) -> Result<Vec<Tensor>> {
        // (B, D/s, H/s, W/s, Ch)
        let x = self.dres0[0].forward_then(volume, self.entry_stride, None, true)?;
        self.after_entry(x, seam_pad_cells)
    }

    /// [`Self::forward`] for inference without the whole volume: `slab(range)` returns the
    /// volume's spheres `range` `(B, len, H, W, C')`, and the entry convolution runs on a few
    /// output spheres at a time, each slab with the neighbouring spheres its kernel reaches
    /// (the first with the zero padding of the whole), so the result is the whole volume's bit
    /// for bit and at most [`SLAB_OUTPUT_SPHERES`] output spheres' worth of volume is held.
    ///
    /// With `side`, a convolution (the fine head's first layer) runs on each slab too, with
    /// stride `s` along D and 1 along H and W, so it reaches the same spheres, and its output
    /// `(B, D/s, H, W, Cf)` (no ReLU) is returned beside the hourglasses'.
    pub fn forward_slabs(
        &self,
        spheres: usize,
        mut slab: impl FnMut(std::ops::Range<usize>) -> Result<Tensor>,
        seam_pad_cells: usize,
        side: Option<&Conv3d>,
    ) -> Result<(Vec<Tensor>, Option<Tensor>)> {
        let s = self.entry_stride[0];
        // output spheres of the entry convolution: (D + 2 - 3) / s + 1
        let out_spheres = (spheres + 2 * PAD[0] - KERNEL_3D) / s + 1;
        let mut parts = Vec::new();
        let mut side_parts = Vec::new();
        let mut first = 0;
        while first < out_spheres {
            let end = (first + SLAB_OUTPUT_SPHERES).min(out_spheres);
            // input spheres the kernel reaches: (first s - 1) ..= ((end - 1) s + 1)
            let front_pad = first * s < PAD[0];
            let lo = (first * s).saturating_sub(PAD[0]);
            let hi = ((end - 1) * s + PAD[0] + 1).min(spheres);
            let back_pad = (end - 1) * s + PAD[0] + 1 > spheres;
            let mut x = slab(lo..hi)?;
            if back_pad && !front_pad {
                // the last slab's missing neighbour: the zero padding of the whole
                let (b, _, h, w, c) = x.dims5()?;
                let zero = Tensor::zeros((b, 1, h, w, c), x.dtype(), x.device())?;
                x = Tensor::cat(&[&x, &zero], 1)?;
            }
            // a symmetric padding of 1 where the slab starts at the volume's front (any
            // output it adds past the slab's end is dropped)
            let pad_d = usize::from(front_pad);
            let padding = [pad_d, PAD[1], PAD[2]];
            // (B, end - first (+ extra), H/s, W/s, Ch)
            let y = self.dres0[0].forward_padded(&x, self.entry_stride, padding, true)?;
            parts.push(y.narrow(1, 0, end - first)?);
            if let Some(conv) = side {
                // (B, end - first (+ extra), H, W, Cf)
                let y = conv.forward_padded(&x, [s, 1, 1], padding, false)?;
                side_parts.push(y.narrow(1, 0, end - first)?);
            }
            drop(x);
            first = end;
        }
        // (B, D/s, H/s, W/s, Ch)
        let x = Tensor::cat(&parts, 1)?;
        drop(parts);
        // (B, D/s, H, W, Cf)
        let side = side.map(|_| Tensor::cat(&side_parts, 1)).transpose()?;
        Ok((self.after_entry(x, seam_pad_cells)?, side))
    }

    /// Everything after the entry convolution `x (B, D/s, H/s, W/s, Ch)`.
    fn after_entry(&self, x: Tensor, seam_pad_cells: usize) -> Result<Vec<Tensor>> {
        // (B, D/s, H/s, (W + 2 p)/s, Ch)
        let x = wrap_longitude(&x, seam_pad_cells / self.entry_stride[2])?;
        let x = self.dres0[1].forward_then(&x, UNIT, None, true)?;
        let y = self.dres1[0].forward_then(&x, UNIT, None, true)?;
        let mut x = self.dres1[1].forward_then(&y, UNIT, Some(&x), false)?;
        let mut outs = Vec::with_capacity(self.hourglasses.len());
        for hg in &self.hourglasses {
            x = hg.forward(&x)?;
            outs.push(x.clone());
        }
        Ok(outs)
    }
}
