//! The lens check's temporal cue: a blocker is fixed on the lens while the scene behind it
//! moves.
//!
//! Over the window's frames, each camera's own panorama on the analysis grid
//! ([`super::lens_health::LensVotes::grey`]) gives per cell `j` its *change*, the median over
//! consecutive frames of the grey difference:
//!
//! ```text
//! change_c(j) = median_t |g_c,t(j) - g_c,t-1(j)|
//! ```
//!
//! Where the lens sees the scene, the cell changes as the rig moves (or the scene does); mud,
//! a mount or a vehicle part paints the same bytes in every frame. A still cell is not enough
//! (the sky, a bare wall or a parked rig are still too), so the cell is compared with what the
//! other cameras see along its ray near the estimated depth: the other cameras' cells that the
//! ray's points land on ([`LensGeometry`], built once per rig) between the estimated inverse
//! range `s` (the median over the frames, [`super::lens_health::LensVotes::inv_range`])
//! divided and multiplied by [`RANGE_BRACKET`]. When the scene there typically changes, a
//! still cell is blocked:
//!
//! ```text
//! clear(j)    = change_c(j) >= CHANGE_MIN
//! blocked(j)  = change_c(j) <= STILL_MAX
//!               and median over (d, j') on the ray, s/RANGE_BRACKET <= 1/r <= s RANGE_BRACKET + FAR_INV_RANGE,
//!                   of change_d(j') >= CHANGE_MIN
//! ```
//!
//! and undecided otherwise. Unlike the odd-one-out vote, one other camera is enough: the
//! estimated depth only brackets the ray (a blocked region's depth is often off, and the
//! bracket and the median over many cells absorb that). It needs motion: on a parked rig
//! nothing changes and the odd-one-out vote decides alone.

use super::lens_health::LensVotes;
use mode360_core::geometry::panorama::{panorama_rig, rig_panoramas};
use mode360_core::geometry::{ErpGrid, PixelCoord, Projection, Rig};
use mode360_estimator::lens_mask::analysis_grid;
use nalgebra::Vector3;
use rayon::prelude::*;

/// A cell whose grey (in `[0, 1]`) changes by at most this from frame to frame is still.
pub const STILL_MAX: f32 = 0.01;
/// A cell whose grey changes by at least this from frame to frame sees a moving scene.
pub const CHANGE_MIN: f32 = 0.03;
/// Frame pairs a cell needs for its change (three frames).
pub const MIN_MOTION_PAIRS: usize = 2;
/// Nearest point along a ray that the tables reach, metres.
pub const MIN_RANGE_M: f64 = 0.3;
/// The ray is asked about between the estimated inverse range divided and multiplied by this.
pub const RANGE_BRACKET: f32 = 1.5;
/// ... widened by this inverse range (1/m) towards the near side, so that a far estimate still
/// asks about a stretch of the ray.
pub const FAR_INV_RANGE: f32 = 0.02;
/// Largest step along a ray, in analysis cells of the other camera's panorama.
const STEP_CELLS: f64 = 0.5;

/// Per rig: each camera's cell weights and, per cell, the other cameras' cells along its ray.
#[derive(Clone, Debug)]
pub struct LensGeometry {
    rig: Rig,
    /// `[camera][j]`: weight of the camera's own cell `j` in its view: solid angle (`cos(lat)`)
    /// for an ERP camera, the number of image pixels that look into the cell for a fisheye
    /// (the share of the image a blocker covers, as the renderer counts it); 0 where unseen.
    weights: Vec<Vec<f64>>,
    /// `[camera]`: start of cell `j`'s ray list in `ray_cells[camera]` (`len + 1` entries).
    ray_offsets: Vec<Vec<u32>>,
    /// `[camera]`: the ray lists: per other camera, the cells in order of inverse range.
    ray_cells: Vec<Vec<RaySample>>,
}

