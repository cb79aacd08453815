//! The lens check over a window of frames: per camera, which cells of its own view are blocked,
//! the blocked fraction reported on `/diagnostics` and the lens masks the estimators get.
//!
//! Both cues are counted on the camera's own panorama (its analysis grid), where a blocker
//! stays put:
//! * the odd-one-out votes ([`super::lens_health`]) land on the cell of the camera that saw the
//!   estimated point ([`LensVotes::cells`]), and each counts on the cells within
//!   [`SPLAT_RADIUS_CELLS`] of it (the directions land with gaps and overlaps, and a vote rests
//!   on a window of several cells anyway);
//! * the temporal cue ([`super::lens_motion`]) decides a cell once for the whole window.
//!
//! A cell is then
//!
//! ```text
//! clear     where the temporal cue sees it change (an opaque blocker does not)
//! blocked   where the temporal cue finds it still while the scene there moves,
//!           or else where odd(j) >= BLOCKED_VOTE * decided(j), decided(j) > 0
//! clear     where decided(j) > 0 otherwise; undecided where neither cue decides
//! ```
//!
//! and blocked cells count only in connected regions of at least [`MIN_REGION_FRACTION`] of
//! the sphere: a blocker is one large region, while the scattered spots of lens soiling and
//! chance mismatches are small. On a moving rig those regions then grow into the still,
//! undecided cells around them that look like the blocker (`grow_blocked`). The blocked
//! fraction is the weight of those regions over the
//! weight of the decided cells, with each cell weighted by its share of the camera's view
//! ([`LensGeometry::weights`]: solid angle for an ERP camera, image pixels for a fisheye). The
//! mask is the regions grown by [`MASK_DILATION_CELLS`] cells, since matching windows that
//! straddle the blocker's edge are spoiled too and the vote at the edge is split.

use super::lens_health::{
    describe_region, regions, LensHealth, LensVotes, BLOCKED_VOTE, MIN_REGION_FRACTION,
};
use super::lens_motion::{cell_changes, motion_votes, LensGeometry, CHANGE_MIN, STILL_MAX};
use mode360_core::geometry::{ErpGrid, Rig};
use mode360_estimator::lens_mask::{analysis_grid, cell_weight, dilate, LensMask};
use std::collections::VecDeque;

/// Frames a [`LensHealthWindow`] keeps by default (the node's and replay's window).
pub const LENS_WINDOW_FRAMES: usize = 10;
/// Cells (of the analysis grid, about 2.8° each) by which a blocked region is grown.
pub const MASK_DILATION_CELLS: usize = 2;
/// Each vote counts on the cells within this many cells of where it lands.
pub const SPLAT_RADIUS_CELLS: usize = 1;

/// The lens check over the newest `capacity` frames (older votes fall out, so a lens that is
/// cleaned reads clean again within a window).
#[derive(Clone, Debug)]
pub struct LensHealthWindow {
    capacity: usize,
    frames: VecDeque<LensVotes>,
    /// The rig's tables for the temporal cue (built on the first frame of a rig).
    geometry: Option<LensGeometry>,
    /// Every camera's cells over the current frames (renewed as each frame comes in).
    cells: Vec<CameraCells>,
}

/// One camera's cells over the window.
#[derive(Clone, Debug, PartialEq)]
struct CameraCells {
    /// Blocked, in regions large enough to count.
    blocked: Vec<bool>,
    /// Decided by either cue.
    decided: Vec<bool>,
}

