//! Synthetic street scenes for a 360° camera rig: procedural road, buildings, cars, trees,
//! street lights and pedestrians, ray cast into one ERP panorama per camera, with the exact
//! ground-truth range of the rig's output frame and optional lens soiling.
//!
//! * World: REP 103, z up, the road runs along +x ([`world`] describes the layout). The rig
//!   frame rides the ego lane: `world_from_rig(i) = (x0 + speed t_i, EGO_LANE_Y_M, 0)` with
//!   `t_i = i * frame_period_s`.
//! * Pixel rays come from [`ErpGrid::dir_from_pixel`]; a camera ray in the world is
//!   `world_from_rig * rig_from_cam * dir`.
//! * Ground truth: for every output-frame pixel the Euclidean range to the first surface,
//!   `min(t, max_depth_m)`; sky pixels are `max_depth_m`.
//! * Shading: Lambertian sun with hard shadows (shadow rays), hemispherical sky ambient, fog
//!   `f = 1 - exp(-t / FOG_DISTANCE_M)`, gamma 2.2. Textures live in world or object
//!   coordinates, so every camera sees the same surface colour.

pub mod bvh;
pub mod material;
pub mod noise;
pub mod soiling;
pub mod world;

use crate::frame::{FloatImage, RgbImage, RigFrame};
use crate::geometry::{ErpGrid, GeometryError, PixelCoord, Rig};
use bvh::{Bvh, Ray};
use material::{Material, Rgb};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use noise::Rng;
use rayon::prelude::*;
use std::collections::BTreeMap;
use world::{WorldParams, EGO_LANE_Y_M};

pub use soiling::{CameraSoiling, SoilingKind};

/// Scene content is generated this far ahead of and behind the rig along x, metres.
pub const VIEW_RANGE_M: f64 = 480.0;
/// First frame's stamp: 2023-11-14T22:13:20Z, in nanoseconds since the epoch.
pub const START_STAMP_NS: u64 = 1_700_000_000_000_000_000;
/// Fog (aerial perspective) distance scale, metres.
pub const FOG_DISTANCE_M: f64 = 900.0;
/// Sun irradiance and sky ambient (linear RGB, for albedo 1).
const SUN_RADIANCE: Rgb = [1.55, 1.45, 1.3];
const SKY_AMBIENT: Rgb = [0.42, 0.48, 0.6];
/// Light bounced from the ground onto downward-facing surfaces.
const GROUND_BOUNCE: Rgb = [0.12, 0.11, 0.1];
/// Sky-ambient weight of a vertical surface (1 for an upward one, `2 base - 1` downward).
const SKY_VIEW_BASE: f64 = 0.6;
/// Ground-bounce weight of a vertical surface.
const GROUND_VIEW_SIDE: f64 = 0.3;
/// Light emitted by street-lamp heads (linear RGB added to the shaded colour).
const LAMP_EMISSION: Rgb = [0.3, 0.28, 0.2];
/// Offset of shadow-ray origins along the normal, metres.
const SHADOW_BIAS_M: f64 = 1e-4;
/// Footprints are divided by `max(|cos incidence|, MIN_COS_INCIDENCE)`.
const MIN_COS_INCIDENCE: f64 = 0.12;
/// Display gamma.
const GAMMA: f32 = 2.2;
/// Two isometries closer than this (metres and radians) are the same pose.
const SAME_POSE_TOLERANCE: f64 = 1e-9;

/// Errors of the synthetic renderer's configuration.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("synth config: {0}")]
    Width(#[from] GeometryError),
    #[error("synth config: field '{field}' must be {requirement}, got {value}")]
    BadParameter {
        field: &'static str,
        requirement: &'static str,
        value: f64,
    },
}

