//! mode360's synthetic scenes: worlds of streets and objects rendered for any rig,
//! with ground-truth depth, the paper's lens soiling and blocked lenses.
//!
//! Synthetic scenes for a 360° camera rig, ray cast into one ERP panorama per camera, with the
//! exact ground-truth range of the rig's output frame and optional lens soiling. Two kinds
//! ([`SceneKind`]): procedural streets (road, buildings, cars, trees, street lights and
//! pedestrians; regular or with a per-seed layout, [`StreetStyle`]) and random objects
//! ([`objects`]: textured primitives at random distances in every direction, where a
//! monocular depth guess fails).
//!
//! * World: REP 103, z up, the road runs along +x ([`world`] describes the layout). The rig
//!   frame rides the ego lane: `world_from_rig(i) = (x0 + speed t_i, ego_lane_y, 0)` with
//!   `t_i = i * frame_period_s` (varied streets add a height offset, roll and pitch). In
//!   random-objects scenes the rig frame is the world frame.
//! * Pixel rays come from [`ErpGrid::dir_from_pixel`] for equirectangular cameras (at the
//!   configured width) and from the camera model for fisheye and dual-fisheye cameras (at
//!   their `image_size`, black where the model sees nothing: [`camera_view`]); a camera ray in
//!   the world is `world_from_rig * rig_from_cam * (origin + t dir)`.
//! * Ground truth: for every output-frame pixel the Euclidean range to the first surface,
//!   `min(t, max_depth_m)`; sky pixels are `max_depth_m`.
//! * Blocked lenses ([`blockers`], [`SynthConfig::blockers`]): after ray casting, a camera's
//!   image may get an opaque blocker (mud, a mount, a vehicle part) over a set fraction of its
//!   view, the same in every frame; lens soiling is applied after it. The ground truth is the
//!   scene's range, blocked or not.
//! * Shading: Lambertian sun with hard shadows (shadow rays), hemispherical sky ambient, fog
//!   `f = 1 - exp(-t / FOG_DISTANCE_M)`, gamma 2.2. Textures live in world or object
//!   coordinates, so every camera sees the same surface colour.

pub mod blockers;
pub mod bvh;
pub mod camera_view;
pub mod clutter;
pub mod colour;
mod config;
pub mod material;
pub mod noise;
pub mod objects;
pub mod pattern;
mod props;
pub mod record;
mod scene;
pub mod shape;
pub mod sky;
pub mod soiling;
pub mod street;
pub mod world;

use bvh::{Bvh, Ray};
use camera_view::PixelRays;
use mode360_core::frame::{FloatImage, RgbImage, RigFrame, SceneLabels};
use mode360_core::geometry::{ErpGrid, PixelCoord, Rig};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use noise::Rng;
use pattern::Background;
use rayon::prelude::*;
use scene::{FrameScene, Ground};
use world::WorldParams;

pub use blockers::{BlockedLens, BlockerError, BlockerKind};
pub use config::{SceneKind, SynthConfig, SynthError};
pub use scene::{FOG_DISTANCE_M, TEXTURE_WRAP_M};
pub use soiling::{CameraSoiling, SoilingKind};
pub use street::StreetStyle;

/// Bag metadata key of the blocked lenses' specifications (`CAM:FRACTION:KIND`, 1-based).
pub const BLOCKED_LENSES_KEY: &str = "blocked_lenses";
/// Bag metadata key of the measured blocked fraction per camera (`name=fraction,...`).
pub const BLOCKED_FRACTION_KEY: &str = "blocked_fraction";
/// Scene content is generated this far ahead of and behind the rig along x, metres.
pub const VIEW_RANGE_M: f64 = 480.0;
/// First frame's stamp: 2023-11-14T22:13:20Z, in nanoseconds since the epoch.
pub const START_STAMP_NS: u64 = 1_700_000_000_000_000_000;
/// Display gamma.
const GAMMA: f32 = 2.2;
/// Two isometries closer than this (metres and radians) are the same pose.
const SAME_POSE_TOLERANCE: f64 = 1e-9;

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
    /// Blocked fraction of each camera's view (rig order; 0 without a blocker), measured on
    /// the painted mask (see [`blockers`]).
    pub blocked: Vec<f64>,
}

