//! Rendering cameras of any model, not only ERP panoramas: for every pixel of a fisheye or
//! dual-fisheye image, the camera model's ray (camera frame) is moved into the world and cast
//! into the frame's scene. Pixels the model cannot unproject (outside the lens circle or the
//! model's unprojection region) stay black, `(0, 0, 0)`, and have no range (NaN).
//!
//! A single fisheye camera's rays start at the camera frame's origin; a dual-fisheye pixel's
//! ray starts at its lens's centre (`cam_from_lens` translation, a few centimetres from the
//! camera origin: see [`DualFisheye::unproject_ray`]).

use super::bvh::Ray;
use super::scene::FrameScene;
use mode360_core::frame::{FloatImage, RgbImage};
use mode360_core::geometry::camera::{CameraModel, DualFisheye, FisheyeCamera};
use mode360_core::geometry::{PixelCoord, Projection};
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

/// Colour of pixels the camera model does not see.
pub const UNSEEN_RGB: [u8; 3] = [0, 0, 0];

/// A pixel's ray in the camera frame: where it starts and its unit direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraRay {
    pub origin: Vector3<f64>,
    pub dir: Vector3<f64>,
}

/// The ray of every pixel of a non-ERP camera image (row-major), `None` where the model sees
/// nothing. Built once per camera and frame; a pure function of the camera model.
#[derive(Clone, Debug)]
pub struct PixelRays {
    pub width: usize,
    pub height: usize,
    rays: Vec<Option<CameraRay>>,
}

impl PixelRays {
    /// The rays of a fisheye or dual-fisheye camera; `None` for an equirectangular one (its
    /// pixels come from the renderer's ERP grid at the configured width).
    pub fn of_projection(projection: &Projection) -> Option<Self> {
        match projection {
            Projection::Equirectangular => None,
            Projection::Fisheye(cam) => Some(Self::fisheye(cam)),
            Projection::DualFisheye(dual) => Some(Self::dual_fisheye(dual)),
        }
    }

    fn build(model: &dyn CameraModel, ray_of: impl Fn(PixelCoord) -> Option<CameraRay>) -> Self {
        let size = model.image_size();
        let (width, height) = (size.width as usize, size.height as usize);
        let mut rays = Vec::with_capacity(width * height);
        for v in 0..height {
            for u in 0..width {
                rays.push(ray_of(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                }));
            }
        }
        Self {
            width,
            height,
            rays,
        }
    }

    /// One lens: rays from the camera origin.
    pub fn fisheye(cam: &FisheyeCamera) -> Self {
        Self::build(cam, |px| {
            cam.unproject(px).map(|dir| CameraRay {
                origin: Vector3::zeros(),
                dir: dir.into_inner(),
            })
        })
    }

    /// Two lenses: rays from each lens's centre.
    pub fn dual_fisheye(dual: &DualFisheye) -> Self {
        Self::build(dual, |px| {
            dual.unproject_ray(px).map(|r| CameraRay {
                origin: r.origin.coords,
                dir: r.dir.into_inner(),
            })
        })
    }

    /// The ray of pixel `(u, v)` (`None` off the image or where the model sees nothing).
    pub fn get(&self, u: usize, v: usize) -> Option<CameraRay> {
        if u >= self.width || v >= self.height {
            return None;
        }
        self.rays[v * self.width + u]
    }

    /// `true` for every pixel the model sees (row-major).
    pub fn valid_mask(&self) -> Vec<bool> {
        self.rays.iter().map(Option::is_some).collect()
    }
}

/// Renders the image of `rays` from `world_from_cam`: colour (black where unseen) and the
/// range along each pixel's ray from its origin, metres (NaN where unseen).
pub(crate) fn render_rays(
    scene: &FrameScene,
    world_from_cam: &Isometry3<f64>,
    rays: &PixelRays,
    encode: impl Fn(f32) -> u8 + Sync,
) -> (RgbImage, FloatImage) {
    let (w, h) = (rays.width, rays.height);
    let mut rgb = vec![0u8; w * h * 3];
    let mut range = vec![f32::NAN; w * h];
    rgb.par_chunks_mut(w * 3)
        .zip(range.par_chunks_mut(w))
        .enumerate()
        .for_each(|(v, (row, row_range))| {
            for u in 0..w {
                let Some(r) = rays.rays[v * w + u] else {
                    row[3 * u..3 * u + 3].copy_from_slice(&UNSEEN_RGB);
                    continue;
                };
                let origin = world_from_cam * nalgebra::Point3::from(r.origin);
                let dir = world_from_cam.rotation * r.dir;
                let s = scene.trace(&Ray::new(origin.coords, dir));
                for i in 0..3 {
                    row[3 * u + i] = encode(s.colour[i]);
                }
                row_range[u] = s.range_m as f32;
            }
        });
    let img = RgbImage::from_raw(w as u32, h as u32, rgb)
        .unwrap_or_else(|| RgbImage::new(w as u32, h as u32));
    (
        img,
        FloatImage {
            width: w,
            height: h,
            data: range,
        },
    )
}