/// How to render a synthetic sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    /// World seed: everything (layout, textures, traffic, soiling) is a function of it.
    pub seed: u64,
    /// ERP width in pixels; height is `width / 2`.
    pub width: usize,
    /// Apply lens soiling to one or two cameras per frame.
    pub soiled: bool,
    /// Ground-truth range of sky pixels and the clamp for all ranges, metres.
    pub max_depth_m: f64,
    /// Time between frames, seconds.
    pub frame_period_s: f64,
    /// Ego speed along +x, metres per second.
    pub speed_mps: f64,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            width: 512,
            soiled: false,
            max_depth_m: 1000.0,
            frame_period_s: 0.1,
            speed_mps: 8.0,
        }
    }
}

impl SynthConfig {
    /// The configuration as text key/value pairs (for bag metadata).
    pub fn to_info(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("generator".into(), "mode360::synth street v1".into());
        m.insert("seed".into(), self.seed.to_string());
        m.insert("width".into(), self.width.to_string());
        m.insert("height".into(), (self.width / 2).to_string());
        m.insert("soiled".into(), self.soiled.to_string());
        m.insert("max_depth_m".into(), self.max_depth_m.to_string());
        m.insert("frame_period_s".into(), self.frame_period_s.to_string());
        m.insert("speed_mps".into(), self.speed_mps.to_string());
        m
    }

    fn validate(&self) -> Result<(), SynthError> {
        ErpGrid::new(self.width)?;
        let checks: [(&'static str, f64, bool, &'static str); 3] = [
            (
                "max_depth_m",
                self.max_depth_m,
                self.max_depth_m.is_finite() && self.max_depth_m > 0.0,
                "finite and > 0",
            ),
            (
                "frame_period_s",
                self.frame_period_s,
                self.frame_period_s.is_finite() && self.frame_period_s >= 0.0,
                "finite and >= 0",
            ),
            (
                "speed_mps",
                self.speed_mps,
                self.speed_mps.is_finite(),
                "finite",
            ),
        ];
        for (field, value, ok, requirement) in checks {
            if !ok {
                return Err(SynthError::BadParameter {
                    field,
                    requirement,
                    value,
                });
            }
        }
        Ok(())
    }
}

/// What was rendered for a frame besides the images.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameReport {
    pub index: usize,
    pub stamp_ns: u64,
    /// Time since the first frame, seconds.
    pub time_s: f64,
    pub world_from_rig: Isometry3<f64>,
    /// One entry per camera (rig order); default (zero coverage) for clean cameras.
    pub soiling: Vec<CameraSoiling>,
}

/// A single rendered view: the ERP image and its range image (metres).
#[derive(Clone, Debug)]
pub struct CameraView {
    pub image: RgbImage,
    pub range_m: FloatImage,
}

/// Renders frames of a procedural street for any rig.
pub struct SynthRenderer {
    cfg: SynthConfig,
    grid: ErpGrid,
    /// Unit ray direction of every ERP pixel (row-major), in the camera frame.
    dirs: Vec<Vector3<f64>>,
    params: WorldParams,
    gamma_lut: Vec<u8>,
}

/// One traced ray's result.
#[derive(Clone, Copy, Debug)]
struct Sample {
    colour: Rgb,
    range_m: f64,
}

/// The first surface a ray meets: its distance and the primitive (`None`: the ground plane).
#[derive(Clone, Copy, Debug)]
struct FirstHit {
    t: f64,
    prim: Option<bvh::PrimHit>,
}

/// The per-frame scene: primitives in a BVH plus the analytic ground plane and sky.
struct FrameScene<'a> {
    bvh: Bvh,
    params: &'a WorldParams,
    pixel_angle_rad: f64,
    max_depth_m: f64,
}

