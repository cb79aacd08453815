//! SSMODE with a second, finer pass for near obstacles (issue 38).
//!
//! The network trained at 256 resolves a cost-volume cell of 1.4°: poles, posts and people
//! narrower than that melt into what stands behind them. Run at a finer input width (512) the
//! same weights keep many of them, but read the open sky too near (validation seed: 2-5 m
//! obstacles 11 of 19 against 7, 5-10 m 72 % against 54 %, sky δ1 73 % against 99 %). The
//! near pass takes the fine pass's range only where it says "nearer" with some margin and
//! within the range where obstacles matter:
//!
//! ```text
//! r = r_fine   where r_fine < NEAR_PASS_MAX_RANGE_M, NEAR_PASS_RATIO r_fine < r_coarse
//!              and c_fine >= NEAR_PASS_MIN_CONFIDENCE
//! r = r_coarse elsewhere (with its confidence)
//! ```
//!
//! A missing reading (NaN) counts as out of range. It costs one more forward pass at the fine
//! width (about 1.8 s at 512 on the 2-core CPU, docs/benchmarks.md).

use std::path::Path;

use image::RgbImage;
use mode360_core::geometry::{ErpGrid, Rig};

use super::lens_mask::LensMask;
use super::ssmode::SsmodeEstimator;
use super::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360_model::model::{ComputeDevice, ReadoutOverrides};

/// Farthest fine-pass range that may replace the coarse pass's, metres (chosen on the
/// validation seed among 5, 10, 20 and 30 m: models/README.md, "Obstacles").
pub const NEAR_PASS_MAX_RANGE_M: f32 = 30.0;
/// How much nearer than the coarse pass the fine pass must read (1.25: the obstacle metrics'
/// tolerance; 1.5 kept fewer obstacles).
pub const NEAR_PASS_RATIO: f32 = 1.25;

/// Lowest confidence of the fine pass for its range to count (0.5, 0.7, 0.8 and 0.9 tried on
/// the validation seed: 0.8 gave 0.1 point of δ1 back on three of four rows, soiled ones
/// included, and kept every obstacle 0.5 keeps).
pub const NEAR_PASS_MIN_CONFIDENCE: f32 = 0.8;

/// The coarse range `coarse` with the fine pass's `fine` where that reads an obstacle nearer
/// (see the module doc); confidences follow the range they belong to. Both on one grid.
pub fn combine(coarse: &DepthEstimate, fine: &DepthEstimate) -> DepthEstimate {
    let mut out = coarse.clone();
    let rows = out
        .range_m
        .data
        .iter_mut()
        .zip(out.confidence.data.iter_mut())
        .zip(fine.range_m.data.iter().zip(&fine.confidence.data));
    for ((r, c), (&rf, &cf)) in rows {
        let coarse_m = if r.is_finite() { *r } else { f32::INFINITY };
        if rf.is_finite()
            && rf < NEAR_PASS_MAX_RANGE_M
            && NEAR_PASS_RATIO * rf < coarse_m
            && cf >= NEAR_PASS_MIN_CONFIDENCE
        {
            *r = rf;
            *c = cf;
        }
    }
    out
}

/// SSMODE at its trained width, and again at a finer one for near obstacles.
pub struct NearPassEstimator {
    coarse: SsmodeEstimator,
    fine: SsmodeEstimator,
}

impl NearPassEstimator {
    /// The weights at `path` on `device`, run at their trained width and at `fine_width`,
    /// both passes read with `readout` ([`SsmodeEstimator::load_configured`]).
    pub fn load_on(
        path: impl AsRef<Path>,
        device: ComputeDevice,
        fine_width: usize,
        readout: &ReadoutOverrides,
    ) -> Result<Self, EstimatorError> {
        let path = path.as_ref();
        let coarse = SsmodeEstimator::load_configured(path, device, None, readout)?;
        let fine = SsmodeEstimator::load_configured(path, device, Some(fine_width), readout)?;
        Ok(Self { coarse, fine })
    }

    /// The input width of the fine pass.
    pub fn fine_width(&self) -> usize {
        self.fine.config().width
    }
}

impl DepthEstimator for NearPassEstimator {
    fn name(&self) -> &str {
        self.coarse.name()
    }

    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        let coarse = self.coarse.estimate(rig, images, output)?;
        let fine = self.fine.estimate(rig, images, output)?;
        Ok(combine(&coarse, &fine))
    }

    fn set_lens_masks(&mut self, masks: &[Option<LensMask>]) {
        self.coarse.set_lens_masks(masks);
        self.fine.set_lens_masks(masks);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(range: &[f32], conf: &[f32]) -> DepthEstimate {
        let grid = ErpGrid::new(4).expect("grid");
        DepthEstimate::on_grid(grid, range.to_vec(), conf.to_vec())
    }

    #[test]
    fn the_fine_pass_wins_only_where_it_sees_something_nearer() {
        let coarse = estimate(
            &[10.0, 10.0, 10.0, f32::NAN, 1000.0, 50.0, 2.0, 5.0],
            &[0.9; 8],
        );
        let fine = estimate(
            // 7.9 < 10 / 1.25: nearer; 8.1 not enough; 12 farther; 20 under the missing
            // coarse reading; 29 under the sky but not confident; 35 beyond the near range;
            // NaN; 1.0
            &[7.9, 8.1, 12.0, 20.0, 29.0, 35.0, f32::NAN, 1.0],
            &[0.85, 0.85, 0.85, 0.85, 0.7, 0.85, 0.85, 0.8],
        );
        let out = combine(&coarse, &fine);
        assert_eq!(
            out.range_m.data,
            vec![7.9, 10.0, 10.0, 20.0, 1000.0, 50.0, 2.0, 1.0]
        );
        assert_eq!(
            out.confidence.data,
            vec![0.85, 0.9, 0.9, 0.85, 0.9, 0.9, 0.9, 0.8]
        );
    }
}
