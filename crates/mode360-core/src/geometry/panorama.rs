//! Every camera as a panorama: the frame, the visibility and the image resampling that let the
//! spherical sweep and the network treat fisheye and dual-fisheye cameras like 360° ones.
//!
//! A camera's **panorama frame** is REP 103-like (x forward, y left, z up), as a 360° camera's
//! own frame. For an equirectangular or dual-fisheye camera it is the camera frame itself; a
//! single fisheye camera's frame is its optical frame (z along the axis, x right, y down), so
//! its panorama frame looks along the optical axis:
//!
//! ```text
//! p_optical = OPTICAL_FROM_PANORAMA p_panorama,   (x, y, z)_optical = (-y, -z, x)_panorama
//! ```
//!
//! [`CameraPanorama::sees`] tells whether the camera sees a direction of its panorama frame
//! (the model projects it into the image); [`PanoramaRemap`] resamples a fisheye image into an
//! ERP panorama of that frame, with a validity mask that is false wherever the camera sees
//! nothing. An ERP camera sees every direction and needs no remap.

use super::erp::{BilinearTaps, ErpGrid, PixelCoord};
use super::rig::{Projection, Rig, RigCamera};
use super::GeometryError;
use image::RgbImage;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

/// Output rows per rayon task while resampling.
const ROWS_PER_TASK: usize = 8;

/// `p_optical = OPTICAL_FROM_PANORAMA p_panorama`: optical z is panorama x (forward), optical
/// x is panorama -y (right), optical y is panorama -z (down).
pub fn optical_from_panorama() -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, -1.0, 0.0, //
        0.0, 0.0, -1.0, //
        1.0, 0.0, 0.0,
    )))
}

/// `cam_from_panorama` of a projection: identity for ERP and dual fisheye, the optical
/// rotation for a single fisheye.
pub fn cam_from_panorama(projection: &Projection) -> Isometry3<f64> {
    match projection {
        Projection::Fisheye(_) => {
            Isometry3::from_parts(Translation3::identity(), optical_from_panorama())
        }
        Projection::Equirectangular | Projection::DualFisheye(_) => Isometry3::identity(),
    }
}

/// One camera seen as a panorama.
#[derive(Clone, Debug)]
pub struct CameraPanorama {
    projection: Projection,
    cam_from_panorama: Isometry3<f64>,
    /// `p_rig = rig_from_panorama p_panorama`.
    pub rig_from_panorama: Isometry3<f64>,
}

impl CameraPanorama {
    pub fn new(camera: &RigCamera) -> Self {
        let cam_from_panorama = cam_from_panorama(&camera.projection);
        Self {
            projection: camera.projection.clone(),
            cam_from_panorama,
            rig_from_panorama: camera.rig_from_cam * cam_from_panorama,
        }
    }

    /// Whether the camera sees the panorama-frame point or direction `p` (any non-zero
    /// length): always for ERP; for a fisheye, when its model projects `p` into the image.
    pub fn sees(&self, p: &Vector3<f64>) -> bool {
        match self.projection.fisheye_model() {
            None => true,
            Some(model) => model
                .project(&(self.cam_from_panorama.rotation * p))
                .is_some(),
        }
    }

    /// Whether this camera's images need [`PanoramaRemap`] before the sweep.
    pub fn needs_remap(&self) -> bool {
        !self.projection.is_equirectangular()
    }
}

/// The rig's cameras as panoramas (same order as `rig.cameras`), and the ERP rig that has
/// them as its cameras (for code that sweeps panoramas).
pub fn rig_panoramas(rig: &Rig) -> Vec<CameraPanorama> {
    rig.cameras.iter().map(CameraPanorama::new).collect()
}

/// `rig` with every camera replaced by its panorama: equirectangular, at `rig_from_panorama`.
pub fn panorama_rig(rig: &Rig) -> Rig {
    let mut out = rig.clone();
    for (cam, pano) in out.cameras.iter_mut().zip(rig_panoramas(rig)) {
        cam.projection = Projection::Equirectangular;
        cam.rig_from_cam = pano.rig_from_panorama;
    }
    out
}

