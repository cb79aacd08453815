//! A small analytic test world for the photometric sweep: an open-topped textured courtyard
//! (ground plane and four walls), a textured sphere and a textured box, a textured sky at
//! infinity. Rendered by ray casting with 2x2 supersampling; ground truth is exact range.
#![allow(dead_code)]

use mode360::frame::{FloatImage, RgbImage};
use mode360::geometry::{ErpGrid, PixelCoord, Rig};
use nalgebra::{Point3, Vector3};

/// Courtyard half-extents and wall height, metres (rig frame, ground at z = 0).
const YARD_MIN: [f64; 2] = [-12.0, -7.0];
const YARD_MAX: [f64; 2] = [25.0, 8.0];
const WALL_HEIGHT_M: f64 = 7.0;
const SPHERE_CENTRE: [f64; 3] = [5.0, -2.5, 1.5];
const SPHERE_RADIUS_M: f64 = 1.2;
const BOX_MIN: [f64; 3] = [-5.0, 2.0, 0.0];
const BOX_MAX: [f64; 3] = [-3.0, 3.5, 2.2];
/// Supersampling per axis.
const SUBSAMPLES: usize = 2;

/// Lattice hash in [0, 1).
fn hash3(i: i64, j: i64, k: i64, salt: u64) -> f64 {
    let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (k as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ salt.wrapping_mul(0x27D4_EB2F_1656_67C5);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Trilinear value noise with smoothstep weights, in [0, 1).
fn value_noise(p: Vector3<f64>, salt: u64) -> f64 {
    let f = p.map(f64::floor);
    let t = (p - f).map(|x| x * x * (3.0 - 2.0 * x));
    let (i, j, k) = (f.x as i64, f.y as i64, f.z as i64);
    let mut acc = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let w = if dx == 1 { t.x } else { 1.0 - t.x }
                    * if dy == 1 { t.y } else { 1.0 - t.y }
                    * if dz == 1 { t.z } else { 1.0 - t.z };
                acc += w * hash3(i + dx, j + dy, k + dz, salt);
            }
        }
    }
    acc
}

/// Multi-octave texture in [0, 1) at world point `p` with feature size `scale_m`.
fn texture(p: Vector3<f64>, scale_m: f64, salt: u64) -> f64 {
    let mut sum = 0.0;
    let mut amp = 0.5;
    let mut norm = 0.0;
    let mut s = scale_m;
    for octave in 0..3 {
        sum += amp * value_noise(p / s, salt + octave);
        norm += amp;
        amp *= 0.5;
        s *= 0.45;
    }
    sum / norm
}

/// What a ray hits: distance (infinite for sky) and colour.
struct Hit {
    t: f64,
    rgb: [f64; 3],
}

fn surface_colour(p: Vector3<f64>, tint: [f64; 3], scale_m: f64, salt: u64) -> [f64; 3] {
    let a = texture(p, scale_m, salt);
    let b = texture(p, scale_m * 2.0, salt + 17);
    let l = 0.15 + 0.85 * a;
    [
        l * tint[0] * (0.7 + 0.3 * b),
        l * tint[1],
        l * tint[2] * (1.3 - 0.3 * b),
    ]
}

fn cast(origin: Vector3<f64>, dir: Vector3<f64>) -> Hit {
    let mut best = Hit {
        t: f64::INFINITY,
        rgb: [0.0; 3],
    };
    let mut consider = |t: f64, make: &dyn Fn(Vector3<f64>) -> [f64; 3]| {
        if t > 1e-6 && t < best.t {
            best = Hit {
                t,
                rgb: make(origin + dir * t),
            };
        }
    };
    // Ground.
    if dir.z < 0.0 {
        consider(-origin.z / dir.z, &|p| {
            surface_colour(p, [0.8, 0.8, 0.75], 0.5, 1)
        });
    }
    // Walls: the exit plane of the courtyard along x and y.
    for axis in 0..2 {
        let d = dir[axis];
        if d.abs() < 1e-12 {
            continue;
        }
        let wall = if d > 0.0 {
            YARD_MAX[axis]
        } else {
            YARD_MIN[axis]
        };
        let t = (wall - origin[axis]) / d;
        let z = origin.z + t * dir.z;
        if (0.0..WALL_HEIGHT_M).contains(&z) {
            let salt = 3 + axis as u64 * 2 + u64::from(d > 0.0);
            let tint = [[0.9, 0.6, 0.5], [0.6, 0.8, 0.9]][axis];
            consider(t, &|p| surface_colour(p, tint, 0.8, salt));
        }
    }
    // Sphere.
    let c = Vector3::from(SPHERE_CENTRE);
    let oc = origin - c;
    let b = oc.dot(&dir);
    let disc = b * b - (oc.norm_squared() - SPHERE_RADIUS_M * SPHERE_RADIUS_M);
    if disc >= 0.0 {
        consider(-b - disc.sqrt(), &|p| {
            surface_colour(p, [0.9, 0.9, 0.4], 0.3, 11)
        });
    }
    // Box (slabs).
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        let inv = 1.0 / dir[a];
        let (mut ta, mut tb) = (
            (BOX_MIN[a] - origin[a]) * inv,
            (BOX_MAX[a] - origin[a]) * inv,
        );
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        t0 = t0.max(ta);
        t1 = t1.min(tb);
    }
    if t0 <= t1 && t0 > 0.0 {
        consider(t0, &|p| surface_colour(p, [0.5, 0.9, 0.5], 0.25, 13));
    }
    if best.t.is_infinite() {
        // Sky at infinity: texture on the direction only, so every camera agrees.
        let a = texture(dir * 6.0, 1.0, 21);
        let up = dir.z.max(0.0);
        best.rgb = [0.45 + 0.4 * a, 0.6 + 0.3 * a, 0.85 + 0.1 * a * (1.0 - up)];
    }
    best
}

