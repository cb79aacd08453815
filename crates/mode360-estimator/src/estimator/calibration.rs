//! Calibration check and refinement: which small rotation of one camera makes the cameras
//! agree best at the estimated depth.
//!
//! On an ERP grid of the output frame ([`RotationCheckConfig::analysis_width`] wide), every
//! camera's grey panorama is sampled at the estimated 3-D point `X_k = rho_k dir_k` of each
//! direction `k` (as in [`super::lens_health`]). Camera `c` turned about its own centre by a
//! small rotation `Q(w) = exp([w]x)` (axis and angle `w` in the rig frame, so
//! `rig_from_cam' = (Q R_c, t_c)`) samples `X_k` elsewhere; its *agreement* with the other
//! cameras is
//!
//! ```text
//! A_c(w) = sum_f sum_{b != c} sum_k cos(lat_k) zncc_k(c_w, b) / sum of the same weights
//! ```
//!
//! with `zncc_k` the windowed ZNCC over `(2 WINDOW_RADIUS + 1)^2` cells, over the frames `f`
//! and the cells `k` where both views are seen and textured at `w = 0` (a fixed set, so that
//! scores at different `w` compare). The correction of camera `c` maximizes `A_c` within
//! [`RotationCheckConfig::max_correction_deg`], by a pattern search along the rig axes with
//! halving steps down to [`RotationCheckConfig::min_step_deg`], then a parabola per axis
//! through the last step. Far points need no depth at all (only rotation moves them), near
//! ones use the estimate; a camera that was knocked disagrees with the others, which keep
//! the estimate right where it matters.
//!
//! Cameras are corrected one at a time against the others; a two-camera rig only shows the
//! rotation between its cameras (both get the same correction, mirrored).

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use super::lens_health::ranges_on;
use super::lens_mask::LensMask;
use super::photometric::sampling::{bilinear_wrapped, CameraSampler};
use super::EstimatorError;
use crate::matching::zncc::box_mean;
use crate::matching::{luma, INTENSITY_SCALE};
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::panorama::{panorama_rig, RigRemap};
use mode360_core::geometry::{ErpGrid, PixelCoord, Rig};

/// Radius of the ZNCC window, analysis cells.
pub const WINDOW_RADIUS: usize = 2;
/// A window whose deviation (grey in `[0, 1]`) is at most this carries no texture to align.
pub const TEXTURELESS_SIGMA: f32 = 0.02;
/// Added to each window variance so that the ZNCC of flat windows stays finite.
const VARIANCE_FLOOR: f32 = 1e-6;
/// Relative depth error the cell weights allow for: a cell weighs `cos(lat) / (1 + s^2)`,
/// with `s` the shift in cells that this error of its range would cause for the camera
/// farthest from the output origin.
pub const DEPTH_ERROR_FRACTION: f32 = 0.1;
/// Most cameras a check handles (partners are a 32-bit mask per cell).
pub const MAX_CAMERAS: usize = 32;
/// Smallest agreement gain for which `refine_rotations` turns a camera: below it the change is
/// within what depth errors and occlusions move (clean cameras gain under 0.001).
pub const MIN_REFINE_GAIN: f64 = 0.0005;
/// Fewest textured cells (over all frames and partners) a camera needs for a correction.
pub const MIN_TEXTURED_CELLS: usize = 500;

/// How the check samples and searches.
#[derive(Clone, Debug, PartialEq)]
pub struct RotationCheckConfig {
    /// Width of the analysis grid (height half of it).
    pub analysis_width: usize,
    /// Largest correction searched, degrees (about every rig axis).
    pub max_correction_deg: f64,
    /// First step of the pattern search, degrees.
    pub initial_step_deg: f64,
    /// The search stops when its step falls below this, degrees.
    pub min_step_deg: f64,
}

