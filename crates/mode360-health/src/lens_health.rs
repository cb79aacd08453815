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
//! cameras match each other there (so at least three cameras must see `k`). Directions where
//! no two other cameras agree (occlusions, depth errors) are undecided for `c`, and so are
//! directions with two odd ones out (where the estimated depth is likely wrong).
//!
//! Each frame's votes ([`LensVotes`]) also keep where each vote lands on the camera's own
//! panorama, that panorama's grey and the estimated inverse range of each of its cells, for
//! the temporal cue ([`super::lens_motion`]: a blocker stays still while the scene behind it
//! moves, which one other camera is enough to see). [`super::lens_window`] counts both over a
//! window of frames, on each camera's own view, into the blocked fraction and the lens masks.

use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::panorama::{panorama_rig, RigRemap};
use mode360_core::geometry::{ErpGrid, PixelCoord, Rig};
/// The analysis grid lives with the lens masks that the estimators read.
pub use mode360_estimator::lens_mask::{analysis_grid, ANALYSIS_WIDTH};
use mode360_estimator::photometric::sampling::{bilinear_wrapped, CameraSampler};
use mode360_estimator::EstimatorError;
use mode360_model::matching::{luma, INTENSITY_SCALE};
use nalgebra::Isometry3;

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
    /// `[camera][j]`: the camera's own panorama on the analysis grid, grey in `[0, 1]` (the
    /// mean of the pixels in the cell; `None` where the lens does not see), for the temporal
    /// cue ([`super::lens_motion`]).
    pub grey: Vec<Vec<Option<f32>>>,
    /// `[camera][j]`: inverse distance from the camera to the estimated point its own cell `j`
    /// sees (the mean over the directions that land there), 1/m; `None` where none lands.
    pub inv_range: Vec<Vec<Option<f32>>>,
}

/// One camera's share of a frame's [`LensVotes`], before voting.
struct CameraView {
    /// `[k]`: the camera's grey at direction `k`'s estimated point (`None` where its lens
    /// does not see it).
    warped: Vec<Option<f32>>,
    /// `[k]`: [`LensVotes::cells`] of the camera.
    cells: Vec<Option<u32>>,
    /// `[j]`: [`LensVotes::grey`] of the camera.
    grey: Vec<Option<f32>>,
    /// `[j]`: [`LensVotes::inv_range`] of the camera.
    inv_range: Vec<Option<f32>>,
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
    let mut own_grey = Vec::with_capacity(n);
    let mut inv_ranges = Vec::with_capacity(n);
    for (c, pano) in panoramas.iter().enumerate() {
        let view = camera_view(
            grid,
            &rig.cameras[c].name,
            pano,
            &pano_rig.cam_from_output(c),
            validity[c].as_ref(),
            &ranges,
        )?;
        own_grey.push(view.grey);
        inv_ranges.push(view.inv_range);
        warped.push(view.warped);
        cells.push(view.cells);
    }
    let mut votes: Vec<Vec<Option<bool>>> = (0..n)
        .map(|c| {
            (0..grid.len())
                .map(|k| odd_one_out(&warped, grid, c, k))
                .collect()
        })
        .collect();
    drop_double_odd_ones(&mut votes, grid.len());
    Ok(LensVotes {
        votes,
        cells,
        grey: own_grey,
        inv_range: inv_ranges,
    })
}

/// Two odd ones out at one direction: the depth there is likely wrong (a view sampled at
/// the wrong point disagrees too), so neither vote counts (`votes[camera][k]`, `k` below
/// `directions`).
fn drop_double_odd_ones(votes: &mut [Vec<Option<bool>>], directions: usize) {
    let n = votes.len();
    for k in 0..directions {
        if (0..n).filter(|&c| votes[c][k] == Some(true)).count() > 1 {
            for camera in votes.iter_mut() {
                if camera[k] == Some(true) {
                    camera[k] = None;
                }
            }
        }
    }
}

/// Camera `name`'s panorama `pano` against the estimated `ranges` of the analysis `grid`:
/// its grey at each direction's estimated point, where that lands on its own panorama, its
/// own grey and inverse range per cell. `sees` is the lens's validity on the panorama's
/// pixels (`None`: sees everywhere).
fn camera_view(
    grid: ErpGrid,
    name: &str,
    pano: &RgbImage,
    cam_from_output: &Isometry3<f64>,
    sees: Option<&Vec<f32>>,
    ranges: &[f32],
) -> Result<CameraView, EstimatorError> {
    let (w, h) = (pano.width() as usize, pano.height() as usize);
    let camera_grid = ErpGrid::new(w).map_err(|_| EstimatorError::BadImageSize {
        camera: name.to_string(),
        width: w as u32,
        height: h as u32,
    })?;
    let grey: Vec<f32> = pano
        .pixels()
        .map(|p| luma([f32::from(p[0]), f32::from(p[1]), f32::from(p[2])]) * INTENSITY_SCALE)
        .collect();
    let sampler = CameraSampler::new(grid, cam_from_output, camera_grid);
    let own_grey = grey_on_grid(grid, &grey, w, h, sees);
    let (warped, cells) = lens_samples(grid, &sampler, &grey, [w, h], sees, ranges);
    let inv_range = inverse_ranges_on_lens(grid, cam_from_output, &cells, ranges);
    Ok(CameraView {
        warped,
        cells,
        grey: own_grey,
        inv_range,
    })
}

