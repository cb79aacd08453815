//! Lens masks: the part of each camera's own view that the lens check found blocked, so that
//! the estimators treat it as unseen (issue 21, item 2), and [`LensGuard`], which runs an
//! estimator with the masks of the frames before and keeps the lens check's window.
//!
//! The lens check votes per direction of the output frame ([`super::lens_health`]); each vote
//! also records the cell of the camera's own panorama that saw the estimated point
//! ([`LensVotes::cells`]). A blocker is fixed on the lens, so the votes are counted again per
//! camera cell over the window, each on the cells within [`SPLAT_RADIUS_CELLS`] of where it
//! landed: a cell is blocked when the camera was the odd one out in at least [`BLOCKED_VOTE`]
//! of the votes counted on it,
//!
//! ```text
//! blocked(j) = odd(j) >= BLOCKED_VOTE * decided(j),  decided(j) > 0
//! ```
//!
//! in connected regions of at least [`MIN_REGION_FRACTION`] of the sphere (`cos(lat)`
//! weights), the same rules as the reported fraction. The mask is those regions grown by
//! [`MASK_DILATION_CELLS`] cells, since matching windows that straddle the blocker's edge are
//! spoiled too and the vote at the edge is split.
//!
//! Where a mask is set, the photometric sweep drops the pairs of that camera (as it does where
//! a fisheye lens does not see), and SSMODE's cost volume counts the camera as not seeing those
//! samples (as for fisheye blind regions).

use super::lens_health::{
    analysis_grid, cell_weight, lens_votes, regions, LensHealth, LensHealthWindow, LensVotes,
    BLOCKED_VOTE, MIN_REGION_FRACTION,
};
use super::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::{ErpGrid, Rig};

/// Cells (of the analysis grid, about 2.8° each) by which a blocked region is grown.
pub const MASK_DILATION_CELLS: usize = 2;
/// Each vote counts on the cells within this many cells of where it lands: the directions of
/// the output grid land on the lens with gaps and overlaps (parallax, rounding), and a vote
/// rests on a matching window of several cells anyway.
pub const SPLAT_RADIUS_CELLS: usize = 1;

/// The blocked part of one camera's view, on the analysis grid of the camera's panorama (its
/// own ERP frame, as the estimators sweep it).
#[derive(Clone, Debug, PartialEq)]
pub struct LensMask {
    /// Row-major over [`analysis_grid`]: `true` where the lens is blocked.
    blocked: Vec<bool>,
}

impl LensMask {
    /// A mask from cells of the analysis grid; `None` unless it has one cell per grid cell.
    pub fn from_cells(blocked: Vec<bool>) -> Option<Self> {
        (blocked.len() == analysis_grid().len()).then_some(Self { blocked })
    }

    /// The blocked cells, row-major over the analysis grid.
    pub fn cells(&self) -> &[bool] {
        &self.blocked
    }

    /// Share of the sphere (solid angle) that is blocked.
    pub fn fraction(&self) -> f64 {
        let grid = analysis_grid();
        let (mut blocked, mut all) = (0.0, 0.0);
        for (k, &b) in self.blocked.iter().enumerate() {
            let w = cell_weight(grid, k);
            all += w;
            if b {
                blocked += w;
            }
        }
        if all > 0.0 {
            blocked / all
        } else {
            0.0
        }
    }

    /// The mask on another ERP grid of the same frame (nearest cell): `true` where blocked.
    pub fn blocked_on(&self, grid: ErpGrid) -> Vec<bool> {
        let mask = analysis_grid();
        (0..grid.len())
            .map(|k| {
                let (u, v) = (k % grid.width(), k / grid.width());
                let mu = ((u * mask.width()) / grid.width()).min(mask.width() - 1);
                let mv = ((v * mask.height()) / grid.height()).min(mask.height() - 1);
                self.blocked[mv * mask.width() + mu]
            })
            .collect()
    }
}

