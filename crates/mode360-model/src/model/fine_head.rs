//! The fine head: the final regression cost corrected at the cost volume's own resolution in
//! latitude and longitude.
//!
//! The hourglasses decide at `1 / s` of the cost volume's cells (`s` the aggregation's entry
//! stride: 2.8 degrees at 256 with `s` 2), so an obstacle narrower than that (a pole at 5 to
//! 8 m is 0.7 to 2 degrees wide) melts into what stands behind it, while the cost volume itself
//! still resolves it. The head reads the volume at full `H` and `W` (at the hourglasses' `D / s`
//! spheres) beside the coarse cost and adds a correction:
//!
//! ```text
//! volume (B, D, H, W, C')   -> cost: conv, stride (s, 1, 1)          (B, D/s, H, W, Cf)
//! coarse (B, D/s, H/s, W/s) -> linear x s in H and W: up             (B, D/s, H, W)
//! hidden = relu(cost + coarse_conv(up))                             (B, D/s, H, W, Cf)
//! fine = up + out(hidden)                                           (B, D/s, H, W)
//! ```
//!
//! `out` starts at zero, so a network given the head is the network without it until the head
//! is trained, and its correction is residual. The first layer is split in two (`cost` on the
//! volume, `coarse` on the upsampled cost; the sum is one convolution over both) so that
//! inference can run `cost` on each slab of the volume while the hourglasses' entry convolution
//! takes it ([`super::hourglass::CostAggregation::forward_slabs`]), before the coarse cost
//! exists. Variable names: `fine_head.cost.*`, `fine_head.coarse.weight`,
//! `fine_head.out.weight`.

use candle_core::{Result, Tensor};
use candle_nn::VarBuilder;

use super::config::SsmodeConfig;
use super::hourglass::Conv3d;
use crate::model::ops::upsample_trilinear;

/// Stride 1 along every axis.
const UNIT: [usize; 3] = [1, 1, 1];
/// Channel axis of a channels-last volume `(B, D, H, W, C)`.
const CHANNEL_AXIS: usize = 4;

/// Prefix of the fine head's variables in a weights file.
pub const FINE_HEAD_PREFIX: &str = "fine_head";
/// The variable a file with a fine head must hold (the head's first layer).
pub const FINE_HEAD_KEY: &str = "fine_head.cost.weight";

/// See the module docs.
#[derive(Clone, Debug)]
pub struct FineHead {
    cost: Conv3d,
    coarse: Conv3d,
    out: Conv3d,
    /// `(s, 1, 1)`: the hourglasses' spheres, the volume's rows and columns.
    stride: [usize; 3],
}

impl FineHead {
    /// The head of `cfg` (`cfg.fine_head_channels` hidden channels, at least 1).
    pub fn new(cfg: &SsmodeConfig, vb: VarBuilder) -> Result<Self> {
        let c = cfg.fine_head_channels.max(1);
        Ok(Self {
            cost: Conv3d::new(cfg.cost_volume_channels(), c, vb.pp("cost"))?,
            coarse: Conv3d::new_no_bias(1, c, vb.pp("coarse"))?,
            out: Conv3d::new_zeroed_no_bias(c, 1, vb.pp("out"))?,
            stride: [cfg.aggregation_stride.max(1), 1, 1],
        })
    }

    /// The first layer on the volume, for [`super::hourglass::CostAggregation::forward_slabs`]
    /// (which runs it with stride `(s, 1, 1)` on each slab).
    pub fn cost_conv(&self) -> &Conv3d {
        &self.cost
    }

    /// The first layer on the whole volume `(B, D, H, W, C')` -> `(B, D/s, H, W, Cf)`.
    pub fn cost_part(&self, volume: &Tensor) -> Result<Tensor> {
        self.cost.forward_then(volume, self.stride, None, false)
    }

    /// `cost_part (B, D/s, H, W, Cf)` ([`Self::cost_part`]) and the last hourglass's cost
    /// `coarse (B, D/s, H/s, W/s)` -> the corrected cost `(B, D/s, H, W)`.
    pub fn forward(&self, cost_part: &Tensor, coarse: &Tensor) -> Result<Tensor> {
        let (_, spheres, height, width, _) = cost_part.dims5()?;
        // (B, D/s, H, W)
        let up = upsample_trilinear(coarse, spheres, height, width)?;
        // (B, D/s, H, W, Cf)
        let hidden =
            self.coarse
                .forward_then(&up.unsqueeze(CHANNEL_AXIS)?, UNIT, Some(cost_part), true)?;
        // (B, D/s, H, W)
        let correction = self
            .out
            .forward_then(&hidden, UNIT, None, false)?
            .squeeze(CHANNEL_AXIS)?;
        up + correction
    }
}