/// For each direction `k` of `grid`: the camera's `grey` (a `size_px` = `[w, h]` panorama)
/// bilinearly sampled where `sampler` puts the estimated point `ranges[k]` away, and the cell
/// of the analysis grid holding that pixel; both `None` where `sees` says the lens does not
/// see the nearest pixel.
fn lens_samples(
    grid: ErpGrid,
    sampler: &CameraSampler,
    grey: &[f32],
    size_px: [usize; 2],
    sees: Option<&Vec<f32>>,
    ranges: &[f32],
) -> (Vec<Option<f32>>, Vec<Option<u32>>) {
    let [w, h] = size_px;
    (0..grid.len())
        .map(|k| {
            let [u, v] = sampler.pixel(k, ranges[k]);
            let (ui, vi) = (u.round() as i64, v.round() as i64);
            let ui = ui.rem_euclid(w as i64) as usize;
            let vi = vi.clamp(0, h as i64 - 1) as usize;
            let seen = sees.is_none_or(|valid| valid.get(vi * w + ui).is_some_and(|&x| x > 0.5));
            if !seen {
                return (None, None);
            }
            // The camera pixel's cell on the analysis grid of the camera's panorama.
            let cu = (ui * grid.width() / w).min(grid.width() - 1);
            let cv = (vi * grid.height() / h).min(grid.height() - 1);
            (
                Some(bilinear_wrapped(grey, w, h, u, v)),
                Some((cv * grid.width() + cu) as u32),
            )
        })
        .unzip()
}

/// Per cell of the camera's own panorama on `grid`: the mean inverse distance (1/m) from the
/// camera to the estimated points of the directions whose `lens_cells` land there, `None`
/// where none lands.
fn inverse_ranges_on_lens(
    grid: ErpGrid,
    cam_from_output: &Isometry3<f64>,
    lens_cells: &[Option<u32>],
    ranges: &[f32],
) -> Vec<Option<f32>> {
    let mut inv_sum = vec![(0.0f32, 0u32); grid.len()];
    for (k, cell) in lens_cells.iter().enumerate() {
        if let Some(j) = cell {
            let dir = grid.dir_from_pixel(PixelCoord {
                u: (k % grid.width()) as f64,
                v: (k / grid.width()) as f64,
            });
            let p = cam_from_output * nalgebra::Point3::from(dir * f64::from(ranges[k]));
            let e = &mut inv_sum[*j as usize];
            e.0 += 1.0 / p.coords.norm().max(1e-3) as f32;
            e.1 += 1;
        }
    }
    inv_sum
        .iter()
        .map(|&(sum, count)| (count > 0).then(|| sum / count as f32))
        .collect()
}

/// A `w x h` grey panorama on `grid`: the mean of the pixels in each cell (the nearest pixel
/// when the panorama is coarser), `None` where `valid` (on the panorama's pixels) says the lens
/// does not see the cell's centre.
fn grey_on_grid(
    grid: ErpGrid,
    grey: &[f32],
    w: usize,
    h: usize,
    valid: Option<&Vec<f32>>,
) -> Vec<Option<f32>> {
    let span = |i: usize, n: usize, cells: usize| {
        let lo = (i * n / cells).min(n - 1);
        (lo, ((i + 1) * n / cells).clamp(lo + 1, n))
    };
    (0..grid.len())
        .map(|k| {
            let (u, v) = (k % grid.width(), k / grid.width());
            let (u0, u1) = span(u, w, grid.width());
            let (v0, v1) = span(v, h, grid.height());
            let centre = ((v0 + v1) / 2) * w + (u0 + u1) / 2;
            if valid.is_some_and(|m| m.get(centre).is_none_or(|&x| x <= 0.5)) {
                return None;
            }
            let mut sum = 0.0;
            for row in grey[v0 * w..v1 * w].chunks_exact(w) {
                sum += row[u0..u1].iter().sum::<f32>();
            }
            Some(sum / ((u1 - u0) * (v1 - v0)) as f32)
        })
        .collect()
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

/// One camera's lens health over a window of frames ([`super::lens_window`]).
#[derive(Clone, Debug, PartialEq)]
pub struct LensHealth {
    /// Share of the camera's view found blocked, 0 to 1 (each part weighted by its share of the
    /// view: solid angle for an ERP camera, image pixels for a fisheye). Undecided parts count
    /// as clear ([`super::lens_window`]).
    pub blocked_fraction: f64,
    /// Share of the camera's view that was decided (how much the fraction rests on).
    pub decided_fraction: f64,
    /// Where the blocked part lies, e.g. "lower left" (`None` when nothing is blocked).
    pub region: Option<String>,
}

/// Where in a camera's own panorama a region's centre lies (`u`, `v` in `[0, 1]`): "upper",
/// "middle" or "lower", then the side ("front" along the camera's forward axis, the optical
/// axis of a fisheye; "left", "right", "back" at the seam).
pub(super) fn describe_region(u: f64, v: f64) -> String {
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
