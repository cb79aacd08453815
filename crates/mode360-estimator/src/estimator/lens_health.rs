//! Lens health: which part of each camera's view is blocked (mud, a mount, a vehicle part), from
//! the images and the estimated depth.
//!
//! On a coarse ERP grid of the output frame ([`ANALYSIS_WIDTH`] wide), every camera's grey
//! panorama is sampled at the estimated 3-D point of each direction, so that cameras that see
//! the point see the same thing there. For a direction `k` and cameras `a`, `b`, the windowed
//! statistics over `(2 WINDOW_RADIUS + 1)^2` cells give the means `mu`, deviations `sigma` and
//! the ZNCC; the two *match* at `k` when
//!
//! ```text
//! both textured (sigma > TEXTURELESS_SIGMA):   zncc_ab >= MATCH_ZNCC
//! both textureless:                            |mu_a - mu_b| <= MATCH_MEAN_DIFF
//! ```
//!
//! (one textured and one not: no match). Brightness alone does not tell a blocked lens from a
//! soiled one, whose dirt dims and veils the scene but keeps its structure.
//!
//! Camera `c` is *the odd one out* at `k` when it matches no other camera while two other
//! cameras match each other there (so at least three cameras must see `k`: a two-camera rig
//! cannot tell which lens is blocked, and its fractions stay 0). Directions where no two other
//! cameras agree (occlusions, depth errors) are undecided for `c`, and so are directions with
//! two odd ones out (where the estimated depth is likely wrong).
//!
//! Over a window of frames ([`LensHealthAccumulator`]), a direction counts as blocked for `c`
//! when `c` was the odd one out in at least [`BLOCKED_VOTE`] of the frames that decided it; the
//! blocked fraction is the solid angle (`cos(lat)` weights) of those directions, in connected
//! regions of at least [`MIN_REGION_FRACTION`] of the sphere, over the solid angle of the
//! decided ones. A blocker stays in place from frame to frame, while the chance
//! mismatches of a clean camera (a reflection, an occlusion edge, a depth error) move: the vote
//! keeps the second out.

use super::photometric::sampling::{bilinear_wrapped, CameraSampler};
use super::EstimatorError;
use crate::matching::{luma, INTENSITY_SCALE};
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::panorama::{panorama_rig, RigRemap};
use mode360_core::geometry::{ErpGrid, PixelCoord, Rig};

/// Width of the analysis grid (height half of it): coarse enough that a few pixels of depth
/// error or calibration do not matter, fine enough for regions of a few degrees.
pub const ANALYSIS_WIDTH: usize = 128;
/// Radius of the statistics window, analysis cells.
pub const WINDOW_RADIUS: usize = 2;
/// Largest difference of window means (grey in `[0, 1]`) between matching views.
pub const MATCH_MEAN_DIFF: f32 = 0.08;
/// Smallest ZNCC between matching textured windows.
pub const MATCH_ZNCC: f32 = 0.5;
/// A window whose deviation is at most this is textureless (matched on its mean alone).
pub const TEXTURELESS_SIGMA: f32 = 0.012;
/// Share of the deciding frames in which a direction must be the camera's odd one out to count
/// as blocked.
pub const BLOCKED_VOTE: f64 = 0.5;
/// Blocked regions smaller than this share of the sphere are dropped: a blocker is one large
/// region, while the scattered spots of lens soiling (drops, small mud spots, glare) and chance
/// mismatches are small.
pub const MIN_REGION_FRACTION: f64 = 0.04;
/// Frames a [`LensHealthWindow`] keeps by default (the node's and replay's window).
pub const LENS_WINDOW_FRAMES: usize = 10;
/// Nearest range used when sampling, metres (closer estimates are clamped).
const MIN_RANGE_M: f32 = 0.3;

/// Per direction of the analysis grid, camera by camera: odd one out, or undecided.
#[derive(Clone, Debug, PartialEq)]
pub struct LensVotes {
    /// `[camera][k]`: `Some(true)` the camera was the odd one out, `Some(false)` it agreed,
    /// `None` undecided.
    pub votes: Vec<Vec<Option<bool>>>,
    /// `[camera][k]`: the cell of the camera's own panorama, on the analysis grid, that sees
    /// direction `k`'s estimated point (`None` where its lens does not see it): where a vote
    /// lands on the lens, for [`super::lens_mask`].
    pub cells: Vec<Vec<Option<u32>>>,
}

