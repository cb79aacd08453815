//! Spherical sweeping: inverse-depth hypotheses and exact per-sphere sampling tables.
//!
//! For output pixel `(u, v)` with unit ray `dir(u, v)` in the output frame and sphere `i` of
//! range `rho_i`, camera `c` samples its ERP image at
//!
//! ```text
//! pixel_c = erp_c( cam_from_output * (rho_i * dir(u, v)) )
//! ```
//!
//! which is exact for every sphere, including spheres nearer than the baseline. A fisheye
//! camera `c` is swept through its panorama (see [`super::panorama`]): `cam_from_output` is then
//! `panorama_from_output`, and [`SweepGeometry::sees`] tells whether its lens sees the point.

use super::erp::{BilinearTaps, ErpGrid, ErpSample, PixelCoord};
use super::panorama::{rig_panoramas, CameraPanorama};
use super::rig::Rig;
use super::GeometryError;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// The paper's sweep range and count.
pub const PAPER_MIN_DEPTH_M: f64 = 0.5;
pub const PAPER_MAX_DEPTH_M: f64 = super::DEFAULT_MAX_DEPTH_M;
pub const PAPER_HYPOTHESES: usize = 192;
/// At least two hypotheses are needed to define a step.
pub const MIN_HYPOTHESES: usize = 2;
/// Rotation angle (rad) and translation (m) below which a camera's pose is the output frame's.
const IDENTITY_TOLERANCE: f64 = 1e-9;

/// A range of depths (metres).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DepthRange {
    pub min_depth_m: f64,
    pub max_depth_m: f64,
}

impl DepthRange {
    pub fn new(min_depth_m: f64, max_depth_m: f64) -> Result<Self, GeometryError> {
        if !(min_depth_m > 0.0 && max_depth_m > min_depth_m && max_depth_m.is_finite()) {
            return Err(GeometryError::BadDepthRange {
                min_m: min_depth_m,
                max_m: max_depth_m,
            });
        }
        Ok(Self {
            min_depth_m,
            max_depth_m,
        })
    }

    /// The paper's 0.5 m to 1000 m.
    pub fn paper() -> Self {
        Self {
            min_depth_m: PAPER_MIN_DEPTH_M,
            max_depth_m: PAPER_MAX_DEPTH_M,
        }
    }
}

/// How depth hypotheses are spread between the nearest and the farthest.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum HypothesisSpacing {
    /// Uniform in inverse depth (the paper): equal parallax steps, so most hypotheses are
    /// near (over 0.5 to 1000 m with 96 of them, 86 are nearer than 5 m).
    #[default]
    InverseDepth,
    /// Uniform in log depth: equal relative steps (`(max/min)^(1/(n-1))`, 8.3 % over 0.5 to
    /// 1000 m with 96), so every range gets the same relative resolution, as δ1 scores it.
    LogDepth,
}

/// Depth hypotheses; index 0 is the farthest (`max_depth`), index `n - 1` the nearest
/// (`min_depth`), with the normalized index `k = i / (n - 1)`:
/// - [`HypothesisSpacing::InverseDepth`]: `1/rho = 1/max + k (1/min - 1/max)`;
/// - [`HypothesisSpacing::LogDepth`]: `ln rho = ln max + k (ln min - ln max)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthHypotheses {
    range: DepthRange,
    count: usize,
    spacing: HypothesisSpacing,
}

impl DepthHypotheses {
    /// `count` hypotheses uniform in inverse depth.
    pub fn new(range: DepthRange, count: usize) -> Result<Self, GeometryError> {
        Self::with_spacing(range, count, HypothesisSpacing::InverseDepth)
    }

    pub fn with_spacing(
        range: DepthRange,
        count: usize,
        spacing: HypothesisSpacing,
    ) -> Result<Self, GeometryError> {
        if count < MIN_HYPOTHESES {
            return Err(GeometryError::TooFewHypotheses {
                count,
                min: MIN_HYPOTHESES,
            });
        }
        Ok(Self {
            range,
            count,
            spacing,
        })
    }