impl RotationCheckConfig {
    /// `rig refine`: fine steps (a 256-wide grid recovers a 1 degree turn to about 0.02
    /// degrees with true depth).
    pub fn refine() -> Self {
        Self {
            analysis_width: 256,
            max_correction_deg: 5.0,
            initial_step_deg: 0.5,
            min_step_deg: 0.01,
        }
    }

    /// The node's drift check: a coarser grid and search, a fraction of a frame's inference.
    pub fn drift() -> Self {
        Self {
            analysis_width: 128,
            max_correction_deg: 3.0,
            initial_step_deg: 0.5,
            min_step_deg: 0.04,
        }
    }
}

/// The best small rotation of one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraCorrection {
    /// Index in rig order.
    pub camera: usize,
    pub name: String,
    /// `w` (radians, rig axes): the camera's rotation becomes `exp([w]x) R_c`.
    pub rotation_vector_rig: Vector3<f64>,
    /// `|w|`, degrees.
    pub angle_deg: f64,
    /// Agreement `A_c` before and after (mean ZNCC, at most 1).
    pub agreement_before: f64,
    pub agreement_after: f64,
    /// Textured cells the agreement was measured on.
    pub cells: usize,
}

impl CameraCorrection {
    /// `agreement_after - agreement_before`.
    pub fn gain(&self) -> f64 {
        self.agreement_after - self.agreement_before
    }

    /// The correction as a rotation in the rig frame.
    pub fn rotation_rig(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(self.rotation_vector_rig)
    }
}

/// One frame, prepared for the check: each camera's grey panorama and where it sees, and the
/// estimated range on the analysis grid.
#[derive(Clone, Debug)]
pub struct CheckFrame {
    grey: Vec<Panorama>,
    ranges_m: Vec<f32>,
    /// Per camera, the range estimated without it (empty: `ranges_m` for every camera).
    ranges_without_m: Vec<Vec<f32>>,
}

impl CheckFrame {
    /// Leaves out the blocked part of each camera's view (`masks` in rig order, `None` or
    /// missing where nothing is blocked): mud agrees with nothing at any turn, and where it
    /// covers a part seen by few cameras it pulls the best turn off.
    pub fn mask_lenses(&mut self, masks: &[Option<LensMask>]) {
        for (pano, mask) in self.grey.iter_mut().zip(masks) {
            let Some(mask) = mask else { continue };
            let blocked = mask.blocked_on(pano.grid);
            let valid = pano.valid.get_or_insert_with(|| vec![1.0; blocked.len()]);
            for (v, b) in valid.iter_mut().zip(blocked) {
                if b {
                    *v = 0.0;
                }
            }
        }
    }

    /// The range camera `c` is checked at: estimated without it where that was given.
    fn ranges_for(&self, c: usize) -> &[f32] {
        self.ranges_without_m.get(c).unwrap_or(&self.ranges_m)
    }
}

#[derive(Clone, Debug)]
struct Panorama {
    grid: ErpGrid,
    grey: Vec<f32>,
    /// Per panorama pixel, whether the camera sees it (`None`: everywhere).
    valid: Option<Vec<f32>>,
}

impl Panorama {
    /// Grey value at panorama pixel `[u, v]`, or `None` where the camera does not see.
    fn sample(&self, [u, v]: [f32; 2]) -> Option<f32> {
        let (w, h) = (self.grid.width(), self.grid.height());
        if let Some(valid) = &self.valid {
            let ui = (u.round() as i64).rem_euclid(w as i64) as usize;
            let vi = (v.round() as i64).clamp(0, h as i64 - 1) as usize;
            if valid[vi * w + ui] <= 0.5 {
                return None;
            }
        }
        Some(bilinear_wrapped(&self.grey, w, h, u, v))
    }
}