/// Odd-one-out votes of one frame: `images` in rig order, `range_m` the estimated range of the
/// output frame (any ERP width).
pub fn lens_votes(
    rig: &Rig,
    images: &[RgbImage],
    range_m: &FloatImage,
) -> Result<LensVotes, EstimatorError> {
    if images.len() != rig.cameras.len() {
        return Err(EstimatorError::ImageCount {
            got: images.len(),
            expected: rig.cameras.len(),
        });
    }
    let grid = analysis_grid();
    let remap = RigRemap::new(rig, grid);
    let panoramas = remap
        .panoramas(images)
        .map_err(|(camera, e)| EstimatorError::BadImage {
            camera,
            problem: e.to_string(),
        })?;
    let validity = remap.validity();
    let pano_rig = panorama_rig(rig);
    let ranges = ranges_on(grid, range_m);
    let n = images.len();
    // Each camera's grey panorama sampled at every direction's estimated point.
    let mut warped = Vec::with_capacity(n);
    let mut cells = Vec::with_capacity(n);
    for (c, pano) in panoramas.iter().enumerate() {
        let (w, h) = (pano.width() as usize, pano.height() as usize);
        let camera_grid = ErpGrid::new(w).map_err(|_| EstimatorError::BadImageSize {
            camera: rig.cameras[c].name.clone(),
            width: w as u32,
            height: h as u32,
        })?;
        let grey: Vec<f32> = pano
            .pixels()
            .map(|p| luma([f32::from(p[0]), f32::from(p[1]), f32::from(p[2])]) * INTENSITY_SCALE)
            .collect();
        let sampler = CameraSampler::new(grid, &pano_rig.cam_from_output(c), camera_grid);
        let sees = validity[c].as_ref();
        let (samples, lens_cells): (Vec<Option<f32>>, Vec<Option<u32>>) = (0..grid.len())
            .map(|k| {
                let [u, v] = sampler.pixel(k, ranges[k]);
                let (ui, vi) = (u.round() as i64, v.round() as i64);
                let ui = ui.rem_euclid(w as i64) as usize;
                let vi = vi.clamp(0, h as i64 - 1) as usize;
                let seen =
                    sees.is_none_or(|valid| valid.get(vi * w + ui).is_some_and(|&x| x > 0.5));
                if !seen {
                    return (None, None);
                }
                // The camera pixel's cell on the analysis grid of the camera's panorama.
                let cu = (ui * grid.width() / w).min(grid.width() - 1);
                let cv = (vi * grid.height() / h).min(grid.height() - 1);
                (
                    Some(bilinear_wrapped(&grey, w, h, u, v)),
                    Some((cv * grid.width() + cu) as u32),
                )
            })
            .unzip();
        warped.push(samples);
        cells.push(lens_cells);
    }
    let mut votes: Vec<Vec<Option<bool>>> = (0..n)
        .map(|c| {
            (0..grid.len())
                .map(|k| odd_one_out(&warped, grid, c, k))
                .collect()
        })
        .collect();
    // Two odd ones out at one direction: the depth there is likely wrong (a view sampled at
    // the wrong point disagrees too), so neither vote counts.
    for k in 0..grid.len() {
        if (0..n).filter(|&c| votes[c][k] == Some(true)).count() > 1 {
            for camera in votes.iter_mut() {
                if camera[k] == Some(true) {
                    camera[k] = None;
                }
            }
        }
    }
    Ok(LensVotes { votes, cells })
}

/// The analysis grid.
pub fn analysis_grid() -> ErpGrid {
    // ANALYSIS_WIDTH is even and large enough: the constructor cannot fail on it.
    ErpGrid::new(ANALYSIS_WIDTH).unwrap_or_else(|_| unreachable!("ANALYSIS_WIDTH is valid"))
}

/// `range_m` (any ERP width) at the analysis grid's cells, nearest neighbour, clamped to
/// `[MIN_RANGE_M, inf)`; non-finite ranges (sky, no estimate) become the far plane.
pub(super) fn ranges_on(grid: ErpGrid, range_m: &FloatImage) -> Vec<f32> {
    let (w, h) = (range_m.width.max(1), range_m.height.max(1));
    let far = range_m
        .data
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .fold(MIN_RANGE_M, f32::max);
    (0..grid.len())
        .map(|k| {
            let (u, v) = (k % grid.width(), k / grid.width());
            let su = ((u as f64 + 0.5) * w as f64 / grid.width() as f64) as usize;
            let sv = ((v as f64 + 0.5) * h as f64 / grid.height() as f64) as usize;
            let d = range_m.data[sv.min(h - 1) * w + su.min(w - 1)];
            if d.is_finite() && d > 0.0 {
                d.max(MIN_RANGE_M)
            } else {
                far
            }
        })
        .collect()
}