/// Bilinear taps at `p` in a `width x height` image whose borders clamp (no wrap).
fn clamped_taps(p: PixelCoord, width: usize, height: usize) -> BilinearTaps {
    let clamp = |x: f64, n: usize| x.clamp(0.0, (n - 1) as f64);
    let (u, v) = (clamp(p.u, width), clamp(p.v, height));
    let (u0, v0) = (u.floor(), v.floor());
    let (fu, fv) = ((u - u0) as f32, (v - v0) as f32);
    let (u0, v0) = (u0 as usize, v0 as usize);
    let (u1, v1) = ((u0 + 1).min(width - 1), (v0 + 1).min(height - 1));
    let idx = |u: usize, v: usize| (v * width + u) as u32;
    BilinearTaps::from_corners([idx(u0, v0), idx(u1, v0), idx(u0, v1), idx(u1, v1)], fu, fv)
}

/// A fisheye camera's image resampled into an ERP panorama of its panorama frame.
#[derive(Clone, Debug)]
pub struct PanoramaRemap {
    grid: ErpGrid,
    source_width: usize,
    source_height: usize,
    /// Per panorama pixel (row-major): the taps into the source image, `None` where the camera
    /// sees nothing.
    taps: Vec<Option<BilinearTaps>>,
}

/// An ERP panorama and where it holds image content.
#[derive(Clone, Debug)]
pub struct RemappedImage {
    pub image: RgbImage,
    /// Row-major, true where the camera sees the pixel's direction.
    pub valid: Vec<bool>,
}

impl PanoramaRemap {
    /// The remap of `camera` into a `grid` panorama (`None` for an ERP camera: nothing to do).
    ///
    /// `pixel(u, v) = model(cam_from_panorama dir(u, v))`, sampled bilinearly.
    pub fn new(camera: &RigCamera, grid: ErpGrid) -> Option<Self> {
        let model = camera.projection.fisheye_model()?;
        let size = model.image_size();
        let rotation = cam_from_panorama(&camera.projection).rotation;
        let (width, height) = (size.width as usize, size.height as usize);
        let taps = (0..grid.len())
            .into_par_iter()
            .with_min_len(grid.width())
            .map(|k| {
                let p = PixelCoord {
                    u: (k % grid.width()) as f64,
                    v: (k / grid.width()) as f64,
                };
                model
                    .project(&(rotation * grid.dir_from_pixel(p)))
                    .map(|px| clamped_taps(px, width, height))
            })
            .collect();
        Some(Self {
            grid,
            source_width: width,
            source_height: height,
            taps,
        })
    }

    pub fn grid(&self) -> ErpGrid {
        self.grid
    }

    /// The fraction of the sphere the camera sees.
    pub fn coverage(&self) -> f64 {
        self.taps.iter().filter(|t| t.is_some()).count() as f64 / self.taps.len().max(1) as f64
    }

    /// Resamples `image` (which must be the camera's image size); unseen pixels are black.
    pub fn apply(&self, image: &RgbImage) -> Result<RemappedImage, GeometryError> {
        let (w, h) = (image.width() as usize, image.height() as usize);
        if (w, h) != (self.source_width, self.source_height) {
            return Err(GeometryError::WrongImageSize {
                expected: (self.source_width, self.source_height),
                got: (w, h),
            });
        }
        let src = image.as_raw();
        let gw = self.grid.width();
        let mut out = vec![0u8; self.grid.len() * 3];
        out.par_chunks_mut(gw * 3 * ROWS_PER_TASK)
            .zip(self.taps.par_chunks(gw * ROWS_PER_TASK))
            .for_each(|(rows, taps)| {
                for (px, t) in rows.chunks_exact_mut(3).zip(taps) {
                    let Some(t) = t else { continue };
                    for (c, o) in px.iter_mut().enumerate() {
                        let v: f32 = (0..4)
                            .map(|k| t.weight[k] * f32::from(src[t.index[k] as usize * 3 + c]))
                            .sum();
                        *o = v.round().clamp(0.0, 255.0) as u8;
                    }
                }
            });
        let image = RgbImage::from_raw(gw as u32, self.grid.height() as u32, out).ok_or(
            GeometryError::WrongImageSize {
                expected: (gw, self.grid.height()),
                got: (0, 0),
            },
        )?;
        Ok(RemappedImage {
            image,
            valid: self.taps.iter().map(Option::is_some).collect(),
        })
    }
}