/// The check for one rig.
#[derive(Clone, Debug)]
pub struct RotationCheck {
    cfg: RotationCheckConfig,
    rig: Rig,
    /// The rig with every camera as a panorama of its own frame (what is sampled).
    pano_rig: Rig,
    grid: ErpGrid,
    /// `cos(lat)` per analysis row.
    row_weight: Vec<f32>,
    /// Largest distance of a camera from the output frame's origin, metres.
    max_offset_m: f32,
}

impl RotationCheck {
    pub fn new(rig: &Rig, cfg: RotationCheckConfig) -> Result<Self, EstimatorError> {
        let bad = |field: &str, problem: String| EstimatorError::BadConfig {
            field: field.to_string(),
            problem,
        };
        let grid = ErpGrid::new(cfg.analysis_width)?;
        if rig.cameras.len() > MAX_CAMERAS {
            return Err(bad(
                "cameras",
                format!(
                    "the calibration check handles at most {MAX_CAMERAS} cameras, the rig has {}",
                    rig.cameras.len()
                ),
            ));
        }
        if !(cfg.min_step_deg > 0.0
            && cfg.initial_step_deg >= cfg.min_step_deg
            && cfg.max_correction_deg >= cfg.initial_step_deg)
        {
            return Err(bad(
                "calibration check steps",
                format!(
                    "need 0 < min_step_deg ({}) <= initial_step_deg ({}) <= max_correction_deg ({})",
                    cfg.min_step_deg, cfg.initial_step_deg, cfg.max_correction_deg
                ),
            ));
        }
        let row_weight = (0..grid.height())
            .map(|v| {
                let ll = grid.lonlat_from_pixel(PixelCoord {
                    u: 0.0,
                    v: v as f64,
                });
                ll.lat_rad.cos() as f32
            })
            .collect();
        let max_offset_m = (0..rig.cameras.len())
            .map(|c| rig.cam_from_output(c).translation.vector.norm() as f32)
            .fold(0.0f32, f32::max);
        Ok(Self {
            cfg,
            rig: rig.clone(),
            pano_rig: panorama_rig(rig),
            grid,
            row_weight,
            max_offset_m,
        })
    }

    pub fn config(&self) -> &RotationCheckConfig {
        &self.cfg
    }

    /// Prepares one frame: `images` in rig order, `range_m` the estimated range of the output
    /// frame (any ERP width; NaN or infinite ranges count as the farthest estimate).
    pub fn frame(
        &self,
        images: &[RgbImage],
        range_m: &FloatImage,
    ) -> Result<CheckFrame, EstimatorError> {
        if images.len() != self.rig.cameras.len() {
            return Err(EstimatorError::ImageCount {
                got: images.len(),
                expected: self.rig.cameras.len(),
            });
        }
        let remap = RigRemap::new(&self.rig, self.grid);
        let panoramas =
            remap
                .panoramas(images)
                .map_err(|(camera, e)| EstimatorError::BadImage {
                    camera,
                    problem: e.to_string(),
                })?;
        let validity = remap.validity();
        let grey = panoramas
            .iter()
            .zip(validity)
            .zip(&self.rig.cameras)
            .map(|((pano, valid), cam)| {
                let (w, h) = (pano.width() as usize, pano.height() as usize);
                let grid = ErpGrid::new(w).map_err(|_| EstimatorError::BadImageSize {
                    camera: cam.name.clone(),
                    width: w as u32,
                    height: h as u32,
                })?;
                let grey = pano
                    .pixels()
                    .map(|p| {
                        luma([f32::from(p[0]), f32::from(p[1]), f32::from(p[2])]) * INTENSITY_SCALE
                    })
                    .collect();
                Ok(Panorama { grid, grey, valid })
            })
            .collect::<Result<Vec<_>, EstimatorError>>()?;
        Ok(CheckFrame {
            grey,
            ranges_m: ranges_on(self.grid, range_m),
            ranges_without_m: Vec::new(),
        })
    }