/// A rendered frame of the analytic world.
pub struct SceneFrame {
    pub images: Vec<RgbImage>,
    /// Exact range of each output-frame pixel centre (sky: `max_depth_m`).
    pub ground_truth: FloatImage,
}

/// Renders every camera of `rig` and the ground truth of its output frame at `width`.
pub fn render(
    rig: &Rig,
    width: usize,
    max_depth_m: f64,
) -> Result<SceneFrame, Box<dyn std::error::Error>> {
    let grid = ErpGrid::new(width)?;
    let mut images = Vec::new();
    for cam in &rig.cameras {
        let pose = cam.rig_from_cam;
        let origin = pose.translation.vector;
        let mut img = RgbImage::new(grid.width() as u32, grid.height() as u32);
        for (u, v, px) in img.enumerate_pixels_mut() {
            let mut rgb = [0.0; 3];
            for sy in 0..SUBSAMPLES {
                for sx in 0..SUBSAMPLES {
                    let p = PixelCoord {
                        u: u as f64 + (sx as f64 + 0.5) / SUBSAMPLES as f64 - 0.5,
                        v: v as f64 + (sy as f64 + 0.5) / SUBSAMPLES as f64 - 0.5,
                    };
                    let dir = pose.rotation * grid.dir_from_pixel(p);
                    let hit = cast(origin, dir);
                    for (acc, c) in rgb.iter_mut().zip(hit.rgb) {
                        *acc += c;
                    }
                }
            }
            let n = (SUBSAMPLES * SUBSAMPLES) as f64;
            for (out, c) in px.0.iter_mut().zip(rgb) {
                *out = (c / n * 255.0).clamp(0.0, 255.0).round() as u8;
            }
        }
        images.push(img);
    }
    let out = rig.rig_from_output;
    let origin: Point3<f64> = out * Point3::origin();
    let mut gt = FloatImage::filled(grid.width(), grid.height(), 0.0);
    for v in 0..grid.height() {
        for u in 0..grid.width() {
            let dir = out.rotation
                * grid.dir_from_pixel(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                });
            let t = cast(origin.coords, dir).t;
            gt.data[v * grid.width() + u] = t.min(max_depth_m) as f32;
        }
    }
    Ok(SceneFrame {
        images,
        ground_truth: gt,
    })
}

/// Depth metrics over pixels with finite ground truth in (0, max_depth].
#[derive(Clone, Copy, Debug)]
pub struct DepthScores {
    pub delta1: f64,
    pub abs_rel: f64,
    pub mae_m: f64,
    pub rmse_m: f64,
    pub pixels: usize,
}

pub fn scores(pred: &FloatImage, gt: &FloatImage, max_depth_m: f64) -> DepthScores {
    let (mut n, mut good, mut abs_rel, mut abs, mut sq) = (0usize, 0usize, 0.0, 0.0, 0.0);
    for (&p, &g) in pred.data.iter().zip(&gt.data) {
        let (p, g) = (p as f64, g as f64);
        if !(g.is_finite() && g > 0.0 && g <= max_depth_m) {
            continue;
        }
        n += 1;
        if p.is_finite() && p > 0.0 && (p / g).max(g / p) < 1.25 {
            good += 1;
        }
        abs_rel += (p - g).abs() / g;
        abs += (p - g).abs();
        sq += (p - g) * (p - g);
    }
    let nf = n.max(1) as f64;
    DepthScores {
        delta1: good as f64 / nf,
        abs_rel: abs_rel / nf,
        mae_m: abs / nf,
        rmse_m: (sq / nf).sqrt(),
        pixels: n,
    }
}
