//! Per-rig sweep sampling tables of an SSMODE configuration ([`SweepSampling`]), built once
//! per rig and resolution.

use std::sync::Arc;

use super::config::{SsmodeConfig, MIN_CAMERAS};
use super::readout::Readout;
use super::sphere_conv::SphereConvTable;
use super::ModelError;
use crate::model::ops::{view_scale, SampleTable};

use mode360_core::geometry::{BilinearTaps, ErpGrid, ErpSample, FarField, Rig, SweepGeometry};

/// Exponent `k` of the pair parallax weight `|dir x b_hat|^k` of the photometric cost channel.
pub const PARALLAX_EXPONENT: f32 = 1.0;

/// Sampling tables for one rig at one configuration's resolution, built once:
/// - one sweep table per camera: for every sphere `d` and cost-volume cell `(v, u)` (sample
///   index `(d H + v) W + u`, at [`SsmodeConfig::cost_width`]), the bilinear taps of
///   `erp_c(cam_from_output * (rho_d * dir(u, v)))` in that camera's matching features (at the
///   same resolution; a fisheye camera's features are those of its panorama, and its taps
///   are all zero where its lens does not see the point);
/// - the SphereNet kernel table of the stage-4 spherical convolution (quarter resolution);
/// - the far field of the readout at the output resolution ([`FarField`]).
#[derive(Clone, Debug)]
pub struct SweepSampling {
    geometry: SweepGeometry,
    /// Per sweep sample `1 / views seeing it` (0 below two views); `None` when every camera
    /// sees everything (360° cameras).
    view_scale: Option<Arc<[f32]>>,
    /// Per cell, the share of spheres two cameras see (built with `view_scale`).
    coverage: Option<Vec<f32>>,
    sweep_tables: Vec<SampleTable>,
    sphere_conv: SphereConvTable,
    /// Per camera pair `(a < b)` and cost cell, the parallax weight of the photometric cost
    /// channel; `None` when the config has none.
    pair_weights: Option<Vec<Vec<f32>>>,
    /// Per output pixel, the output hypotheses the rig cannot tell from the far plane at
    /// [`Readout::far_parallax_cells`]; `None` when that is 0.
    far_field: Option<Arc<FarField>>,
}

impl SweepSampling {
    /// Builds the tables for `rig` at `cfg`'s quarter resolution, with the default readout's
    /// far field ([`Readout::default`]).
    pub fn new(rig: &Rig, cfg: &SsmodeConfig) -> Result<Self, ModelError> {
        Self::with_readout(rig, cfg, &Readout::default())
    }

    /// [`Self::new`] with `readout`'s far field ([`Readout::far_parallax_cells`]).
    pub fn with_readout(
        rig: &Rig,
        cfg: &SsmodeConfig,
        readout: &Readout,
    ) -> Result<Self, ModelError> {
        cfg.validate()?;
        readout.validate()?;
        let cameras = rig.cameras.len();
        if cameras < MIN_CAMERAS {
            return Err(ModelError::TooFewCameras {
                got: cameras,
                min: MIN_CAMERAS,
            });
        }
        let grid = ErpGrid::new(cfg.cost_width())?;
        let trunk_grid = ErpGrid::new(cfg.feature_width())?;
        let geometry =
            SweepGeometry::new(rig, grid, vec![grid; cameras], cfg.sphere_hypotheses()?)?;
        let pixels = grid.len();
        let sweep_tables = (0..cameras)
            .map(|cam| SampleTable::from_erp(grid, geometry.camera_samples(cam)))
            .collect::<Vec<_>>();
        let view_scale = (!geometry.all_see_everything()).then(|| view_scale(&sweep_tables));
        let coverage = view_scale
            .as_ref()
            .map(|scale| coverage_of(scale, pixels, cfg.spheres));
        let pair_weights = cfg.photometric_cost.then(|| {
            let centres: Vec<_> = (0..cameras)
                .map(|cam| geometry.camera_centre_in_output_m(cam))
                .collect();
            crate::matching::pair_parallax_weights(grid, &centres, PARALLAX_EXPONENT)
        });
        let far_field = if readout.far_parallax_cells > 0.0 {
            let out = ErpGrid::new(cfg.width)?;
            let out_geometry =
                SweepGeometry::new(rig, out, vec![out; cameras], cfg.output_hypotheses()?)?;
            let max_shift_rad = readout.far_parallax_cells * cfg.cost_cell_rad();
            Some(Arc::new(FarField::new(&out_geometry, max_shift_rad)))
        } else {
            None
        };
        Ok(Self {
            view_scale,
            coverage,
            pair_weights,
            far_field,
            sweep_tables,
            sphere_conv: SphereConvTable::new(trunk_grid),
            geometry,
        })
    }

