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
//! volume (B, D, H, W, C')   -> cost: 3x3x3 conv, stride (s, 1, 1)    (B, D/s, H, W, Cf)
//! coarse (B, D/s, H/s, W/s) -> linear x s in H and W: up             (B, D/s, H, W)
//! hidden = relu(cost + up · coarse.weight)                          (B, D/s, H, W, Cf)
//! fine = up + hidden · out.weight                                   (B, D/s, H, W)
//! ```
//!
//! Only `cost` looks at neighbours; `coarse` and `out` act per cell (weights `(Cf)`), because
//! at full resolution a 3x3x3 layer costs as much as the hourglasses' entry (a first version
//! with three of them took a training step from 3 to 9 s); [`crate::model::ops::fine_mix`]
//! runs the two in one pass each way. `out` starts at zero, so a network
//! given the head is the network without it until the head is trained, and its correction is
//! residual. Training reads the volume detached: the head learns to read the volume, the
//! features keep learning through the hourglasses only (its gradient into the 9-channel volume
//! doubled the head's backward pass). `cost` runs on each slab of the volume while the
//! hourglasses' entry convolution takes it ([`super::hourglass::CostAggregation::forward_slabs`]),
//! before the coarse cost exists. Variable names: `fine_head.cost.*`, `fine_head.coarse.weight`,
//! `fine_head.out.weight`.

use candle_core::{Result, Tensor};
use candle_nn::{Init, VarBuilder};

use super::config::SsmodeConfig;
use super::hourglass::Conv3d;
use crate::model::ops::{fine_mix, upsample_trilinear};

/// Prefix of the fine head's variables in a weights file.
pub const FINE_HEAD_PREFIX: &str = "fine_head";
/// The variable a file with a fine head must hold (the head's first layer).
pub const FINE_HEAD_KEY: &str = "fine_head.cost.weight";

/// See the module docs.
#[derive(Clone, Debug)]
pub struct FineHead {
    cost: Conv3d,
    /// `(Cf)`: the upsampled coarse cost's weight in each hidden channel.
    coarse: Tensor,
    /// `(Cf)`: each hidden channel's weight in the correction (starts at zero).
    out: Tensor,
    /// `(s, 1, 1)`: the hourglasses' spheres, the volume's rows and columns.
    stride: [usize; 3],
}

impl FineHead {
    /// The head of `cfg` (`cfg.fine_head_channels` hidden channels, at least 1).
    pub fn new(cfg: &SsmodeConfig, vb: VarBuilder) -> Result<Self> {
        let c = cfg.fine_head_channels.max(1);
        Ok(Self {
            cost: Conv3d::new(cfg.cost_volume_channels(), c, vb.pp("cost"))?,
            coarse: vb
                .pp("coarse")
                .get_with_hints(c, "weight", Init::Const(1.0))?,
            out: vb.pp("out").get_with_hints(c, "weight", Init::Const(0.0))?,
            stride: [cfg.aggregation_stride.max(1), 1, 1],
        })
    }

    /// The first layer on the volume, for [`super::hourglass::CostAggregation::forward_slabs`]
    /// (which runs it with stride `(s, 1, 1)` on each slab).
    pub fn cost_conv(&self) -> &Conv3d {
        &self.cost
    }

    /// The first layer on the whole volume `(B, D, H, W, C')` -> `(B, D/s, H, W, Cf)`, the
    /// volume detached (see the module docs).
    pub fn cost_part(&self, volume: &Tensor) -> Result<Tensor> {
        self.cost
            .forward_then(&volume.detach(), self.stride, None, false)
    }

    /// `cost_part (B, D/s, H, W, Cf)` ([`Self::cost_part`]) and the last hourglass's cost
    /// `coarse (B, D/s, H/s, W/s)` -> the corrected cost `(B, D/s, H, W)`.
    pub fn forward(&self, cost_part: &Tensor, coarse: &Tensor) -> Result<Tensor> {
        let (_, spheres, height, width, _) = cost_part.dims5()?;
        // (B, D/s, H, W)
        let up = upsample_trilinear(coarse, spheres, height, width)?;
        // (2, Cf)
        let w = Tensor::stack(&[&self.coarse, &self.out], 0)?;
        // (B, D/s, H, W)
        fine_mix(&up, cost_part, &w)
    }
}