    pub fn count(&self) -> usize {
        self.count
    }

    pub fn range(&self) -> DepthRange {
        self.range
    }

    pub fn spacing(&self) -> HypothesisSpacing {
        self.spacing
    }

    /// Depth (m) at normalized index `k` (0 the farthest, 1 the nearest; any real `k`).
    pub fn depth_at_normalized(&self, k: f64) -> f64 {
        let (min, max) = (self.range.min_depth_m, self.range.max_depth_m);
        match self.spacing {
            HypothesisSpacing::InverseDepth => 1.0 / (1.0 / max + k * (1.0 / min - 1.0 / max)),
            HypothesisSpacing::LogDepth => (max.ln() + k * (min.ln() - max.ln())).exp(),
        }
    }

    /// Normalized index of a depth (inverse of [`Self::depth_at_normalized`]), unclamped.
    pub fn normalized_of_depth(&self, depth_m: f64) -> f64 {
        let (min, max) = (self.range.min_depth_m, self.range.max_depth_m);
        match self.spacing {
            HypothesisSpacing::InverseDepth => {
                (1.0 / depth_m - 1.0 / max) / (1.0 / min - 1.0 / max)
            }
            HypothesisSpacing::LogDepth => (max.ln() - depth_m.ln()) / (max.ln() - min.ln()),
        }
    }

    /// Inverse depth (1/m) of hypothesis `i`; `i` may be fractional.
    pub fn inverse_depth(&self, i: f64) -> f64 {
        1.0 / self.depth_m(i)
    }

    /// Depth (m) of hypothesis `i`; `i` may be fractional.
    pub fn depth_m(&self, i: f64) -> f64 {
        self.depth_at_normalized(i / (self.count - 1) as f64)
    }

    /// Fractional hypothesis index of a depth (inverse of [`Self::depth_m`]).
    pub fn index_of_depth(&self, depth_m: f64) -> f64 {
        self.normalized_of_depth(depth_m) * (self.count - 1) as f64
    }

    /// All depths, farthest first.
    pub fn depths_m(&self) -> Vec<f64> {
        (0..self.count).map(|i| self.depth_m(i as f64)).collect()
    }
}

/// Everything needed to sample a rig's cameras on sweep spheres around the output frame.
///
/// Each camera is swept as its panorama ([`CameraPanorama`]): an ERP camera directly, a fisheye
/// through its image resampled into an ERP panorama of its panorama frame
/// ([`super::panorama::PanoramaRemap`]). [`Self::sees`] says whether the camera's model sees a
/// sample at all; a sweep aggregates only the cameras that do.
#[derive(Clone, Debug)]
pub struct SweepGeometry {
    output: ErpGrid,
    hypotheses: DepthHypotheses,
    /// `panorama_from_output` of every camera.
    cam_from_output: Vec<Isometry3<f64>>,
    camera_grids: Vec<ErpGrid>,
    panoramas: Vec<CameraPanorama>,
}

impl SweepGeometry {
    /// Sweep for `rig` with an output ERP grid and per-camera panorama grids (same order as
    /// `rig.cameras`).
    pub fn new(
        rig: &Rig,
        output: ErpGrid,
        camera_grids: Vec<ErpGrid>,
        hypotheses: DepthHypotheses,
    ) -> Result<Self, GeometryError> {
        if camera_grids.len() != rig.cameras.len() {
            return Err(GeometryError::NoSuchCamera {
                index: camera_grids.len(),
                count: rig.cameras.len(),
            });
        }
        let panoramas = rig_panoramas(rig);
        Ok(Self {
            output,
            hypotheses,
            cam_from_output: panoramas
                .iter()
                .map(|p| p.rig_from_panorama.inverse() * rig.rig_from_output)
                .collect(),
            camera_grids,
            panoramas,
        })
    }