impl LensGeometry {
    /// The tables of `rig` (about a second on this 2-core machine, once per rig).
    pub fn new(rig: &Rig) -> Self {
        let grid = analysis_grid();
        let pano_rig = panorama_rig(rig);
        let panoramas = rig_panoramas(rig);
        let n = rig.cameras.len();
        let sees: Vec<Vec<bool>> = panoramas
            .iter()
            .map(|p| {
                (0..grid.len())
                    .map(|k| p.sees(&grid.dir_from_pixel(grid.pixel_of_index(k))))
                    .collect()
            })
            .collect();
        let weights = rig
            .cameras
            .iter()
            .zip(&sees)
            .map(|(cam, sees)| cell_weights(grid, &cam.projection, sees))
            .collect();
        let mut ray_offsets = Vec::with_capacity(n);
        let mut ray_cells = Vec::with_capacity(n);
        for c in 0..n {
            let rig_from_c = pano_rig.cameras[c].rig_from_cam;
            let per_cell: Vec<Vec<RaySample>> = (0..grid.len())
                .into_par_iter()
                .map(|k| {
                    let mut cells = Vec::new();
                    if !sees[c][k] {
                        return cells;
                    }
                    let dir_rig = rig_from_c.rotation * grid.dir_from_pixel(grid.pixel_of_index(k));
                    for d in (0..n).filter(|&d| d != c) {
                        let d_from_rig = pano_rig.cameras[d].rig_from_cam.inverse();
                        // q(s) = s a + b: the ray's point at range 1/s, in d's panorama frame
                        // and scaled by s.
                        let a = d_from_rig.transform_vector(
                            &(rig_from_c.translation.vector
                                - pano_rig.cameras[d].rig_from_cam.translation.vector),
                        );
                        let b = d_from_rig.transform_vector(&dir_rig);
                        let mut last = None;
                        ray_cells_of(grid, &a, &b, &sees[d], |s_inv, j| {
                            let packed = (d * grid.len() + j) as u32;
                            if last != Some(packed) {
                                cells.push(RaySample {
                                    inv_range: s_inv as f32,
                                    cell: packed,
                                });
                                last = Some(packed);
                            }
                        });
                    }
                    cells
                })
                .collect();
            let mut offsets = Vec::with_capacity(grid.len() + 1);
            offsets.push(0);
            let mut cells = Vec::with_capacity(per_cell.iter().map(Vec::len).sum());
            for list in per_cell {
                cells.extend(list);
                offsets.push(cells.len() as u32);
            }
            ray_offsets.push(offsets);
            ray_cells.push(cells);
        }
        Self {
            rig: rig.clone(),
            weights,
            ray_offsets,
            ray_cells,
        }
    }

    /// Whether these tables were built for `rig`.
    pub fn serves(&self, rig: &Rig) -> bool {
        &self.rig == rig
    }

    /// `[camera][j]`: the weight of each own cell in the camera's view (see the field docs).
    pub fn weights(&self) -> &[Vec<f64>] {
        &self.weights
    }

    /// The other cameras' cells along camera `c`'s ray through its cell `j` that points with
    /// inverse range in `[lo, hi]` land on, as `(d, j')`.
    fn ray(
        &self,
        c: usize,
        j: usize,
        lo: f32,
        hi: f32,
    ) -> impl Iterator<Item = (usize, usize)> + '_ {
        let cells = analysis_grid().len();
        let list = &self.ray_cells[c]
            [self.ray_offsets[c][j] as usize..self.ray_offsets[c][j + 1] as usize];
        list.iter().enumerate().filter_map(move |(i, sample)| {
            // A cell covers the inverse ranges from its entry to the next sample of the same
            // camera (or beyond, for the last).
            let end = list
                .get(i + 1)
                .filter(|next| next.cell / cells as u32 == sample.cell / cells as u32)
                .map_or(f32::INFINITY, |next| next.inv_range);
            (sample.inv_range <= hi && end >= lo)
                .then_some((sample.cell as usize / cells, sample.cell as usize % cells))
        })
    }
}

/// Where a ray's points from `inv_range` on land in another camera's panorama.
#[derive(Clone, Copy, Debug)]
struct RaySample {
    /// Inverse range along the ray where the cell is first entered, 1/m.
    inv_range: f32,
    /// The other camera `d` and its cell `j'`, packed as `d * cells + j'`.
    cell: u32,
}

/// Calls `push` with every cell (seen by the other camera) of the curve `q(s) = s a + b`,
/// `s` from 0 (the direction at infinity) to `1 / MIN_RANGE_M`, stepping so that the direction
/// moves by at most [`STEP_CELLS`] cells.
fn ray_cells_of(
    grid: ErpGrid,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    sees: &[bool],
    mut push: impl FnMut(f64, usize),
) {
    let cell_rad = std::f64::consts::TAU / grid.width() as f64;
    let s_max = 1.0 / MIN_RANGE_M;
    let a_norm = a.norm();
    let mut s = 0.0;
    loop {
        let q = a * s + b;
        if q.norm() > 1e-9 {
            let j = grid.index_from_dir(&q);
            if sees[j] {
                push(s, j);
            }
        }
        if s >= s_max || a_norm < 1e-9 {
            break;
        }
        // |d(q/|q|)/ds| <= |a| / |q|.
        s = (s + STEP_CELLS * cell_rad * q.norm().max(1e-3) / a_norm).min(s_max);
    }
}