    /// These tables with the samples of each camera's `blocked` cells (row-major over the
    /// camera's panorama at the cost volume's resolution; `None`: nothing blocked) counted as
    /// not seen, as a fisheye's blind region is: a sample any of whose taps lands on a blocked
    /// cell gets zero weight, and the view scale and coverage count the views left.
    pub fn with_blocked(&self, blocked: &[Option<Vec<bool>>]) -> Self {
        let sweep_tables: Vec<SampleTable> = self
            .sweep_tables
            .iter()
            .enumerate()
            .map(
                |(cam, table)| match blocked.get(cam).and_then(Option::as_ref) {
                    None => table.clone(),
                    Some(cells) => mask_table(table, cells),
                },
            )
            .collect();
        let view_scale = view_scale(&sweep_tables);
        let spheres = self.geometry.hypotheses().count();
        let coverage = coverage_of(&view_scale, self.geometry.output().len(), spheres);
        Self {
            geometry: self.geometry.clone(),
            view_scale: Some(view_scale),
            coverage: Some(coverage),
            sweep_tables,
            sphere_conv: self.sphere_conv.clone(),
            pair_weights: self.pair_weights.clone(),
            far_field: self.far_field.clone(),
        }
    }

    /// The sweep geometry at the cost volume's resolution.
    pub fn geometry(&self) -> &SweepGeometry {
        &self.geometry
    }

    pub fn camera_count(&self) -> usize {
        self.sweep_tables.len()
    }

    /// Camera `cam`'s sweep table, `spheres * H * W` samples, sphere-major then row-major.
    pub fn sweep_table(&self, cam: usize) -> Option<&SampleTable> {
        self.sweep_tables.get(cam)
    }

    /// The SphereNet kernel table of the stage-4 spherical convolution.
    pub fn sphere_conv(&self) -> &SphereConvTable {
        &self.sphere_conv
    }

    /// Per sweep sample (sphere-major, row-major) `1 / views seeing it`, 0 where fewer than
    /// two cameras see it; `None` when every camera sees every sample.
    pub fn view_scale(&self) -> Option<&Arc<[f32]>> {
        self.view_scale.as_ref()
    }

    /// Per camera pair `(a < b)` and cost cell, the photometric cost channel's parallax weights;
    /// `None` when the config has no photometric cost channel.
    pub fn pair_weights(&self) -> Option<&[Vec<f32>]> {
        self.pair_weights.as_deref()
    }

    /// Per output pixel (row-major at the network's width), the output hypotheses counted
    /// from the far plane that the rig cannot tell from it; `None`: the far plane alone.
    pub fn far_counts(&self) -> Option<&[u16]> {
        self.far_field.as_deref().map(FarField::counts)
    }

    /// Per cost-volume cell (row-major): the fraction of spheres that at least two cameras
    /// see there; `None` when every camera sees everything (all 1).
    pub fn coverage(&self) -> Option<&[f32]> {
        self.coverage.as_deref()
    }
}

/// Per cell of `pixels`, the share of the `spheres` spheres whose sample at least two views see
/// (a non-zero view scale).
fn coverage_of(view_scale: &[f32], pixels: usize, spheres: usize) -> Vec<f32> {
    (0..pixels)
        .map(|k| {
            (0..spheres)
                .filter(|d| view_scale[d * pixels + k] > 0.0)
                .count() as f32
                / spheres.max(1) as f32
        })
        .collect()
}

/// `table` with every sample that has a tap of non-zero weight on a `blocked` pixel zeroed
/// (unseen), in the table's own storage.
fn mask_table(table: &SampleTable, blocked: &[bool]) -> SampleTable {
    let hits = |t: &BilinearTaps| {
        t.index
            .iter()
            .zip(&t.weight)
            .any(|(&p, &wt)| wt > 0.0 && blocked.get(p as usize).copied().unwrap_or(false))
    };
    if let Some((grid, samples)) = table.erp_samples() {
        let masked = samples
            .iter()
            .map(|&s| {
                if hits(&grid.taps_of(s)) {
                    ErpSample::UNSEEN
                } else {
                    s
                }
            })
            .collect();
        return SampleTable::from_erp(grid, masked);
    }
    let taps: Vec<BilinearTaps> = table
        .iter()
        .map(|t| if hits(&t) { BilinearTaps::UNSEEN } else { t })
        .collect();
    SampleTable::new(&taps)
}