/// Window statistics of one camera around cell `k`: mean, deviation and the centred values
/// (`None` when the camera does not see every cell of the window).
fn window(samples: &[Option<f32>], grid: ErpGrid, k: usize) -> Option<(f32, f32, Vec<f32>)> {
    let (w, h) = (grid.width() as i64, grid.height() as i64);
    let (u0, v0) = ((k as i64) % w, (k as i64) / w);
    let r = WINDOW_RADIUS as i64;
    let mut values = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
    for dv in -r..=r {
        let v = (v0 + dv).clamp(0, h - 1);
        for du in -r..=r {
            let u = (u0 + du).rem_euclid(w);
            values.push(samples[(v * w + u) as usize]?);
        }
    }
    let n = values.len() as f32;
    let mean = values.iter().sum::<f32>() / n;
    for x in &mut values {
        *x -= mean;
    }
    let sigma = (values.iter().map(|x| x * x).sum::<f32>() / n).sqrt();
    Some((mean, sigma, values))
}

/// Whether two windows show the same thing (see the module docs).
fn windows_match(a: &(f32, f32, Vec<f32>), b: &(f32, f32, Vec<f32>)) -> bool {
    match (a.1 <= TEXTURELESS_SIGMA, b.1 <= TEXTURELESS_SIGMA) {
        (true, true) => (a.0 - b.0).abs() <= MATCH_MEAN_DIFF,
        (false, false) => {
            let n = a.2.len() as f32;
            let cov = a.2.iter().zip(&b.2).map(|(x, y)| x * y).sum::<f32>() / n;
            cov / (a.1 * b.1) >= MATCH_ZNCC
        }
        _ => false,
    }
}

/// Camera `c`'s vote at cell `k`.
fn odd_one_out(warped: &[Vec<Option<f32>>], grid: ErpGrid, c: usize, k: usize) -> Option<bool> {
    let own = window(&warped[c], grid, k)?;
    let others: Vec<_> = (0..warped.len())
        .filter(|&j| j != c)
        .filter_map(|j| window(&warped[j], grid, k))
        .collect();
    let others_agree = others
        .iter()
        .enumerate()
        .any(|(i, a)| others[i + 1..].iter().any(|b| windows_match(a, b)));
    if !others_agree {
        return None;
    }
    Some(!others.iter().any(|o| windows_match(&own, o)))
}

/// Blocked fractions over a window of frames (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct LensHealthAccumulator {
    /// `[camera][k]`: frames in which the camera was the odd one out, and frames that decided.
    odd: Vec<Vec<u32>>,
    decided: Vec<Vec<u32>>,
}

/// The lens health over the newest `capacity` frames (older votes fall out, so a lens that is
/// cleaned reads clean again within a window).
#[derive(Clone, Debug)]
pub struct LensHealthWindow {
    capacity: usize,
    frames: std::collections::VecDeque<LensVotes>,
}

impl LensHealthWindow {
    /// A window of `capacity` frames (at least one).
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            frames: std::collections::VecDeque::new(),
        }
    }

    /// Adds one frame's votes, dropping the oldest beyond the capacity (and every older frame
    /// when the number of cameras changes).
    pub fn add(&mut self, votes: LensVotes) {
        if self
            .frames
            .front()
            .is_some_and(|f| f.votes.len() != votes.votes.len())
        {
            self.frames.clear();
        }
        if self.frames.len() == self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back(votes);
    }

    /// The frames in the window, oldest first.
    pub fn frames(&self) -> impl Iterator<Item = &LensVotes> {
        self.frames.iter()
    }

    /// Each camera's health over the window (empty before the first frame).
    pub fn health(&self) -> Vec<LensHealth> {
        let mut acc = LensHealthAccumulator::default();
        for votes in &self.frames {
            acc.add(votes);
        }
        acc.health()
    }
}

impl Default for LensHealthWindow {
    fn default() -> Self {
        Self::new(LENS_WINDOW_FRAMES)
    }
}