    /// [`Self::frame`] with, per camera, the range estimated from the other cameras only: a
    /// turned camera pulls a joint estimate towards agreeing with it (which hides part of its
    /// turn), an estimate without it cannot. `without_m` is in rig order, one per camera.
    pub fn frame_with_exclusions(
        &self,
        images: &[RgbImage],
        range_m: &FloatImage,
        without_m: &[FloatImage],
    ) -> Result<CheckFrame, EstimatorError> {
        if without_m.len() != self.rig.cameras.len() {
            return Err(EstimatorError::ImageCount {
                got: without_m.len(),
                expected: self.rig.cameras.len(),
            });
        }
        let mut frame = self.frame(images, range_m)?;
        frame.ranges_without_m = without_m.iter().map(|r| ranges_on(self.grid, r)).collect();
        Ok(frame)
    }

    /// The sampler of camera `camera` turned by `w` (rig axes) for panoramas on `pano_grid`.
    fn sampler(&self, camera: usize, w: &Vector3<f64>, pano_grid: ErpGrid) -> CameraSampler {
        let pano_cam = &self.pano_rig.cameras[camera];
        let turned = Isometry3::from_parts(
            pano_cam.rig_from_cam.translation,
            UnitQuaternion::from_scaled_axis(*w) * pano_cam.rig_from_cam.rotation,
        );
        let cam_from_output = turned.inverse() * self.pano_rig.rig_from_output;
        CameraSampler::new(self.grid, &cam_from_output, pano_grid)
    }

    /// Camera `camera`'s view of every analysis cell of each frame, turned by `w` (rig axes);
    /// the sampler is built once for all frames whose panoramas share a size.
    fn warp_frames(
        &self,
        frames: &[CheckFrame],
        camera: usize,
        at: usize,
        w: &Vector3<f64>,
    ) -> Vec<Vec<Option<f32>>> {
        let mut sampler: Option<(ErpGrid, CameraSampler)> = None;
        frames
            .iter()
            .map(|frame| {
                let pano = &frame.grey[camera];
                if sampler.as_ref().is_none_or(|(g, _)| *g != pano.grid) {
                    sampler = Some((pano.grid, self.sampler(camera, w, pano.grid)));
                }
                let s = sampler.as_ref().map(|(_, s)| s);
                let ranges = frame.ranges_for(at);
                (0..self.grid.len())
                    .map(|k| s.and_then(|s| pano.sample(s.pixel(k, ranges[k]))))
                    .collect()
            })
            .collect()
    }

    /// Agreement of camera `c` turned by `w` with the fixed views of the others on `cells`
    /// (per frame): per cell, the mean ZNCC over the better half of the partners that see it
    /// (so a partner that is itself turned or blocked does not pull `c`), weighted by
    /// `cos(lat)`.
    fn agreement(
        &self,
        frames: &[CheckFrame],
        fixed: &[Vec<Option<WindowStats>>],
        cells: &[Vec<ScoredCell>],
        c: usize,
        w: &Vector3<f64>,
    ) -> f64 {
        let (gw, gh) = (self.grid.width(), self.grid.height());
        let mut tmp = vec![0.0f32; self.grid.len()];
        let (mut sum, mut weight) = (0.0f64, 0.0f64);
        let mut values = Vec::new();
        for (f, view) in self.warp_frames(frames, c, c, w).iter().enumerate() {
            let a: Vec<f32> = view.iter().map(|x| x.unwrap_or(0.0)).collect();
            let stats_a = WindowStats::new(&a, gw, gh, &mut tmp);
            let used = cells[f].iter().fold(0u32, |m, cell| m | cell.partners);
            // Per partner, the window mean of the product with `a`.
            let mean_ab: Vec<Option<Vec<f32>>> = fixed[f]
                .iter()
                .enumerate()
                .map(|(b, partner)| {
                    let stats_b = partner.as_ref()?;
                    (used & (1 << b) != 0).then(|| {
                        let ab: Vec<f32> =
                            a.iter().zip(&stats_b.image).map(|(x, y)| x * y).collect();
                        let mut out = vec![0.0f32; ab.len()];
                        box_mean(&ab, gw, gh, WINDOW_RADIUS, &mut tmp, &mut out);
                        out
                    })
                })
                .collect();
            for cell in &cells[f] {
                let k = cell.k;
                values.clear();
                for (b, m) in mean_ab.iter().enumerate() {
                    let (Some(m), Some(stats_b)) = (m, &fixed[f][b]) else {
                        continue;
                    };
                    if cell.partners & (1 << b) == 0 {
                        continue;
                    }
                    let cov = m[k] - stats_a.mean[k] * stats_b.mean[k];
                    let denom = ((stats_a.variance[k] + VARIANCE_FLOOR)
                        * (stats_b.variance[k] + VARIANCE_FLOOR))
                        .sqrt();
                    values.push(cov / denom);
                }
                if values.is_empty() {
                    continue;
                }
                values.sort_by(|x, y| y.total_cmp(x));
                let best = values.len().div_ceil(2);
                let mean = values[..best].iter().sum::<f32>() / best as f32;
                sum += f64::from(cell.weight * mean);
                weight += f64::from(cell.weight);
            }
        }
        if weight > 0.0 {
            sum / weight
        } else {
            0.0
        }
    }