/// The remaps of a whole rig into panoramas `grid` wide (ERP cameras pass through).
#[derive(Clone, Debug)]
pub struct RigRemap {
    rig: Rig,
    grid: ErpGrid,
    remaps: Vec<Option<PanoramaRemap>>,
}

impl RigRemap {
    pub fn new(rig: &Rig, grid: ErpGrid) -> Self {
        Self {
            rig: rig.clone(),
            grid,
            remaps: rig
                .cameras
                .iter()
                .map(|c| PanoramaRemap::new(c, grid))
                .collect(),
        }
    }

    /// Whether this remap was built for `rig` at `grid`.
    pub fn serves(&self, rig: &Rig, grid: ErpGrid) -> bool {
        self.grid == grid && &self.rig == rig
    }

    /// Whether any camera needs resampling.
    pub fn any_fisheye(&self) -> bool {
        self.remaps.iter().any(Option::is_some)
    }

    /// Per camera, where its panorama holds content (1) or nothing (0), row-major on the
    /// remap's grid; `None` for an ERP camera (content everywhere).
    pub fn validity(&self) -> Vec<Option<Vec<f32>>> {
        self.remaps
            .iter()
            .map(|r| {
                r.as_ref().map(|r| {
                    r.taps
                        .iter()
                        .map(|t| if t.is_some() { 1.0 } else { 0.0 })
                        .collect()
                })
            })
            .collect()
    }

    /// Each camera's image as a panorama: fisheye images resampled into `grid` (unseen
    /// pixels black), ERP images as they are. An image of the wrong size is an error naming
    /// the camera.
    pub fn panoramas<'a>(
        &self,
        images: &'a [RgbImage],
    ) -> Result<Vec<std::borrow::Cow<'a, RgbImage>>, (String, GeometryError)> {
        images
            .iter()
            .zip(&self.remaps)
            .zip(&self.rig.cameras)
            .map(|((img, remap), cam)| match remap {
                None => Ok(std::borrow::Cow::Borrowed(img)),
                Some(r) => r
                    .apply(img)
                    .map(|m| std::borrow::Cow::Owned(m.image))
                    .map_err(|e| (cam.name.clone(), e)),
            })
            .collect()
    }
}

/// Per pixel of `grid` (row-major), how many cameras of `rig` see the output sphere's point at
/// `range_m` in that pixel's direction.
pub fn cameras_seeing(rig: &Rig, grid: ErpGrid, range_m: f64) -> Vec<usize> {
    let panoramas = rig_panoramas(rig);
    let panorama_from_output: Vec<Isometry3<f64>> = panoramas
        .iter()
        .map(|p| p.rig_from_panorama.inverse() * rig.rig_from_output)
        .collect();
    (0..grid.len())
        .into_par_iter()
        .with_min_len(grid.width())
        .map(|k| {
            let p = PixelCoord {
                u: (k % grid.width()) as f64,
                v: (k / grid.width()) as f64,
            };
            let point = nalgebra::Point3::from(grid.dir_from_pixel(p) * range_m);
            panoramas
                .iter()
                .zip(&panorama_from_output)
                .filter(|(pano, from_out)| pano.sees(&(*from_out * point).coords))
                .count()
        })
        .collect()
}