    /// Whether every camera sees every direction (all ERP): no visibility to track.
    pub fn all_see_everything(&self) -> bool {
        self.panoramas.iter().all(|p| !p.needs_remap())
    }

    /// Whether camera `cam` sees the point of output pixel `p` on a sphere of `range_m`.
    pub fn sees_at_range(&self, cam: usize, p: PixelCoord, range_m: f64) -> bool {
        let point_out = Point3::from(self.output.dir_from_pixel(p) * range_m);
        self.panoramas[cam].sees(&(self.cam_from_output[cam] * point_out).coords)
    }

    /// Whether camera `cam` sees output pixel `p` on sphere `sphere`.
    pub fn sees(&self, cam: usize, sphere: usize, p: PixelCoord) -> bool {
        self.sees_at_range(cam, p, self.hypotheses.depth_m(sphere as f64))
    }

    pub fn output(&self) -> ErpGrid {
        self.output
    }

    /// Whether camera `cam`'s panorama is the output frame on the output grid (the reference
    /// camera of most rigs): its samples are the output pixels on every sphere.
    pub fn is_output_camera(&self, cam: usize) -> bool {
        let pose = self.cam_from_output[cam];
        self.camera_grids[cam] == self.output
            && pose.translation.vector.norm() < IDENTITY_TOLERANCE
            && pose.rotation.angle() < IDENTITY_TOLERANCE
    }

    /// Camera `cam`'s panorama centre in the output frame, metres: `output_from_cam * 0`.
    pub fn camera_centre_in_output_m(&self, cam: usize) -> nalgebra::Vector3<f64> {
        self.cam_from_output[cam].inverse().translation.vector
    }

    pub fn hypotheses(&self) -> &DepthHypotheses {
        &self.hypotheses
    }

    pub fn camera_count(&self) -> usize {
        self.cam_from_output.len()
    }

    pub fn camera_grid(&self, cam: usize) -> ErpGrid {
        self.camera_grids[cam]
    }

    /// The point of output pixel `p` on a sphere of `range_m` in camera `cam`'s panorama
    /// frame, metres: `cam_from_output * (range_m * dir(p))`.
    pub fn point_in_camera_m(&self, cam: usize, p: PixelCoord, range_m: f64) -> Vector3<f64> {
        let point_out = Point3::from(self.output.dir_from_pixel(p) * range_m);
        (self.cam_from_output[cam] * point_out).coords
    }

    /// Whether camera `cam`'s lens sees `point` given in its panorama frame
    /// ([`Self::point_in_camera_m`]).
    pub fn sees_point(&self, cam: usize, point: &Vector3<f64>) -> bool {
        self.panoramas[cam].sees(point)
    }

    /// Where camera `cam` sees the point of output pixel `p` on a sphere of `range_m`.
    pub fn sample_at_range(&self, cam: usize, p: PixelCoord, range_m: f64) -> PixelCoord {
        let point_out = Point3::from(self.output.dir_from_pixel(p) * range_m);
        let point_cam = self.cam_from_output[cam] * point_out;
        self.camera_grids[cam].pixel_from_dir(&point_cam.coords)
    }

    /// Where camera `cam` sees output pixel `p` on sphere `sphere`.
    pub fn sample(&self, cam: usize, sphere: usize, p: PixelCoord) -> PixelCoord {
        self.sample_at_range(cam, p, self.hypotheses.depth_m(sphere as f64))
    }

    /// Bilinear taps of camera `cam` for every sphere and output pixel, sphere-major then
    /// row-major (sample index `(sphere H + v) W + u`); all-zero taps where the camera's lens
    /// does not see the point. [`Self::camera_samples`] expanded.
    pub fn camera_taps(&self, cam: usize) -> Vec<BilinearTaps> {
        let grid = self.camera_grids[cam];
        self.camera_samples(cam)
            .into_par_iter()
            .with_min_len(self.output.width())
            .map(|s| grid.taps_of(s))
            .collect()
    }