impl LensHealthWindow {
    /// A window of `capacity` frames (at least one).
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            frames: VecDeque::new(),
            geometry: None,
            cells: Vec::new(),
        }
    }

    /// Adds one frame's votes of `rig`, dropping the oldest beyond the capacity (and every
    /// older frame when the rig changes).
    pub fn add(&mut self, rig: &Rig, votes: LensVotes) {
        if !self.geometry.as_ref().is_some_and(|g| g.serves(rig)) {
            self.frames.clear();
            self.geometry = Some(LensGeometry::new(rig));
        }
        self.push(votes);
    }

    /// Adds one frame's votes to the window.
    fn push(&mut self, votes: LensVotes) {
        if self.frames.len() == self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back(votes);
        self.cells = self.count_cells();
    }

    /// Whether a frame has been added.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Each camera's health over the window (empty before the first frame).
    pub fn health(&self) -> Vec<LensHealth> {
        let grid = analysis_grid();
        self.cells
            .iter()
            .enumerate()
            .map(|(c, cam)| {
                let weight = |k: usize| self.weight(c, k);
                let (mut seen, mut decided, mut blocked) = (0.0, 0.0, 0.0);
                let mut centre = [0.0f64; 2];
                for k in 0..grid.len() {
                    let w = weight(k);
                    seen += w;
                    if cam.decided[k] {
                        decided += w;
                    }
                    if cam.blocked[k] {
                        blocked += w;
                        centre[0] += w * (k % grid.width()) as f64;
                        centre[1] += w * (k / grid.width()) as f64;
                    }
                }
                LensHealth {
                    // Of the whole view, not of its decided part: a blocker is decided wherever
                    // it covers the view (the odd one out, still before a changing scene, or
                    // grown through still cells that look like it), so what stays undecided is
                    // clear view that no cue could check (the sky, parts few cameras see).
                    blocked_fraction: if seen > 0.0 { blocked / seen } else { 0.0 },
                    decided_fraction: if seen > 0.0 { decided / seen } else { 0.0 },
                    region: (blocked > 0.0).then(|| {
                        describe_region(
                            centre[0] / blocked / grid.width() as f64,
                            centre[1] / blocked / grid.height() as f64,
                        )
                    }),
                }
            })
            .collect()
    }

    /// Each camera's lens mask (rig order; `None` where nothing is blocked), empty before the
    /// first frame.
    pub fn masks(&self) -> Vec<Option<LensMask>> {
        let grid = analysis_grid();
        self.cells
            .iter()
            .map(|cam| {
                cam.blocked.iter().any(|&b| b).then(|| {
                    LensMask::from_cells(dilate(grid, &cam.blocked, MASK_DILATION_CELLS))
                        .unwrap_or_else(|| unreachable!("a mask of the analysis grid"))
                })
            })
            .collect()
    }

    /// Weight of camera `c`'s cell `k` in its view.
    fn weight(&self, c: usize, k: usize) -> f64 {
        match &self.geometry {
            Some(g) => g.weights()[c][k],
            None => cell_weight(analysis_grid(), k),
        }
    }

    /// Every camera's cells over the window (see the module docs).
    fn count_cells(&self) -> Vec<CameraCells> {
        let frames: Vec<&LensVotes> = self.frames.iter().collect();
        let changes = cell_changes(&frames);
        let motion = self
            .geometry
            .as_ref()
            .map(|g| motion_votes(g, &frames, &changes))
            .unwrap_or_default();
        let grid = analysis_grid();
        let all: f64 = (0..grid.len()).map(|k| cell_weight(grid, k)).sum();
        let greys = mean_greys(&frames);
        splat_counts(&frames)
            .into_iter()
            .enumerate()
            .map(|(c, (odd, counted))| {
                let mut decided = vec![false; grid.len()];
                let mut candidate = vec![false; grid.len()];
                for k in 0..grid.len() {
                    let state = match motion.get(c).and_then(|m| m[k]) {
                        Some(still) => Some(still),
                        None => (counted[k] > 0)
                            .then(|| f64::from(odd[k]) >= BLOCKED_VOTE * f64::from(counted[k])),
                    };
                    decided[k] = state.is_some();
                    candidate[k] = state == Some(true);
                }
                let mut blocked = vec![false; grid.len()];
                for region in regions(grid, &candidate) {
                    let area: f64 = region.iter().map(|&k| cell_weight(grid, k)).sum();
                    if area >= MIN_REGION_FRACTION * all {
                        for k in region {
                            blocked[k] = true;
                        }
                    }
                }
                let moving = changes.get(c).is_some_and(|change| {
                    moving_share(change, |k| self.weight(c, k)) >= MIN_MOVING_SHARE
                });
                if let (true, Some(change), Some(grey)) = (moving, changes.get(c), greys.get(c)) {
                    grow_blocked(grid, &mut blocked, &mut decided, change, grey);
                }
                CameraCells { blocked, decided }
            })
            .collect()
    }
}