    /// Camera `c`'s correction `w` with its agreement before and after, measured on `cells`.
    fn correction(
        &self,
        c: usize,
        w: Vector3<f64>,
        before: f64,
        after: f64,
        cells: usize,
    ) -> CameraCorrection {
        CameraCorrection {
            camera: c,
            name: self.rig.cameras[c].name.clone(),
            rotation_vector_rig: w,
            angle_deg: w.norm().to_degrees(),
            agreement_before: before,
            agreement_after: after,
            cells,
        }
    }

    /// Every camera's unturned view of every frame and its window statistics, at the range
    /// camera `at` is checked at.
    fn prepare(&self, frames: &[CheckFrame], at: usize) -> Result<Prepared, EstimatorError> {
        if frames.is_empty() {
            return Err(EstimatorError::BadConfig {
                field: "frames".to_string(),
                problem: "the calibration check needs at least one frame".to_string(),
            });
        }
        let n = self.rig.cameras.len();
        let (gw, gh) = (self.grid.width(), self.grid.height());
        let zero = Vector3::zeros();
        // views[f][c], warped camera by camera.
        let by_camera: Vec<Vec<Vec<Option<f32>>>> = (0..n)
            .map(|c| self.warp_frames(frames, c, at, &zero))
            .collect();
        let views: Vec<Vec<Vec<Option<f32>>>> = (0..frames.len())
            .map(|f| {
                by_camera
                    .iter()
                    .map(|per_frame| per_frame[f].clone())
                    .collect()
            })
            .collect();
        let fixed = views
            .iter()
            .map(|per_cam| {
                let mut tmp = vec![0.0f32; self.grid.len()];
                per_cam
                    .iter()
                    .map(|v| {
                        let img: Vec<f32> = v.iter().map(|x| x.unwrap_or(0.0)).collect();
                        Some(WindowStats::new(&img, gw, gh, &mut tmp))
                    })
                    .collect()
            })
            .collect();
        Ok(Prepared { views, fixed })
    }