    /// [`Self::camera_taps`] in compact form, on the camera's grid
    /// ([`Self::camera_grid`]): [`ErpSample::UNSEEN`] where the lens does not see the point.
    /// The same samples as [`Self::sample`] and [`Self::sees`], built from the camera's
    /// rotated output rays: with `cam_from_output = (R, t)`, the point of pixel `k` on sphere
    /// `rho` is `rho (R dir_k) + t`, so a sample costs a multiply-add and the two arctangents
    /// of its longitude and latitude.
    pub fn camera_samples(&self, cam: usize) -> Vec<ErpSample> {
        let w = self.output.width();
        let pixels = self.output.len();
        let pose = self.cam_from_output[cam];
        let rotated: Vec<Vector3<f64>> = (0..pixels)
            .into_par_iter()
            .with_min_len(w)
            .map(|k| pose.rotation * self.output.dir_from_pixel(self.output.pixel_of_index(k)))
            .collect();
        let t = pose.translation.vector;
        let ranges_m = self.hypotheses.depths_m();
        let grid = self.camera_grids[cam];
        let panorama = &self.panoramas[cam];
        let check_sight = panorama.needs_remap();
        (0..ranges_m.len() * pixels)
            .into_par_iter()
            .with_min_len(w)
            .map(|n| {
                let point = ranges_m[n / pixels] * rotated[n % pixels] + t;
                if check_sight && !panorama.sees(&point) {
                    ErpSample::UNSEEN
                } else {
                    grid.bilinear_sample(grid.pixel_from_dir(&point))
                }
            })
            .collect()
    }

    /// Sample positions of one camera on one sphere for every output pixel, row-major, as
    /// `[u, v]` pairs.
    pub fn sphere_coords(&self, cam: usize, sphere: usize) -> Vec<[f32; 2]> {
        let w = self.output.width();
        let range_m = self.hypotheses.depth_m(sphere as f64);
        (0..self.output.len())
            .into_par_iter()
            .with_min_len(w)
            .map(|k| {
                let p = self.output.pixel_of_index(k);
                let q = self.sample_at_range(cam, p, range_m);
                [q.u as f32, q.v as f32]
            })
            .collect()
    }
}

/// Taps of a sample the camera does not see: zero weights, so it contributes nothing.
pub const UNSEEN_TAPS: BilinearTaps = BilinearTaps::UNSEEN;

/// Precomputed sample positions for every camera, sphere and output pixel
/// (layout `[camera][sphere][v][u]`), built once per rig and resolution.
#[derive(Clone, Debug)]
pub struct SweepTable {
    geometry: SweepGeometry,
    coords: Vec<[f32; 2]>,
}

impl SweepTable {
    pub fn build(geometry: SweepGeometry) -> Self {
        let n_cam = geometry.camera_count();
        let n_sph = geometry.hypotheses.count();
        let mut coords = Vec::with_capacity(n_cam * n_sph * geometry.output.len());
        for cam in 0..n_cam {
            for sphere in 0..n_sph {
                coords.extend(geometry.sphere_coords(cam, sphere));
            }
        }
        Self { geometry, coords }
    }

    pub fn geometry(&self) -> &SweepGeometry {
        &self.geometry
    }

    /// Sample positions of camera `cam` on sphere `sphere`, row-major over the output grid.
    pub fn coords(&self, cam: usize, sphere: usize) -> &[[f32; 2]] {
        let n = self.geometry.output.len();
        let start = (cam * self.geometry.hypotheses.count() + sphere) * n;
        &self.coords[start..start + n]
    }

    /// Bilinear taps into camera `cam`'s image for output pixel index `k` on `sphere`.
    pub fn taps(&self, cam: usize, sphere: usize, k: usize) -> BilinearTaps {
        let [u, v] = self.coords(cam, sphere)[k];
        self.geometry.camera_grids[cam].bilinear_taps(PixelCoord {
            u: u as f64,
            v: v as f64,
        })
    }