/// Each camera's mask (rig order; `None` where nothing is blocked) from the lens check's
/// frames (see the module docs). Empty without frames.
pub fn lens_masks<'a>(frames: impl IntoIterator<Item = &'a LensVotes>) -> Vec<Option<LensMask>> {
    let grid = analysis_grid();
    let mut odd: Vec<Vec<u32>> = Vec::new();
    let mut decided: Vec<Vec<u32>> = Vec::new();
    for frame in frames {
        if odd.len() != frame.votes.len() {
            odd = vec![vec![0; grid.len()]; frame.votes.len()];
            decided = odd.clone();
        }
        for (c, (votes, cells)) in frame.votes.iter().zip(&frame.cells).enumerate() {
            for (vote, cell) in votes.iter().zip(cells) {
                if let (Some(is_odd), Some(j)) = (vote, cell) {
                    for n in neighbourhood(grid, *j as usize, SPLAT_RADIUS_CELLS) {
                        decided[c][n] += 1;
                        odd[c][n] += u32::from(*is_odd);
                    }
                }
            }
        }
    }
    let all: f64 = (0..grid.len()).map(|k| cell_weight(grid, k)).sum();
    odd.iter()
        .zip(&decided)
        .map(|(odd, decided)| {
            let candidate: Vec<bool> = odd
                .iter()
                .zip(decided)
                .map(|(&o, &d)| d > 0 && f64::from(o) >= BLOCKED_VOTE * f64::from(d))
                .collect();
            let mut blocked = vec![false; grid.len()];
            let mut any = false;
            for region in regions(grid, &candidate) {
                let area: f64 = region.iter().map(|&k| cell_weight(grid, k)).sum();
                if area >= MIN_REGION_FRACTION * all {
                    any = true;
                    for k in region {
                        blocked[k] = true;
                    }
                }
            }
            any.then(|| LensMask {
                blocked: dilate(grid, &blocked, MASK_DILATION_CELLS),
            })
        })
        .collect()
}

/// The cells within `r` rows and columns of cell `k` (columns wrap, rows clamp; each once).
fn neighbourhood(grid: ErpGrid, k: usize, r: usize) -> impl Iterator<Item = usize> {
    let (w, h) = (grid.width(), grid.height());
    let (u, v) = (k % w, k / w);
    let rows = v.saturating_sub(r)..=(v + r).min(h - 1);
    rows.flat_map(move |vv| (0..=2 * r).map(move |du| vv * w + (u + w + du - r) % w))
}

/// `mask` grown by `r` cells in rows and columns (columns wrap, rows clamp).
fn dilate(grid: ErpGrid, mask: &[bool], r: usize) -> Vec<bool> {
    let (w, h) = (grid.width(), grid.height());
    let mut rows = vec![false; mask.len()];
    for v in 0..h {
        for u in 0..w {
            if mask[v * w + u] {
                for du in 0..=2 * r {
                    rows[v * w + (u + w + du - r) % w] = true;
                }
            }
        }
    }
    let mut out = vec![false; mask.len()];
    for v in 0..h {
        for u in 0..w {
            if rows[v * w + u] {
                for vv in v.saturating_sub(r)..=(v + r).min(h - 1) {
                    out[vv * w + u] = true;
                }
            }
        }
    }
    out
}

/// Runs an estimator on complete groups with the lens masks of the frames before, and keeps the
/// lens check's window (the node's and replay's lens health, eval's masks).
#[derive(Debug)]
pub struct LensGuard {
    window: LensHealthWindow,
    masks: Vec<Option<LensMask>>,
    /// Whether the estimator gets the masks (the check runs either way).
    masking: bool,
}

impl LensGuard {
    /// A guard over a window of `frames` frames; `masking` false only checks.
    pub fn new(frames: usize, masking: bool) -> Self {
        Self {
            window: LensHealthWindow::new(frames),
            masks: Vec::new(),
            masking,
        }
    }

    /// Each camera's health over the window (empty before the first frame).
    pub fn health(&self) -> Vec<LensHealth> {
        self.window.health()
    }

    /// Each camera's current mask (empty before the first frame or without masking).
    pub fn masks(&self) -> &[Option<LensMask>] {
        &self.masks
    }

    /// Estimates a complete group (`images` of every camera of `rig`), with the masks found so
    /// far, then checks the lenses on the estimate. On the first frame, when the check finds a
    /// blocked lens, the frame is estimated again with its mask rather than a frame late.
    pub fn estimate(
        &mut self,
        estimator: &mut dyn DepthEstimator,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        let first = !self.has_checked();
        let mut estimate = self.estimate_masked(estimator, rig, images, output)?;
        let changed = self.check(rig, images, &estimate.range_m)?;
        if changed && first && self.masks.iter().any(Option::is_some) {
            estimator.set_lens_masks(&self.masks);
            estimate = estimator.estimate(rig, images, output)?;
        }
        Ok(estimate)
    }

    /// Estimates with the masks the check has found so far, leaving this frame's check to
    /// [`Self::check`] (the node runs it after publishing, off the latency path).
    pub fn estimate_masked(
        &self,
        estimator: &mut dyn DepthEstimator,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        estimator.set_lens_masks(&self.masks);
        estimator.estimate(rig, images, output)
    }