impl FrameScene<'_> {
    /// The first surface along `ray` (BVH primitive or ground plane `z = 0`), if any.
    fn first_hit(&self, ray: &Ray) -> Option<FirstHit> {
        let t_ground = if ray.dir.z < 0.0 {
            -ray.origin.z / ray.dir.z
        } else {
            f64::INFINITY
        };
        match self.bvh.closest(ray, t_ground) {
            Some(h) => Some(FirstHit {
                t: h.hit.t,
                prim: Some(h),
            }),
            None if t_ground.is_finite() => Some(FirstHit {
                t: t_ground,
                prim: None,
            }),
            None => None,
        }
    }

    fn range_only(&self, ray: &Ray) -> f64 {
        self.first_hit(ray)
            .map_or(self.max_depth_m, |h| h.t.min(self.max_depth_m))
    }

    fn trace(&self, ray: &Ray) -> Sample {
        let seed = self.params.tex_seed;
        let sun = self.params.sun_dir;
        let Some(FirstHit { t, prim: prim_hit }) = self.first_hit(ray) else {
            return Sample {
                colour: material::sky(&ray.dir, &sun, self.pixel_angle_rad, seed),
                range_m: self.max_depth_m,
            };
        };
        let p = ray.at(t);
        let (material, mut n, p_obj) = match prim_hit {
            Some(h) => {
                let prim = &self.bvh.prims[h.prim];
                (prim.material, h.hit.normal, p - prim.object_origin)
            }
            None => {
                let g = world::ground_material(self.params, &p);
                (g.material, Vector3::z(), p - g.texture_origin)
            }
        };
        let cos_in = n.dot(&ray.dir);
        if cos_in > 0.0 {
            n = -n;
        }
        let footprint_m = t * self.pixel_angle_rad / cos_in.abs().max(MIN_COS_INCIDENCE);
        let p_tex = Vector3::new(p.x.rem_euclid(TEXTURE_WRAP_M), p.y, p.z);
        let albedo = material::albedo(&material, &p_tex, &p_obj, &n, footprint_m, seed);
        let lambert = n.dot(&sun);
        let sunlit = if lambert > 0.0 {
            let shadow = Ray::new(p + n * SHADOW_BIAS_M, sun);
            if self.bvh.any(&shadow, f64::INFINITY) {
                0.0
            } else {
                lambert
            }
        } else {
            0.0
        };
        // Hemispherical ambient: the sky fills `(1 + n_z) / 2` of a surface's view (slightly
        // flattened), the ground the rest.
        let sky_w = SKY_VIEW_BASE + (1.0 - SKY_VIEW_BASE) * n.z;
        let ground_w = (-n.z).max(0.0) + GROUND_VIEW_SIDE * (1.0 - n.z.abs());
        let mut c = [0.0f32; 3];
        for i in 0..3 {
            c[i] = albedo[i]
                * (SUN_RADIANCE[i] * sunlit as f32
                    + SKY_AMBIENT[i] * sky_w as f32
                    + GROUND_BOUNCE[i] * ground_w as f32);
        }
        if material == Material::Lamp {
            for (ci, e) in c.iter_mut().zip(LAMP_EMISSION) {
                *ci += e;
            }
        }
        // Aerial perspective towards the horizon sky colour.
        let fog = (1.0 - (-t / FOG_DISTANCE_M).exp()) as f32;
        for (ci, h) in c.iter_mut().zip(material::HORIZON_SKY) {
            *ci += (h - *ci) * fog;
        }
        Sample {
            colour: c,
            range_m: t.min(self.max_depth_m),
        }
    }
}

/// Entries of the gamma lookup table, indexed by `sqrt(c)` (finer steps in the shadows).
const GAMMA_LUT_SIZE: usize = 4096;

/// `lut[i] = round(255 (i / (N - 1))^(2 / gamma))`, so `srgb8(c) = lut[sqrt(c) (N - 1)]`.
fn gamma_lut() -> Vec<u8> {
    (0..GAMMA_LUT_SIZE)
        .map(|i| {
            let s = i as f32 / (GAMMA_LUT_SIZE - 1) as f32;
            (s.powf(2.0 / GAMMA) * 255.0 + 0.5) as u8
        })
        .collect()
}

