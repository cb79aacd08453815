//! [`RotationCheck`]: the agreement of one camera, turned by a small rotation, with the others
//! at the estimated depth, and the textured cells it is measured on.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};

use super::frame::CheckFrame;
use super::{
    CameraCorrection, RotationCheckConfig, DEPTH_ERROR_FRACTION, MAX_CAMERAS, TEXTURELESS_SIGMA,
    WINDOW_RADIUS,
};
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::panorama::panorama_rig;
use mode360_core::geometry::{ErpGrid, PixelCoord, Rig};
use mode360_estimator::photometric::sampling::CameraSampler;
use mode360_estimator::EstimatorError;
use mode360_model::matching::zncc::{box_mean, ViewStats};

/// Added to each window variance so that the ZNCC of flat windows stays finite.
const VARIANCE_FLOOR: f32 = 1e-6;

/// The check for one rig.
#[derive(Clone, Debug)]
pub struct RotationCheck {
    pub(super) cfg: RotationCheckConfig,
    pub(super) rig: Rig,
    /// The rig with every camera as a panorama of its own frame (what is sampled).
    pano_rig: Rig,
    pub(super) grid: ErpGrid,
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
        CheckFrame::new(&self.rig, self.grid, images, range_m)
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
        let mut frame = self.frame(images, range_m)?;
        frame.set_ranges_without(self.grid, without_m)?;
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
    pub(super) fn agreement(
        &self,
        frames: &[CheckFrame],
        fixed: &[Vec<Option<ViewStats>>],
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
            let stats_a = ViewStats::new(a, gw, gh, WINDOW_RADIUS, &mut tmp);
            let used = cells[f].iter().fold(0u32, |m, cell| m | cell.partners);
            // Per partner, the window mean of the product with `a`.
            let mean_ab: Vec<Option<Vec<f32>>> = fixed[f]
                .iter()
                .enumerate()
                .map(|(b, partner)| {
                    let stats_b = partner.as_ref()?;
                    (used & (1 << b) != 0).then(|| {
                        let ab: Vec<f32> = stats_a
                            .image
                            .iter()
                            .zip(&stats_b.image)
                            .map(|(x, y)| x * y)
                            .collect();
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
    pub(super) fn correction(
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
    pub(super) fn prepare(
        &self,
        frames: &[CheckFrame],
        at: usize,
    ) -> Result<Prepared, EstimatorError> {
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
                        Some(ViewStats::new(img, gw, gh, WINDOW_RADIUS, &mut tmp))
                    })
                    .collect()
            })
            .collect();
        Ok(Prepared { views, fixed })
    }

    /// Per frame, the cells where camera `c` sees and is textured, with the partners that see
    /// and are textured there too; fixed for a whole search.
    pub(super) fn cells(
        &self,
        frames: &[CheckFrame],
        prepared: &Prepared,
        c: usize,
    ) -> Vec<Vec<ScoredCell>> {
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
}

/// A cell a camera is scored on, with its `cos(lat)` weight and the partners (bit `b`) that
/// see it textured too.
pub(super) struct ScoredCell {
    k: usize,
    weight: f32,
    partners: u32,
}

/// (cell, partner) pairs over all frames.
pub(super) fn scored_pairs(cells: &[Vec<ScoredCell>]) -> usize {
    cells
        .iter()
        .flatten()
        .map(|c| c.partners.count_ones() as usize)
        .sum()
}

/// The unturned views of a check's frames: `views[f][c][k]`, and their window statistics.
pub(super) struct Prepared {
    views: Vec<Vec<Vec<Option<f32>>>>,
    pub(super) fixed: Vec<Vec<Option<ViewStats>>>,
}