impl Default for LensHealthWindow {
    fn default() -> Self {
        Self::new(LENS_WINDOW_FRAMES)
    }
}

/// Largest difference (grey in `[0, 1]`) between an undecided still cell and the median grey
/// of the blocked cells for the blocked region to take it in.
pub const GROW_GREY_DIFF: f32 = 0.08;

/// Share of a camera's view (by weight) that must change over the window for its blocked
/// regions to grow: on a parked rig everything is still, and stillness says nothing.
pub const MIN_MOVING_SHARE: f64 = 0.1;

/// Share of the seen weight whose cells change by at least [`CHANGE_MIN`] over the window.
fn moving_share(change: &[Option<f32>], weight: impl Fn(usize) -> f64) -> f64 {
    let (mut moving, mut seen) = (0.0, 0.0);
    for (k, x) in change.iter().enumerate() {
        if let Some(x) = x {
            seen += weight(k);
            if *x >= CHANGE_MIN {
                moving += weight(k);
            }
        }
    }
    if seen > 0.0 {
        moving / seen
    } else {
        0.0
    }
}

/// Grows the blocked regions into neighbouring cells that neither cue decided, that stay still
/// over the window and look like the blocker (grey within [`GROW_GREY_DIFF`] of the blocked
/// cells' median): where a blocker covers a part of the view that fewer than three cameras see
/// and whose scene is still too (the sky, far facades), neither cue can decide, but the
/// blocker's own look continues there. Grown cells count as blocked and decided. Only on a
/// moving rig (at least [`MIN_MOVING_SHARE`] of the view changing).
fn grow_blocked(
    grid: ErpGrid,
    blocked: &mut [bool],
    decided: &mut [bool],
    change: &[Option<f32>],
    grey: &[Option<f32>],
) {
    let mut inside: Vec<f32> = (0..grid.len())
        .filter(|&k| blocked[k])
        .filter_map(|k| grey[k])
        .collect();
    if inside.is_empty() {
        return;
    }
    inside.sort_unstable_by(f32::total_cmp);
    let typical = inside[inside.len() / 2];
    let mut stack: Vec<usize> = (0..grid.len()).filter(|&k| blocked[k]).collect();
    while let Some(k) = stack.pop() {
        for n in neighbourhood(grid, k, 1) {
            let takes = !decided[n]
                && change[n].is_some_and(|x| x <= STILL_MAX)
                && grey[n].is_some_and(|g| (g - typical).abs() <= GROW_GREY_DIFF);
            if takes {
                blocked[n] = true;
                decided[n] = true;
                stack.push(n);
            }
        }
    }
}

/// `[camera][j]`: each own cell's mean grey over the frames (`None` where never seen).
fn mean_greys(frames: &[&LensVotes]) -> Vec<Vec<Option<f32>>> {
    let n = frames.first().map_or(0, |f| f.grey.len());
    let cells = analysis_grid().len();
    (0..n)
        .map(|c| {
            let mut sum = vec![(0.0f32, 0u32); cells];
            for frame in frames {
                let Some(grey) = frame.grey.get(c) else {
                    continue;
                };
                for (acc, g) in sum.iter_mut().zip(grey) {
                    if let Some(g) = g {
                        acc.0 += g;
                        acc.1 += 1;
                    }
                }
            }
            sum.iter()
                .map(|&(s, count)| (count > 0).then(|| s / count as f32))
                .collect()
        })
        .collect()
}