/// Directions of the output sphere that fewer than two cameras see, as a fraction of the
/// sphere's pixels, at `range_m` from the output frame's origin (sampled on `grid`).
pub fn poorly_seen_fraction(rig: &Rig, grid: ErpGrid, range_m: f64) -> f64 {
    let seen = cameras_seeing(rig, grid, range_m);
    seen.iter().filter(|&&n| n < 2).count() as f64 / grid.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_optical_axis_is_the_panorama_forward() {
        let r = optical_from_panorama();
        let close = |a: Vector3<f64>, b: Vector3<f64>| (a - b).norm() < 1e-12;
        assert!(close(r * Vector3::x(), Vector3::z()));
        assert!(close(r * Vector3::y(), -Vector3::x()));
        assert!(close(r * Vector3::z(), -Vector3::y()));
    }

    #[test]
    fn a_lens_that_looks_forward_leaves_the_back_unseen() {
        // Two 180-degree Kannala-Brandt lenses side by side, both looking forward (+x):
        // the unseen part lies behind the rig (|longitude| > 90 degrees); the image corners see
        // up to 127 degrees off axis, so it is somewhat less than half the sphere.
        let cam = |name: &str, y: f64| {
            format!(
                "  - name: {name}\n    topic: /{name}\n    frame_id: {name}\n    projection: kannala_brandt\n    \
                 image_size: [64, 64]\n    intrinsics: {{fx: 20.0, fy: 20.0, cx: 31.5, cy: 31.5, k1: 0, k2: 0, k3: 0, k4: 0}}\n    \
                 rig_from_cam: {{translation: [0, {y}, 1], rotation_rpy: [-1.5707963267948966, 0, -1.5707963267948966]}}\n"
            )
        };
        let yaml = format!(
            "output: {{frame_id: o, rig_from_output: {{translation: [0, 0, 1], rotation_xyzw: [0, 0, 0, 1]}}}}\ncameras:\n{}{}",
            cam("a", 0.2),
            cam("b", -0.2)
        );
        let rig = Rig::from_yaml_str(&yaml, "forward.yaml").unwrap();
        let part = unseen_part(&rig, ErpGrid::new(128).unwrap(), 100.0).unwrap();
        assert!(part.fraction > 0.3 && part.fraction < 0.5, "{part:?}");
        let (from, to) = part.lon_deg.unwrap();
        assert!(
            (from - 90.0).abs() <= 5.0 && (to + 90.0).abs() <= 5.0,
            "{part:?}"
        );
        assert!(part.to_string().contains("seen by no camera"));
        // A rig of 360-degree cameras sees everything.
        let erp = Rig::from_yaml_str(
            "cameras:\n  - {name: a, topic: /a, frame_id: a, rig_from_cam: {translation: [0, 0, 1], rotation_xyzw: [0, 0, 0, 1]}}\n  - {name: b, topic: /b, frame_id: b, rig_from_cam: {translation: [0, 1, 1], rotation_xyzw: [0, 0, 0, 1]}}\n",
            "erp.yaml",
        )
        .unwrap();
        assert_eq!(unseen_part(&erp, ErpGrid::new(64).unwrap(), 100.0), None);
    }

    #[test]
    fn clamped_taps_stay_inside_and_sum_to_one() {
        for (u, v) in [(-0.4, -0.3), (9.4, 4.2), (3.25, 2.5)] {
            let t = clamped_taps(PixelCoord { u, v }, 10, 5);
            assert!(t.index.iter().all(|&i| i < 50));
            assert!((t.weight.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        }
        let t = clamped_taps(PixelCoord { u: 3.25, v: 2.5 }, 10, 5);
        assert_eq!(t.index, [23, 24, 33, 34]);
        assert!((t.weight[1] - 0.125).abs() < 1e-6);
    }
}

/// The part of the output sphere no camera sees (at a range), for a warning that says where.
#[derive(Clone, Debug, PartialEq)]
pub struct UnseenPart {
    /// Share of the sphere's area, 0 to 1.
    pub fraction: f64,
    /// Latitude band (degrees, output frame) that holds every unseen direction.
    pub min_lat_deg: f64,
    pub max_lat_deg: f64,
    /// Longitude interval (degrees, `from` to `to` counter-clockwise, left of forward is
    /// positive) holding them; `None` when they span every longitude.
    pub lon_deg: Option<(f64, f64)>,
    pub range_m: f64,
}

impl std::fmt::Display for UnseenPart {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:.1} % of the sphere at {} m is seen by no camera: latitudes {:.0} to {:.0} degrees",
            100.0 * self.fraction,
            self.range_m,
            self.min_lat_deg,
            self.max_lat_deg
        )?;
        match self.lon_deg {
            None => write!(f, ", all longitudes"),
            Some((from, to)) => write!(f, ", longitudes {from:.0} to {to:.0} degrees"),
        }?;
        write!(f, " (output frame: 0 forward, 90 left, latitude 90 up)")
    }
}