/// One camera's lens health over the accumulated frames.
#[derive(Clone, Debug, PartialEq)]
pub struct LensHealth {
    /// Share of the decided view found blocked, 0 to 1.
    pub blocked_fraction: f64,
    /// Share of the camera's view that was decided (how much the fraction rests on).
    pub decided_fraction: f64,
    /// Where the blocked part lies, e.g. "lower left" (`None` when nothing is blocked).
    pub region: Option<String>,
}

impl LensHealthAccumulator {
    /// Adds one frame's votes.
    pub fn add(&mut self, votes: &LensVotes) {
        let cells = analysis_grid().len();
        if self.odd.len() != votes.votes.len() {
            self.odd = vec![vec![0; cells]; votes.votes.len()];
            self.decided = vec![vec![0; cells]; votes.votes.len()];
        }
        for (c, camera) in votes.votes.iter().enumerate() {
            for (k, vote) in camera.iter().enumerate() {
                if let Some(odd) = vote {
                    self.decided[c][k] += 1;
                    self.odd[c][k] += u32::from(*odd);
                }
            }
        }
    }

    /// Each camera's health over the frames added so far.
    pub fn health(&self) -> Vec<LensHealth> {
        let grid = analysis_grid();
        let weight = |k: usize| cell_weight(grid, k);
        self.odd
            .iter()
            .zip(&self.decided)
            .map(|(odd, decided)| {
                let (mut seen, mut all) = (0.0, 0.0);
                let mut candidate = vec![false; grid.len()];
                for k in 0..grid.len() {
                    all += weight(k);
                    if decided[k] == 0 {
                        continue;
                    }
                    seen += weight(k);
                    candidate[k] = f64::from(odd[k]) >= BLOCKED_VOTE * f64::from(decided[k]);
                }
                let (mut blocked, mut centre) = (0.0, [0.0f64; 2]);
                for region in regions(grid, &candidate) {
                    let area: f64 = region.iter().map(|&k| weight(k)).sum();
                    if area < MIN_REGION_FRACTION * all {
                        continue;
                    }
                    blocked += area;
                    for &k in &region {
                        centre[0] += weight(k) * (k % grid.width()) as f64;
                        centre[1] += weight(k) * (k / grid.width()) as f64;
                    }
                }
                let blocked_fraction = if seen > 0.0 { blocked / seen } else { 0.0 };
                LensHealth {
                    blocked_fraction,
                    decided_fraction: if all > 0.0 { seen / all } else { 0.0 },
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
}

/// Solid-angle weight `cos(lat)` of cell `k` of `grid`.
pub(super) fn cell_weight(grid: ErpGrid, k: usize) -> f64 {
    grid.lonlat_from_pixel(PixelCoord {
        u: (k % grid.width()) as f64,
        v: (k / grid.width()) as f64,
    })
    .lat_rad
    .cos()
}

/// Where in the output panorama a region's centre lies (`u`, `v` in `[0, 1]`): "upper",
/// "middle" or "lower", then the side as seen in the panorama ("left", "centre", "right",
/// "back" at the seam).
fn describe_region(u: f64, v: f64) -> String {
    let height = if v < 1.0 / 3.0 {
        "upper"
    } else if v < 2.0 / 3.0 {
        "middle"
    } else {
        "lower"
    };
    let side = match u {
        u if !(0.125..0.875).contains(&u) => "back",
        u if u < 0.375 => "left",
        u if u < 0.625 => "front",
        _ => "right",
    };
    format!("{height} {side}")
}

/// The 4-connected regions of `mask` on `grid` (columns wrap across the seam), as cell lists.
pub(super) fn regions(grid: ErpGrid, mask: &[bool]) -> Vec<Vec<usize>> {
    let (w, h) = (grid.width(), grid.height());
    let mut seen = vec![false; mask.len()];
    let mut out = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        let (mut region, mut stack) = (Vec::new(), vec![start]);
        while let Some(k) = stack.pop() {
            region.push(k);
            let (u, v) = (k % w, k / w);
            let mut neighbours = vec![v * w + (u + 1) % w, v * w + (u + w - 1) % w];
            if v > 0 {
                neighbours.push(k - w);
            }
            if v + 1 < h {
                neighbours.push(k + w);
            }
            for n in neighbours {
                if mask[n] && !seen[n] {
                    seen[n] = true;
                    stack.push(n);
                }
            }
        }
        out.push(region);
    }
    out
}