    /// Per frame, the cells where camera `c` sees and is textured, with the partners that see
    /// and are textured there too; fixed for a whole search.
    fn cells(&self, frames: &[CheckFrame], prepared: &Prepared, c: usize) -> Vec<Vec<ScoredCell>> {
        let gw = self.grid.width();
        let min_var = TEXTURELESS_SIGMA * TEXTURELESS_SIGMA;
        let cell_rad = std::f32::consts::TAU / gw as f32;
        prepared
            .views
            .iter()
            .zip(&prepared.fixed)
            .zip(frames)
            .map(|((views, fixed), frame)| {
                let ranges = frame.ranges_for(c);
                let Some(sa) = &fixed[c] else {
                    return Vec::new();
                };
                (0..self.grid.len())
                    .filter_map(|k| {
                        if views[c][k].is_none() || sa.variance[k] <= min_var {
                            return None;
                        }
                        let partners = (0..views.len())
                            .filter(|&b| {
                                b != c
                                    && views[b][k].is_some()
                                    && fixed[b].as_ref().is_some_and(|sb| sb.variance[k] > min_var)
                            })
                            .fold(0u32, |m, b| m | (1 << b));
                        // How far a depth error moves a sample, in cells: near cells, whose
                        // depth the estimate gets less right, weigh less than far ones,
                        // which only a rotation moves.
                        let shift = self.max_offset_m * DEPTH_ERROR_FRACTION
                            / ranges[k].max(f32::MIN_POSITIVE)
                            / cell_rad;
                        (partners != 0).then(|| ScoredCell {
                            k,
                            weight: self.row_weight[k / gw] / (1.0 + shift * shift),
                            partners,
                        })
                    })
                    .collect()
            })
            .collect()
    }

    /// Agreement `A_c(w)` of camera `c` turned by `w` (rig axes, radians) over `frames`.
    pub fn agreement_of(
        &self,
        frames: &[CheckFrame],
        c: usize,
        w: &Vector3<f64>,
    ) -> Result<f64, EstimatorError> {
        let prepared = self.prepare(frames, c)?;
        let cells = self.cells(frames, &prepared, c);
        Ok(self.agreement(frames, &prepared.fixed, &cells, c, w))
    }

    /// The best correction of every camera over `frames` (at least one).
    pub fn corrections(
        &self,
        frames: &[CheckFrame],
    ) -> Result<Vec<CameraCorrection>, EstimatorError> {
        let zero = Vector3::zeros();
        let exclusions = frames.iter().any(|f| !f.ranges_without_m.is_empty());
        let shared = if exclusions {
            None
        } else {
            Some(self.prepare(frames, 0)?)
        };
        let corrections = (0..self.rig.cameras.len())
            .into_par_iter()
            .map(|c| {
                let own;
                let prepared = match &shared {
                    Some(p) => p,
                    None => {
                        own = self.prepare(frames, c)?;
                        &own
                    }
                };
                let cells = self.cells(frames, prepared, c);
                let count = scored_pairs(&cells);
                let score =
                    |w: &Vector3<f64>| self.agreement(frames, &prepared.fixed, &cells, c, w);
                let before = score(&zero);
                let (w, after) = if count >= MIN_TEXTURED_CELLS {
                    pattern_search(&score, before, &self.cfg)
                } else {
                    (zero, before)
                };
                Ok(self.correction(c, w, before, after, count))
            })
            .collect::<Result<Vec<_>, EstimatorError>>()?;
        Ok(corrections)
    }
}