    /// The lens check of one complete group: adds its votes (from the images and the range
    /// estimated from them) to the window and, when masking, renews the masks the next
    /// estimates get. Returns whether the masks changed.
    pub fn check(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        range_m: &FloatImage,
    ) -> Result<bool, EstimatorError> {
        self.window.add(lens_votes(rig, images, range_m)?);
        if !self.masking {
            return Ok(false);
        }
        let masks = lens_masks(self.window.frames());
        if masks == self.masks {
            return Ok(false);
        }
        self.masks = masks;
        Ok(true)
    }

    /// Whether the check has seen a frame.
    pub fn has_checked(&self) -> bool {
        self.window.frames().next().is_some()
    }

    /// Estimates without masks and without a lens check: a partial group (`rig` a subset of the
    /// cameras; the check needs every camera), or any group with the checks switched off.
    pub fn estimate_partial(
        &self,
        estimator: &mut dyn DepthEstimator,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        estimator.set_lens_masks(&[]);
        estimator.estimate(rig, images, output)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Votes of one frame in which camera 1 of 3 is the odd one out on the cells `odd_cells`
    /// and agrees elsewhere; each direction lands on the same-numbered cell of every camera.
    fn frame(odd_cells: &[usize]) -> LensVotes {
        let n = analysis_grid().len();
        let votes = (0..3)
            .map(|c| {
                (0..n)
                    .map(|k| Some(c == 1 && odd_cells.contains(&k)))
                    .collect()
            })
            .collect();
        let cells = (0..3)
            .map(|_| (0..n).map(|k| Some(k as u32)).collect())
            .collect();
        LensVotes { votes, cells }
    }

    /// The cells of a block of `rows` x `cols` cells at `(v0, u0)` of the analysis grid.
    fn block(v0: usize, u0: usize, rows: usize, cols: usize) -> Vec<usize> {
        let w = analysis_grid().width();
        (v0..v0 + rows)
            .flat_map(|v| (u0..u0 + cols).map(move |u| v * w + u))
            .collect()
    }

    #[test]
    fn a_large_blocked_region_is_masked_and_grown_small_spots_are_not() {
        let big = block(40, 10, 20, 30);
        let spot = block(10, 90, 2, 2);
        let cells: Vec<usize> = big.iter().chain(&spot).copied().collect();
        let frames = vec![frame(&cells), frame(&cells)];
        let masks = lens_masks(&frames);
        assert_eq!(masks.len(), 3);
        assert!(masks[0].is_none() && masks[2].is_none(), "{masks:?}");
        let mask = masks[1].as_ref().expect("camera 1 masked");
        let w = analysis_grid().width();
        for &k in &big {
            assert!(mask.cells()[k], "blocked cell {k} not masked");
        }
        // Grown by MASK_DILATION_CELLS on every side, not further (mid-side; the splat rounds
        // the corners: a corner cell has 4 odd votes of 9).
        let r = MASK_DILATION_CELLS;
        assert!(mask.cells()[(40 - r) * w + 25]);
        assert!(!mask.cells()[(40 - r - 1) * w + 25]);
        assert!(mask.cells()[50 * w + 39 + r]);
        assert!(!mask.cells()[50 * w + 39 + r + 1]);
        assert!(!mask.cells()[(40 - r) * w + 10 - r], "corner rounded off");
        // The small spot is below MIN_REGION_FRACTION and stays unmasked.
        assert!(spot.iter().all(|&k| !mask.cells()[k]));
        let masked = mask.cells().iter().filter(|&&b| b).count();
        let (block, grown) = (20 * 30, (20 + 2 * r) * (30 + 2 * r));
        assert!(masked > block && masked < grown, "{masked} cells");
    }

    #[test]
    fn a_region_odd_in_under_half_the_frames_is_not_masked() {
        let big = block(40, 10, 20, 30);
        let frames = vec![frame(&big), frame(&[]), frame(&[])];
        assert!(lens_masks(&frames).iter().all(Option::is_none));
    }

    #[test]
    fn masks_resample_onto_other_grids() -> Result<(), Box<dyn std::error::Error>> {
        let grid = analysis_grid();
        let mut cells = vec![false; grid.len()];
        // The left half of the panorama.
        for (k, c) in cells.iter_mut().enumerate() {
            *c = k % grid.width() < grid.width() / 2;
        }
        let mask = LensMask::from_cells(cells).ok_or("mask size")?;
        assert!((mask.fraction() - 0.5).abs() < 1e-9);
        let fine = ErpGrid::new(512)?;
        let on_fine = mask.blocked_on(fine);
        assert_eq!(on_fine.iter().filter(|&&b| b).count(), fine.len() / 2);
        assert!(on_fine[0] && !on_fine[511]);
        assert!(LensMask::from_cells(vec![true; 3]).is_none());
        Ok(())
    }
}