/// Per camera, the odd-one-out votes counted on its own cells: `(odd, decided)` per cell.
fn splat_counts(frames: &[&LensVotes]) -> Vec<(Vec<u32>, Vec<u32>)> {
    let grid = analysis_grid();
    let n = frames.first().map_or(0, |f| f.votes.len());
    let mut counts = vec![(vec![0u32; grid.len()], vec![0u32; grid.len()]); n];
    for frame in frames.iter().filter(|f| f.votes.len() == n) {
        for (c, (votes, cells)) in frame.votes.iter().zip(&frame.cells).enumerate() {
            for (vote, cell) in votes.iter().zip(cells) {
                if let (Some(is_odd), Some(j)) = (vote, cell) {
                    for k in neighbourhood(grid, *j as usize, SPLAT_RADIUS_CELLS) {
                        counts[c].1[k] += 1;
                        counts[c].0[k] += u32::from(*is_odd);
                    }
                }
            }
        }
    }
    counts
}

/// The cells within `r` rows and columns of cell `k` (columns wrap, rows clamp; each once).
fn neighbourhood(grid: ErpGrid, k: usize, r: usize) -> impl Iterator<Item = usize> {
    let (w, h) = (grid.width(), grid.height());
    let (u, v) = (k % w, k / w);
    let rows = v.saturating_sub(r)..=(v + r).min(h - 1);
    rows.flat_map(move |vv| (0..=2 * r).map(move |du| vv * w + (u + w + du - r) % w))
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
        LensVotes {
            votes,
            cells,
            grey: vec![vec![None; n]; 3],
            inv_range: vec![vec![None; n]; 3],
        }
    }

    /// A window holding `frames` (no rig: the odd-one-out votes alone).
    fn window(frames: Vec<LensVotes>) -> LensHealthWindow {
        let mut window = LensHealthWindow::new(frames.len());
        for f in frames {
            window.push(f);
        }
        window
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
        let masks = window(frames).masks();
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
        assert!(window(frames).masks().iter().all(Option::is_none));
    }

    #[test]
    fn a_blocked_region_grows_into_still_look_alike_cells_only_on_a_moving_rig() {
        let n = analysis_grid().len();
        let big = block(40, 10, 20, 30);
        // Beside it, cells no vote decides (as where fewer than three cameras see).
        let beside = block(40, 40, 20, 20);
        let frames = |moving: bool| -> Vec<LensVotes> {
            (0..3)
                .map(|t| {
                    let mut f = frame(&big);
                    for &k in &beside {
                        f.votes[1][k] = None;
                    }
                    // Camera 1's own view: the blocker dark and still, the cells beside it
                    // still and nearly as dark, the rest of the scene changing from frame to
                    // frame when the rig moves.
                    f.grey[1] = (0..n)
                        .map(|k| {
                            Some(if big.contains(&k) {
                                0.1
                            } else if beside.contains(&k) {
                                0.12
                            } else if moving {
                                0.3 + 0.2 * t as f32
                            } else {
                                0.5
                            })
                        })
                        .collect();
                    f
                })
                .collect()
        };
        let moving = window(frames(true));
        let parked = window(frames(false));
        let masked =
            |w: &LensHealthWindow, k: usize| w.masks()[1].as_ref().is_some_and(|m| m.cells()[k]);
        // Away from the dilated edge of the big region.
        let inner_beside = block(45, 50, 10, 5);
        assert!(inner_beside.iter().all(|&k| masked(&moving, k)));
        assert!(inner_beside.iter().all(|&k| !masked(&parked, k)));
        let (fm, fp) = (
            moving.health()[1].blocked_fraction,
            parked.health()[1].blocked_fraction,
        );
        assert!(fm > fp + 0.01, "moving {fm} vs parked {fp}");
    }
}