impl RotationCheck {
    /// A quick estimate of every camera's correction (the node's drift check): from `w = 0`,
    /// `iterations` diagonal Newton steps on the agreement, each from central differences of
    /// `step_deg` along the rig axes (7 evaluations a step; a step is clamped to 2 `step_deg`
    /// per axis, and where the agreement is not concave it moves uphill by `step_deg`). While
    /// a step still hits that clamp, more steps follow, until the correction could reach
    /// `max_correction_deg` (so a knock larger than `2 iterations step_deg` is not read short).
    pub fn quick_corrections(
        &self,
        frames: &[CheckFrame],
        iterations: usize,
        step_deg: f64,
    ) -> Result<Vec<CameraCorrection>, EstimatorError> {
        let prepared = self.prepare(frames, 0)?;
        let h = step_deg.to_radians();
        let max = self.cfg.max_correction_deg.to_radians();
        Ok((0..self.rig.cameras.len())
            .into_par_iter()
            .map(|c| {
                let cells = self.cells(frames, &prepared, c);
                let count = scored_pairs(&cells);
                let score =
                    |w: &Vector3<f64>| self.agreement(frames, &prepared.fixed, &cells, c, w);
                let mut w = Vector3::zeros();
                let before = score(&w);
                let mut at_w = before;
                if count >= MIN_TEXTURED_CELLS {
                    let most = iterations + (max / (2.0 * h)).ceil() as usize;
                    let mut clamped = true;
                    for i in 0..most {
                        if i >= iterations && !clamped {
                            break;
                        }
                        clamped = false;
                        let mut next = w;
                        for axis in 0..3 {
                            let (mut minus, mut plus) = (w, w);
                            minus[axis] -= h;
                            plus[axis] += h;
                            let (sm, sp) = (score(&minus), score(&plus));
                            let slope = (sp - sm) / (2.0 * h);
                            let curvature = (sp - 2.0 * at_w + sm) / (h * h);
                            next[axis] += if curvature < 0.0 {
                                let newton = -slope / curvature;
                                clamped |= newton.abs() > 2.0 * h;
                                newton.clamp(-2.0 * h, 2.0 * h)
                            } else {
                                h * slope.signum()
                            };
                        }
                        if next.norm() > max {
                            next *= max / next.norm();
                        }
                        let at_next = score(&next);
                        if at_next <= at_w {
                            break;
                        }
                        w = next;
                        at_w = at_next;
                    }
                }
                self.correction(c, w, before, at_w, count)
            })
            .collect())
    }
}

/// A cell a camera is scored on, with its `cos(lat)` weight and the partners (bit `b`) that
/// see it textured too.
struct ScoredCell {
    k: usize,
    weight: f32,
    partners: u32,
}

/// (cell, partner) pairs over all frames.
fn scored_pairs(cells: &[Vec<ScoredCell>]) -> usize {
    cells
        .iter()
        .flatten()
        .map(|c| c.partners.count_ones() as usize)
        .sum()
}

/// The unturned views of a check's frames: `views[f][c][k]`, and their window statistics.
struct Prepared {
    views: Vec<Vec<Vec<Option<f32>>>>,
    fixed: Vec<Vec<Option<WindowStats>>>,
}

/// Maximizes `score` from `w = 0` (where it is `at_zero`): moves along the rig axes by
/// `step` while that improves, halves the step otherwise; then one parabola per axis
/// through the last step. Returns the best `w` and its score.
fn pattern_search(
    score: &dyn Fn(&Vector3<f64>) -> f64,
    at_zero: f64,
    cfg: &RotationCheckConfig,
) -> (Vector3<f64>, f64) {
    let max = cfg.max_correction_deg.to_radians();
    let min_step = cfg.min_step_deg.to_radians();
    let mut best = Vector3::zeros();
    let mut best_score = at_zero;
    let mut step = cfg.initial_step_deg.to_radians();
    while step >= min_step {
        let mut moved = false;
        for axis in 0..3 {
            for sign in [-1.0, 1.0] {
                let mut candidate = best;
                candidate[axis] += sign * step;
                if candidate.norm() > max {
                    continue;
                }
                let s = score(&candidate);
                if s > best_score {
                    best = candidate;
                    best_score = s;
                    moved = true;
                }
            }
        }
        if !moved {
            step *= 0.5;
        }
    }
    // Sub-step refinement: the vertex of the parabola through -h, 0, +h along each axis.
    let h = 2.0 * step;
    let mut refined = best;
    for axis in 0..3 {
        let mut minus = best;
        minus[axis] -= h;
        let mut plus = best;
        plus[axis] += h;
        let (sm, sp) = (score(&minus), score(&plus));
        let curvature = sm - 2.0 * best_score + sp;
        if curvature < 0.0 {
            let offset = 0.5 * h * (sm - sp) / curvature;
            refined[axis] += offset.clamp(-h, h);
        }
    }
    let refined_score = score(&refined);
    if refined_score > best_score && refined.norm() <= max {
        (refined, refined_score)
    } else {
        (best, best_score)
    }
}