/// Weights of a camera's own cells (see [`LensGeometry::weights`]).
fn cell_weights(grid: ErpGrid, projection: &Projection, sees: &[bool]) -> Vec<f64> {
    let Some(model) = projection.fisheye_model() else {
        return (0..grid.len())
            .map(|k| grid.lonlat_from_pixel(grid.pixel_of_index(k)).lat_rad.cos())
            .collect();
    };
    let panorama_from_cam = mode360_core::geometry::panorama::cam_from_panorama(projection)
        .rotation
        .inverse();
    let size = model.image_size();
    (0..size.height)
        .into_par_iter()
        .fold(
            || vec![0.0; grid.len()],
            |mut weights, v| {
                for u in 0..size.width {
                    let px = PixelCoord {
                        u: f64::from(u),
                        v: f64::from(v),
                    };
                    if let Some(ray) = model.unproject(px) {
                        let j = grid.index_from_dir(&(panorama_from_cam * ray.into_inner()));
                        if sees[j] {
                            weights[j] += 1.0;
                        }
                    }
                }
                weights
            },
        )
        .reduce(
            || vec![0.0; grid.len()],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += y;
                }
                a
            },
        )
}

/// Per camera and own cell over `frames` (oldest first), given their `change`
/// ([`cell_changes`]): `Some(true)` still while the scene along its ray moves (blocked),
/// `Some(false)` it sees change (clear), `None` undecided (see the module docs). Empty when the
/// frames do not fit `geometry`'s cameras.
pub fn motion_votes(
    geometry: &LensGeometry,
    frames: &[&LensVotes],
    change: &[Vec<Option<f32>>],
) -> Vec<Vec<Option<bool>>> {
    let n = geometry.weights.len();
    if change.len() != n || frames.iter().any(|f| f.grey.len() != n) {
        return Vec::new();
    }
    let cells = analysis_grid().len();
    (0..n)
        .map(|c| {
            (0..cells)
                .into_par_iter()
                .map(|j| {
                    let own = change[c][j]?;
                    if own >= CHANGE_MIN {
                        return Some(false);
                    }
                    if own > STILL_MAX {
                        return None;
                    }
                    let est = inverse_range(frames, c, j)?;
                    let (lo, hi) = (est / RANGE_BRACKET, est * RANGE_BRACKET + FAR_INV_RANGE);
                    let mut along: Vec<f32> = geometry
                        .ray(c, j, lo, hi)
                        .filter_map(|(d, k)| change[d][k])
                        .collect();
                    if along.is_empty() {
                        return None;
                    }
                    along.sort_unstable_by(f32::total_cmp);
                    let typical = along[along.len() / 2];
                    (typical >= CHANGE_MIN).then_some(true)
                })
                .collect()
        })
        .collect()
}

/// `[camera][j]`: each own cell's change over `frames` (see the module docs).
pub fn cell_changes(frames: &[&LensVotes]) -> Vec<Vec<Option<f32>>> {
    let n = frames.first().map_or(0, |f| f.grey.len());
    (0..n)
        .map(|c| {
            (0..analysis_grid().len())
                .into_par_iter()
                .map(|j| cell_change(frames, c, j))
                .collect()
        })
        .collect()
}

/// Median over the frames of the estimated inverse range of camera `c`'s cell `j`.
fn inverse_range(frames: &[&LensVotes], c: usize, j: usize) -> Option<f32> {
    let mut values: Vec<f32> = frames
        .iter()
        .filter_map(|f| f.inv_range.get(c)?.get(j).copied()?)
        .collect();
    if values.is_empty() {
        return None;
    }
    values.sort_unstable_by(f32::total_cmp);
    Some(values[values.len() / 2])
}

/// Median frame-to-frame change of camera `c`'s cell `j` (`None` with fewer than
/// [`MIN_MOTION_PAIRS`] pairs that both see it).
fn cell_change(frames: &[&LensVotes], c: usize, j: usize) -> Option<f32> {
    let mut diffs: Vec<f32> = frames
        .windows(2)
        .filter_map(|w| {
            Some((w[1].grey[c].get(j).copied()?? - w[0].grey[c].get(j).copied()??).abs())
        })
        .collect();
    if diffs.len() < MIN_MOTION_PAIRS {
        return None;
    }
    diffs.sort_unstable_by(f32::total_cmp);
    Some(diffs[diffs.len() / 2])
}