/// Area share below which an unseen part is not worth a warning (a pixel or two of a coarse
/// grid at the poles).
pub const UNSEEN_WARNING_FRACTION: f64 = 0.002;
/// Range and grid width of the coverage check that the node and `synth` run on a rig.
pub const COVERAGE_CHECK_RANGE_M: f64 = 100.0;
pub const COVERAGE_CHECK_WIDTH: usize = 128;

/// [`unseen_part`] at [`COVERAGE_CHECK_RANGE_M`] on a [`COVERAGE_CHECK_WIDTH`] grid.
pub fn rig_coverage_warning(rig: &Rig) -> Option<UnseenPart> {
    let grid = ErpGrid::new(COVERAGE_CHECK_WIDTH).ok()?;
    unseen_part(rig, grid, COVERAGE_CHECK_RANGE_M)
}

/// Longitude bins used to find the unseen part's longitude interval.
const LON_BINS: usize = 72;

/// Where no camera of `rig` sees directions of the output sphere at `range_m` (sampled on
/// `grid`, pixels weighted by their solid angle `cos(lat)`); `None` when that is less than
/// [`UNSEEN_WARNING_FRACTION`] of the sphere.
pub fn unseen_part(rig: &Rig, grid: ErpGrid, range_m: f64) -> Option<UnseenPart> {
    let w = grid.width();
    // (lon deg, lat deg, solid-angle weight) of every pixel no camera sees
    let unseen: Vec<(f64, f64, f64)> = cameras_seeing(rig, grid, range_m)
        .into_iter()
        .enumerate()
        .filter(|&(_, n)| n == 0)
        .map(|(k, _)| {
            let ll = grid.lonlat_from_pixel(grid.pixel_of_index(k));
            (
                ll.lon_rad.to_degrees(),
                ll.lat_rad.to_degrees(),
                ll.lat_rad.cos(),
            )
        })
        .collect();
    let total: f64 = (0..grid.height())
        .map(|v| {
            let ll = grid.lonlat_from_pixel(PixelCoord {
                u: 0.0,
                v: v as f64,
            });
            ll.lat_rad.cos() * w as f64
        })
        .sum();
    let fraction = unseen.iter().map(|u| u.2).sum::<f64>() / total;
    if fraction < UNSEEN_WARNING_FRACTION {
        return None;
    }
    let min_lat_deg = unseen.iter().map(|u| u.1).fold(f64::INFINITY, f64::min);
    let max_lat_deg = unseen.iter().map(|u| u.1).fold(f64::NEG_INFINITY, f64::max);
    // The longitude interval is the circle minus its largest run of empty bins.
    let mut occupied = [false; LON_BINS];
    let bin_deg = 360.0 / LON_BINS as f64;
    for u in &unseen {
        occupied[(((u.0 + 180.0) / bin_deg) as usize).min(LON_BINS - 1)] = true;
    }
    let (mut best_len, mut best_start) = (0, 0);
    for start in 0..LON_BINS {
        let len = (0..LON_BINS)
            .take_while(|i| !occupied[(start + i) % LON_BINS])
            .count();
        if len > best_len {
            (best_len, best_start) = (len, start);
        }
    }
    let lon_deg = (best_len > 0).then(|| {
        let from = ((best_start + best_len) % LON_BINS) as f64 * bin_deg - 180.0;
        let to = best_start as f64 * bin_deg - 180.0;
        (from, to)
    });
    Some(UnseenPart {
        fraction,
        min_lat_deg,
        max_lat_deg,
        lon_deg,
        range_m,
    })
}