/// Encodes linear `c` (clamped to [0, 1]) to 8 bits with display gamma [`GAMMA`].
#[inline]
fn to_srgb8(lut: &[u8], c: f32) -> u8 {
    let i = (c.clamp(0.0, 1.0).sqrt() * (GAMMA_LUT_SIZE - 1) as f32 + 0.5) as usize;
    lut[i.min(GAMMA_LUT_SIZE - 1)]
}

/// World texture coordinates wrap along x with this period, metres, so that f32 texture
/// arithmetic keeps millimetre precision however far the rig drives (one seam per period).
pub const TEXTURE_WRAP_M: f64 = 2048.0;

fn same_pose(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    (a.translation.vector - b.translation.vector).norm() < SAME_POSE_TOLERANCE
        && a.rotation.angle_to(&b.rotation) < SAME_POSE_TOLERANCE
}

impl SynthRenderer {
    /// Validates `cfg` and prepares the world of its seed.
    pub fn new(cfg: SynthConfig) -> Result<Self, SynthError> {
        cfg.validate()?;
        let grid = ErpGrid::new(cfg.width)?;
        let mut dirs = Vec::with_capacity(grid.len());
        for v in 0..grid.height() {
            for u in 0..grid.width() {
                dirs.push(grid.dir_from_pixel(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                }));
            }
        }
        let params = WorldParams::new(cfg.seed);
        Ok(Self {
            cfg,
            grid,
            dirs,
            params,
            gamma_lut: gamma_lut(),
        })
    }

    pub fn config(&self) -> &SynthConfig {
        &self.cfg
    }

    pub fn grid(&self) -> ErpGrid {
        self.grid
    }

    /// Unit vector towards the sun in the world frame.
    pub fn sun_dir(&self) -> Vector3<f64> {
        self.params.sun_dir
    }

    /// Time of frame `index` since the first frame, seconds.
    pub fn frame_time_s(&self, index: usize) -> f64 {
        index as f64 * self.cfg.frame_period_s
    }

    /// Header stamp of frame `index`: `START_STAMP_NS + index * frame_period`.
    pub fn frame_stamp_ns(&self, index: usize) -> u64 {
        let period_ns = (self.cfg.frame_period_s * 1e9).round() as u64;
        START_STAMP_NS.saturating_add(period_ns.saturating_mul(index as u64))
    }

    /// Pose of the rig frame in the world at frame `index`.
    pub fn world_from_rig(&self, index: usize) -> Isometry3<f64> {
        let x = self.cfg.speed_mps * self.frame_time_s(index);
        Isometry3::from_parts(
            Translation3::new(x, EGO_LANE_Y_M, 0.0),
            UnitQuaternion::identity(),
        )
    }

    /// Frame `index`: one ERP image per camera of `rig` (rig order) and the ground-truth range
    /// of the rig's output frame.
    pub fn render_frame(&self, rig: &Rig, index: usize) -> RigFrame {
        self.render_frame_with_report(rig, index).0
    }

    /// Like [`Self::render_frame`], also reporting the pose and soiling per camera.
    pub fn render_frame_with_report(&self, rig: &Rig, index: usize) -> (RigFrame, FrameReport) {
        let t_s = self.frame_time_s(index);
        let world_from_rig = self.world_from_rig(index);
        let scene = self.frame_scene(index);
        let output_cam = rig
            .cameras
            .iter()
            .position(|c| same_pose(&c.rig_from_cam, &rig.rig_from_output));
        let mut images = Vec::with_capacity(rig.cameras.len());
        let mut gt: Option<FloatImage> = None;
        for (ci, cam) in rig.cameras.iter().enumerate() {
            let world_from_cam = world_from_rig * cam.rig_from_cam;
            let keep_range = output_cam == Some(ci);
            let (img, range) = self.render_view(&scene, &world_from_cam, keep_range);
            images.push(img);
            if keep_range {
                gt = range;
            }
        }
        let gt = match gt {
            Some(g) => g,
            None => self.render_range(&scene, &(world_from_rig * rig.rig_from_output)),
        };
        let mut soiling = vec![CameraSoiling::default(); images.len()];
        if self.cfg.soiled && !images.is_empty() {
            let mut rng = Rng::new(&[self.cfg.seed, index as u64, 0x5011]);
            let count = if images.len() > 1 && rng.chance(0.5) {
                2
            } else {
                1
            };
            let first = rng.index(images.len());
            let second = (first + 1 + rng.index(images.len() - 1)) % images.len();
            let chosen = if count == 2 {
                vec![first, second]
            } else {
                vec![first]
            };
            for c in chosen {
                soiling[c] = soiling::soil_image(&mut images[c], &mut rng);
            }
        }
        let stamp_ns = self.frame_stamp_ns(index);
        (
            RigFrame {
                stamp_ns,
                images,
                ground_truth: Some(gt),
            },
            FrameReport {
                index,
                stamp_ns,
                time_s: t_s,
                world_from_rig,
                soiling,
            },
        )
    }

    /// One clean ERP view from an arbitrary camera pose at the time of frame `index`, with
    /// its own range image (same conventions as the ground truth). The scene is the one
    /// around the rig's position at that frame.
    pub fn render_camera(&self, index: usize, world_from_cam: &Isometry3<f64>) -> CameraView {
        let scene = self.frame_scene(index);
        let (image, range) = self.render_view(&scene, world_from_cam, true);
        let range_m = range
            .unwrap_or_else(|| FloatImage::filled(self.grid.width(), self.grid.height(), f32::NAN));
        CameraView { image, range_m }
    }

    fn frame_scene(&self, index: usize) -> FrameScene<'_> {
        FrameScene {
            bvh: Bvh::build(world::scene_prims(
                &self.params,
                self.world_from_rig(index).translation.x,
                VIEW_RANGE_M,
                self.frame_time_s(index),
            )),
            params: &self.params,
            pixel_angle_rad: std::f64::consts::PI / self.grid.height() as f64,
            max_depth_m: self.cfg.max_depth_m,
        }
    }

    fn render_view(
        &self,
        scene: &FrameScene,
        world_from_cam: &Isometry3<f64>,
        keep_range: bool,
    ) -> (RgbImage, Option<FloatImage>) {
        let (w, h) = (self.grid.width(), self.grid.height());
        let origin = world_from_cam.translation.vector;
        let rot = world_from_cam.rotation;
        let mut rgb = vec![0u8; w * h * 3];
        let mut range = vec![0f32; w * h];
        rgb.par_chunks_mut(w * 3)
            .zip(range.par_chunks_mut(w))
            .enumerate()
            .for_each(|(v, (row, row_range))| {
                for u in 0..w {
                    let d = rot * self.dirs[v * w + u];
                    let s = scene.trace(&Ray::new(origin, d));
                    for i in 0..3 {
                        row[3 * u + i] = to_srgb8(&self.gamma_lut, s.colour[i]);
                    }
                    row_range[u] = s.range_m as f32;
                }
            });
        let img = RgbImage::from_raw(w as u32, h as u32, rgb)
            .unwrap_or_else(|| RgbImage::new(w as u32, h as u32));
        let range = keep_range.then_some(FloatImage {
            width: w,
            height: h,
            data: range,
        });
        (img, range)
    }

    fn render_range(&self, scene: &FrameScene, world_from_out: &Isometry3<f64>) -> FloatImage {
        let (w, h) = (self.grid.width(), self.grid.height());
        let origin = world_from_out.translation.vector;
        let rot = world_from_out.rotation;
        let mut data = vec![0f32; w * h];
        data.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, r) in row.iter_mut().enumerate() {
                let d = rot * self.dirs[v * w + u];
                *r = scene.range_only(&Ray::new(origin, d)) as f32;
            }
        });
        FloatImage {
            width: w,
            height: h,
            data,
        }
    }
}