/// Windowed mean and variance of one view on the analysis grid.
#[derive(Clone, Debug)]
struct WindowStats {
    image: Vec<f32>,
    mean: Vec<f32>,
    variance: Vec<f32>,
}

impl WindowStats {
    fn new(image: &[f32], w: usize, h: usize, tmp: &mut [f32]) -> Self {
        let mut mean = vec![0.0; image.len()];
        box_mean(image, w, h, WINDOW_RADIUS, tmp, &mut mean);
        let sq: Vec<f32> = image.iter().map(|x| x * x).collect();
        let mut variance = vec![0.0; image.len()];
        box_mean(&sq, w, h, WINDOW_RADIUS, tmp, &mut variance);
        for (var, m) in variance.iter_mut().zip(&mean) {
            *var = (*var - m * m).max(0.0);
        }
        Self {
            image: image.to_vec(),
            mean,
            variance,
        }
    }
}

/// `rig` with each correction applied: camera `c`'s rotation becomes `Q_c R_c`.
pub fn apply_corrections(rig: &Rig, corrections: &[CameraCorrection]) -> Rig {
    let mut out = rig.clone();
    for corr in corrections {
        if let Some(cam) = out.cameras.get_mut(corr.camera) {
            cam.rig_from_cam = Isometry3::from_parts(
                cam.rig_from_cam.translation,
                corr.rotation_rig() * cam.rig_from_cam.rotation,
            );
        }
    }
    out
}

/// Corrects the rig's rotations camera by camera: each round finds every camera's best
/// correction against the others and applies the one that raises the agreement most, until
/// no correction is larger than the search's last step or gains [`MIN_REFINE_GAIN`]. The
/// reference camera is never turned: turning every camera alike changes little that the
/// images show, so the others are aligned to it (as a calibration tool anchors camera 0).
/// Returns the refined rig and each camera's total correction (rig axes).
pub fn refine_rotations(
    rig: &Rig,
    frames: &[CheckFrame],
    cfg: &RotationCheckConfig,
) -> Result<(Rig, Vec<CameraCorrection>), EstimatorError> {
    let n = rig.cameras.len();
    let mut current = rig.clone();
    let mut total: Vec<UnitQuaternion<f64>> = vec![UnitQuaternion::identity(); n];
    let mut last = Vec::new();
    for _round in 0..n {
        let check = RotationCheck::new(&current, cfg.clone())?;
        let corrections = check.corrections(frames)?;
        let best = corrections
            .iter()
            .filter(|c| c.camera != rig.reference)
            .max_by(|a, b| a.gain().total_cmp(&b.gain()))
            .cloned();
        last = corrections;
        let Some(best) = best else { break };
        if best.angle_deg < cfg.min_step_deg || best.gain() < MIN_REFINE_GAIN {
            break;
        }
        total[best.camera] = best.rotation_rig() * total[best.camera];
        current = apply_corrections(&current, std::slice::from_ref(&best));
    }
    let check = RotationCheck::new(rig, cfg.clone())?;
    let mut summary = Vec::with_capacity(n);
    for (c, q) in total.iter().enumerate() {
        let w = q.scaled_axis();
        let before = check.agreement_of(frames, c, &Vector3::zeros())?;
        let after_check = RotationCheck::new(&current, cfg.clone())?;
        let after = after_check.agreement_of(frames, c, &Vector3::zeros())?;
        let cells = last.iter().find(|x| x.camera == c).map_or(0, |x| x.cells);
        summary.push(CameraCorrection {
            camera: c,
            name: rig.cameras[c].name.clone(),
            rotation_vector_rig: w,
            angle_deg: w.norm().to_degrees(),
            agreement_before: before,
            agreement_after: after,
            cells,
        });
    }
    Ok((current, summary))
}