    /// Bytes held by the table.
    pub fn memory_bytes(&self) -> usize {
        self.coords.len() * std::mem::size_of::<[f32; 2]>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `camera_taps` against the per-sample `sees` and `sample` on the OmniMVS-like fisheye rig
    /// (whose lenses leave parts of every sphere unseen).
    #[test]
    fn camera_taps_match_the_per_sample_sweep() -> Result<(), Box<dyn std::error::Error>> {
        let rig = Rig::from_file(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../launch_configs/rig_omnimvs.yaml"
        ))?;
        let output = ErpGrid::new(32)?;
        let hypotheses = DepthHypotheses::new(DepthRange::paper(), 8)?;
        let cameras = rig.cameras.len();
        let geometry = SweepGeometry::new(&rig, output, vec![output; cameras], hypotheses)?;
        let (mut unseen, mut worst) = (0usize, 0.0f32);
        for cam in 0..cameras {
            let taps = geometry.camera_taps(cam);
            assert_eq!(taps.len(), 8 * output.len());
            for (n, got) in taps.iter().enumerate() {
                let (sphere, k) = (n / output.len(), n % output.len());
                let p = PixelCoord {
                    u: (k % 32) as f64,
                    v: (k / 32) as f64,
                };
                if !geometry.sees(cam, sphere, p) {
                    assert_eq!(got.weight, [0.0; 4], "camera {cam} sample {n}");
                    unseen += 1;
                    continue;
                }
                let want = output.bilinear_taps(geometry.sample(cam, sphere, p));
                assert_eq!(got.index, want.index, "camera {cam} sample {n}");
                for (a, b) in got.weight.iter().zip(&want.weight) {
                    worst = worst.max((a - b).abs());
                }
            }
        }
        assert!(unseen > 0, "the fisheye rig should leave samples unseen");
        // the tables round the offsets to 1/65536 of a pixel (ErpSample::FRACTION_STEPS)
        assert!(worst < 4e-5, "largest tap weight difference {worst}");
        Ok(())
    }

    #[test]
    fn hypotheses_round_trip_in_both_spacings() -> Result<(), GeometryError> {
        let range = DepthRange::paper();
        for spacing in [HypothesisSpacing::InverseDepth, HypothesisSpacing::LogDepth] {
            let h = DepthHypotheses::with_spacing(range, 96, spacing)?;
            assert!((h.depth_m(0.0) - 1000.0).abs() < 1e-9);
            assert!((h.depth_m(95.0) - 0.5).abs() < 1e-12);
            for depth_m in [0.7, 3.0, 40.0, 350.0] {
                let i = h.index_of_depth(depth_m);
                assert!(
                    (h.depth_m(i) / depth_m - 1.0).abs() < 1e-12,
                    "{spacing:?} {depth_m}"
                );
            }
        }
        // Log spacing: equal ratios, (1000 / 0.5)^(1/95) = 1.0833 per step.
        let log = DepthHypotheses::with_spacing(range, 96, HypothesisSpacing::LogDepth)?;
        let ratio = log.depth_m(10.0) / log.depth_m(11.0);
        assert!((ratio - 2000f64.powf(1.0 / 95.0)).abs() < 1e-12);
        assert!((log.depth_m(40.0) / log.depth_m(41.0) - ratio).abs() < 1e-12);
        // Uniform inverse depth leaves 10 of 96 hypotheses beyond 5 m; log spacing 67.
        let beyond = |h: &DepthHypotheses| h.depths_m().iter().filter(|&&d| d > 5.0).count();
        assert_eq!(beyond(&DepthHypotheses::new(range, 96)?), 10);
        assert_eq!(beyond(&log), 67);
        Ok(())
    }
}