/// A single rendered view: the image (ERP, or a camera model's) and its range image (metres).
#[derive(Clone, Debug)]
pub struct CameraView {
    pub image: RgbImage,
    pub range_m: FloatImage,
}

/// Renders frames of a procedural street or of random objects for any rig.
pub struct SynthRenderer {
    cfg: SynthConfig,
    grid: ErpGrid,
    /// Unit ray direction of every ERP pixel (row-major), in the camera frame.
    dirs: Vec<Vector3<f64>>,
    params: WorldParams,
    gamma_lut: Vec<u8>,
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
        let params = WorldParams::with_style(cfg.seed, cfg.street);
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

    /// The street's layout and sun (also built for objects scenes, which ignore it).
    pub fn world_params(&self) -> &WorldParams {
        &self.params
    }

    /// Pose of the rig frame in the world at frame `index` (the identity in objects scenes).
    pub fn world_from_rig(&self, index: usize) -> Isometry3<f64> {
        if self.cfg.scene == SceneKind::Objects {
            return Isometry3::identity();
        }
        let l = &self.params.layout;
        let x = self.cfg.speed_mps * self.frame_time_s(index);
        let rotation = if l.rig_roll_rad == 0.0 && l.rig_pitch_rad == 0.0 {
            UnitQuaternion::identity()
        } else {
            UnitQuaternion::from_euler_angles(l.rig_roll_rad, l.rig_pitch_rad, 0.0)
        };
        Isometry3::from_parts(
            Translation3::new(x, l.ego_lane_y_m, l.rig_height_offset_m),
            rotation,
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
        let scene = self.frame_scene(index, &Self::centres(rig, &world_from_rig));
        // Only an ERP camera's range image can double as the ground truth.
        let output_cam = rig.cameras.iter().position(|c| {
            c.projection.is_equirectangular() && same_pose(&c.rig_from_cam, &rig.rig_from_output)
        });
        let mut images = Vec::with_capacity(rig.cameras.len());
        // Where each camera sees (None: every pixel, an ERP panorama), for the soiling.
        let mut masks: Vec<Option<Vec<bool>>> = Vec::with_capacity(rig.cameras.len());
        let mut gt: Option<(FloatImage, SceneLabels)> = None;
        for (ci, cam) in rig.cameras.iter().enumerate() {
            let world_from_cam = world_from_rig * cam.rig_from_cam;
            if let Some(rays) = PixelRays::of_projection(&cam.projection) {
                let (img, _) = camera_view::render_rays(&scene, &world_from_cam, &rays, |c| {
                    to_srgb8(&self.gamma_lut, c)
                });
                images.push(img);
                masks.push(Some(rays.valid_mask()));
                continue;
            }
            let keep_range = output_cam == Some(ci);
            let (img, range) = self.render_view(&scene, &world_from_cam, keep_range);
            images.push(img);
            masks.push(None);
            if keep_range {
                gt = range;
            }
        }
        let (gt, labels) = match gt {
            Some(g) => g,
            None => self.render_range(&scene, &(world_from_rig * rig.rig_from_output)),
        };
        let mut blocked = vec![0.0; images.len()];
        for lens in &self.cfg.blockers {
            if let (Some(cam), Some(img)) =
                (rig.cameras.get(lens.camera), images.get_mut(lens.camera))
            {
                blocked[lens.camera] =
                    blockers::block_image(img, &cam.projection, lens, self.cfg.seed);
            }
        }
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
                soiling[c] = match &masks[c] {
                    None => soiling::soil_image(&mut images[c], &mut rng),
                    Some(mask) => soiling::soil_image_within(&mut images[c], mask, &mut rng),
                };
            }
        }
        let stamp_ns = self.frame_stamp_ns(index);
        (
            RigFrame {
                stamp_ns,
                images,
                ground_truth: Some(gt),
                labels: Some(labels),
            },
            FrameReport {
                index,
                stamp_ns,
                time_s: t_s,
                world_from_rig,
                soiling,
                blocked,
            },
        )
    }

    /// One clean ERP view from an arbitrary camera pose at the time of frame `index`, with
    /// its own range image (same conventions as the ground truth). The scene is the one
    /// around the rig's position at that frame (for objects scenes: the one rendered for any
    /// rig whose cameras lie in [`objects::standard_rig_zone`], if this camera does too).
    pub fn render_camera(&self, index: usize, world_from_cam: &Isometry3<f64>) -> CameraView {
        let scene = self.frame_scene(index, &[world_from_cam.translation.vector]);
        let (image, range) = self.render_view(&scene, world_from_cam, true);
        let range_m = range.map_or_else(
            || FloatImage::filled(self.grid.width(), self.grid.height(), f32::NAN),
            |(range, _)| range,
        );
        CameraView { image, range_m }
    }

    /// Camera `camera` of `rig` (rig order) at frame `index`, clean, in the scene
    /// [`Self::render_frame`] renders for that rig: its image (an ERP panorama at the
    /// configured width, or the camera model's image) and the range along every pixel's ray
    /// from the ray's origin, metres (NaN where the model sees nothing). `None` when `rig`
    /// has no such camera. For checking the rendering against the ground truth.
    pub fn render_rig_camera(&self, rig: &Rig, index: usize, camera: usize) -> Option<CameraView> {
        let cam = rig.cameras.get(camera)?;
        let world_from_rig = self.world_from_rig(index);
        let scene = self.frame_scene(index, &Self::centres(rig, &world_from_rig));
        let world_from_cam = world_from_rig * cam.rig_from_cam;
        let (image, range_m) = match PixelRays::of_projection(&cam.projection) {
            Some(rays) => camera_view::render_rays(&scene, &world_from_cam, &rays, |c| {
                to_srgb8(&self.gamma_lut, c)
            }),
            None => {
                let (image, range) = self.render_view(&scene, &world_from_cam, true);
                let range_m = range.map_or_else(
                    || FloatImage::filled(self.grid.width(), self.grid.height(), f32::NAN),
                    |(range, _)| range,
                );
                (image, range_m)
            }
        };
        Some(CameraView { image, range_m })
    }

    /// The blocked fraction of each camera of `rig` (rig order, 0 without a blocker): what
    /// every frame's [`FrameReport::blocked`] holds, without rendering.
    pub fn blocked_fractions(&self, rig: &Rig) -> Vec<f64> {
        let mut blocked = vec![0.0; rig.cameras.len()];
        for lens in &self.cfg.blockers {
            if let Some(cam) = rig.cameras.get(lens.camera) {
                blocked[lens.camera] =
                    blockers::lens_mask(lens, &cam.projection, self.grid.width(), self.cfg.seed)
                        .fraction;
            }
        }
        blocked
    }

    /// World-frame centres of the rig's cameras and of its output frame at `world_from_rig`.
    fn centres(rig: &Rig, world_from_rig: &Isometry3<f64>) -> Vec<Vector3<f64>> {
        let mut centres: Vec<Vector3<f64>> = rig
            .cameras
            .iter()
            .map(|c| (world_from_rig * c.rig_from_cam).translation.vector)
            .collect();
        centres.push((world_from_rig * rig.rig_from_output).translation.vector);
        centres
    }

    /// The scene of frame `index`; `camera_centres_w` (world frame) shape the keep-out box
    /// of objects scenes.
    fn frame_scene(&self, index: usize, camera_centres_w: &[Vector3<f64>]) -> FrameScene<'_> {
        let pixel_angle_rad = std::f64::consts::PI / self.grid.height() as f64;
        match self.cfg.scene {
            SceneKind::Street => FrameScene {
                bvh: Bvh::build(world::scene_prims(
                    &self.params,
                    self.world_from_rig(index).translation.x,
                    VIEW_RANGE_M,
                    self.frame_time_s(index),
                )),
                ground: Ground::Street(&self.params),
                background: Background::Sky,
                sun_dir: self.params.sun_dir,
                tex_seed: self.params.tex_seed,
                pixel_angle_rad,
                max_depth_m: self.cfg.max_depth_m,
                specular: self.params.clutter,
            },
            SceneKind::Objects => {
                let keep_out = objects::keep_out_box(camera_centres_w);
                let o = objects::objects_scene(self.cfg.seed, index, &keep_out);
                FrameScene {
                    bvh: Bvh::build(o.prims),
                    ground: match o.ground {
                        Some((z_m, material)) => Ground::Plane { z_m, material },
                        None => Ground::None,
                    },
                    background: o.background,
                    sun_dir: o.sun_dir,
                    tex_seed: self.params.tex_seed,
                    pixel_angle_rad,
                    max_depth_m: self.cfg.max_depth_m,
                    specular: false,
                }
            }
        }
    }

    /// One ERP view: the image and, with `keep_range`, its range image and labels.
    fn render_view(
        &self,
        scene: &FrameScene,
        world_from_cam: &Isometry3<f64>,
        keep_range: bool,
    ) -> (RgbImage, Option<(FloatImage, SceneLabels)>) {
        let (w, h) = (self.grid.width(), self.grid.height());
        let origin = world_from_cam.translation.vector;
        let rot = world_from_cam.rotation;
        let mut rgb = vec![0u8; w * h * 3];
        let mut range = vec![0f32; w * h];
        let mut labels = SceneLabels::sky(w, h);
        rgb.par_chunks_mut(w * 3)
            .zip(range.par_chunks_mut(w))
            .zip(labels.class.par_chunks_mut(w))
            .zip(labels.instance.par_chunks_mut(w))
            .enumerate()
            .for_each(|(v, (((row, row_range), row_class), row_instance))| {
                for u in 0..w {
                    let d = rot * self.dirs[v * w + u];
                    let s = scene.trace(&Ray::new(origin, d));
                    for i in 0..3 {
                        row[3 * u + i] = to_srgb8(&self.gamma_lut, s.colour[i]);
                    }
                    row_range[u] = s.range_m as f32;
                    row_class[u] = s.label.class;
                    row_instance[u] = s.label.instance;
                }
            });
        let img = RgbImage::from_raw(w as u32, h as u32, rgb)
            .unwrap_or_else(|| RgbImage::new(w as u32, h as u32));
        let range = keep_range.then_some((
            FloatImage {
                width: w,
                height: h,
                data: range,
            },
            labels,
        ));
        (img, range)
    }

    /// The range image and labels of an ERP view at `world_from_out`.
    fn render_range(
        &self,
        scene: &FrameScene,
        world_from_out: &Isometry3<f64>,
    ) -> (FloatImage, SceneLabels) {
        let (w, h) = (self.grid.width(), self.grid.height());
        let origin = world_from_out.translation.vector;
        let rot = world_from_out.rotation;
        let mut data = vec![0f32; w * h];
        let mut labels = SceneLabels::sky(w, h);
        data.par_chunks_mut(w)
            .zip(labels.class.par_chunks_mut(w))
            .zip(labels.instance.par_chunks_mut(w))
            .enumerate()
            .for_each(|(v, ((row, row_class), row_instance))| {
                for u in 0..w {
                    let d = rot * self.dirs[v * w + u];
                    let (range_m, label) = scene.range_and_label(&Ray::new(origin, d));
                    row[u] = range_m as f32;
                    row_class[u] = label.class;
                    row_instance[u] = label.instance;
                }
            });
        (
            FloatImage {
                width: w,
                height: h,
                data,
            },
            labels,
        )
    }
}
