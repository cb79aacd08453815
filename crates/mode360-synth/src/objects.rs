//! Random-objects scenes (like OmniMVS's OmniThings): for frame `index` of world `seed`, 30 to
//! 80 textured primitives (spheres, and boxes, ellipsoids and cylinders at random
//! orientations) in every direction around the rig, at log-uniform distances from 0.5 m to
//! 300 m and sized to span 8 to 80 degrees (nearby ones at most about 30), over a random background at infinity and, in
//! half the frames, a textured ground plane at a random height below the cameras. Nothing in
//! such a frame is predictable from what one panorama looks like, so depth must come from
//! parallax.
//!
//! The arrangement is a pure function of `(seed, index)` and the keep-out box: no object's
//! bounding box enters the box around the rig's cameras grown by [`KEEP_OUT_M`] (objects
//! that would are pushed outwards along their direction). The box always contains
//! [`standard_rig_zone`], which holds every camera of the Deep360 rig and of the training
//! code's random rigs, so for those rigs the scene depends on `(seed, index)` only.

use super::bvh::{Aabb, OrientedKind, Prim, PrimLabel, Shape};
use super::colour::Rgb;
use super::material::{Material, SurfacePrim};
use super::noise::Rng;
use super::pattern::{random_colour, random_unit, Background, Pattern};
use nalgebra::{UnitQuaternion, Vector3};

/// Every object surface and the ground plane stay at least this far from each camera centre.
pub const KEEP_OUT_M: f64 = 0.3;
/// Object centres lie log-uniformly between these distances from the rig, metres.
pub const MIN_OBJECT_DISTANCE_M: f64 = 0.5;
pub const MAX_OBJECT_DISTANCE_M: f64 = 300.0;
/// Objects per frame (inclusive range).
pub const MIN_OBJECTS: usize = 30;
pub const MAX_OBJECTS: usize = 80;
/// Angular half size of an object seen from the rig, radians (log-uniform).
const MIN_HALF_ANGLE_RAD: f64 = 0.07;
const MAX_HALF_ANGLE_RAD: f64 = 0.7;
/// Nearer than this the largest half angle shrinks like `(d / this)^0.25`, metres.
const FULL_SIZE_DISTANCE_M: f64 = 20.0;
/// Probability of a ground plane, and its gap below the keep-out box (log-uniform), metres.
const GROUND_PROBABILITY: f64 = 0.5;
const MIN_GROUND_GAP_M: f64 = 0.05;
const MAX_GROUND_GAP_M: f64 = 3.0;
/// Probability that the background is the street scenes' sky rather than a pattern.
const SKY_BACKGROUND_PROBABILITY: f64 = 0.25;
/// Pushing an object out of the keep-out box: at most this many steps.
const PUSH_STEPS: usize = 200;

/// The rig-frame box that holds the cameras of the Deep360 rig (1 m square, 1.8 m high) and of
/// the training code's random rigs (1.5 m square, 1.5 to 2.2 m high).
pub fn standard_rig_zone() -> Aabb {
    Aabb {
        min: Vector3::new(-0.75, -0.75, 1.5),
        max: Vector3::new(0.75, 0.75, 2.2),
    }
}

/// The keep-out box around camera centres `points` (world frame, rig frame = world in
/// objects scenes): the standard rig zone and the points, grown by [`KEEP_OUT_M`].
pub fn keep_out_box(points: &[Vector3<f64>]) -> Aabb {
    let b = points.iter().fold(standard_rig_zone(), |b, p| {
        b.union(&Aabb { min: *p, max: *p })
    });
    Aabb {
        min: b.min - Vector3::repeat(KEEP_OUT_M),
        max: b.max + Vector3::repeat(KEEP_OUT_M),
    }
}

/// A random-objects frame: primitives, optional ground plane, background and sun.
#[derive(Clone, Debug)]
pub struct ObjectsScene {
    pub prims: Vec<SurfacePrim>,
    /// Height and material of the ground plane, if any.
    pub ground: Option<(f64, Material)>,
    pub background: Background,
    pub sun_dir: Vector3<f64>,
}

fn overlaps(a: &Aabb, b: &Aabb) -> bool {
    (0..3).all(|i| a.min[i] < b.max[i] && b.min[i] < a.max[i])
}

fn log_uniform(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    rng.range(lo.ln(), hi.ln()).exp()
}

/// A uniformly random rotation (Shoemake's method).
fn random_rotation(rng: &mut Rng) -> UnitQuaternion<f64> {
    let (u1, u2, u3) = (rng.unit(), rng.unit(), rng.unit());
    let tau = std::f64::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        b * (tau * u3).cos(),
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
    ))
}

/// A random surface: mostly a high-contrast [`Pattern`] with features a fraction of the
/// object's size `size_m`, sometimes one of the street materials.
fn random_material(rng: &mut Rng, size_m: f64) -> Material {
    if rng.chance(0.75) {
        let lo = (0.04 * size_m).max(0.01);
        return Material::Pattern(Pattern::random(rng, lo, (0.6 * size_m).max(2.0 * lo)));
    }
    let c: Rgb = random_colour(rng);
    match rng.index(7) {
        0 => Material::Concrete,
        1 => Material::Foliage(c),
        2 => Material::Bark,
        3 => Material::CarPaint(c),
        4 => Material::Clothes(c),
        5 => Material::Paving,
        _ => Material::Facade {
            wall: c,
            floor_height_m: rng.range(0.3, 3.6) as f32,
            bay_width_m: rng.range(0.3, 3.4) as f32,
            seed: (rng.next_u64() >> 40) as u32,
        },
    }
}

/// A random shape of size `s` (largest half extent) centred at `c`.
fn random_shape(rng: &mut Rng, c: Vector3<f64>, s: f64) -> Shape {
    if rng.chance(0.2) {
        return Shape::Sphere {
            centre: c,
            radius_m: s,
        };
    }
    let kind = match rng.index(3) {
        0 => OrientedKind::Box,
        1 => OrientedKind::Ellipsoid,
        _ => OrientedKind::Cylinder,
    };
    let mut h = Vector3::new(s, s * rng.range(0.2, 1.0), s * rng.range(0.2, 1.0));
    if kind == OrientedKind::Box && rng.chance(0.25) {
        // A thin plate.
        h.z = s * rng.range(0.01, 0.08);
    }
    if kind == OrientedKind::Cylinder {
        // Radius h.x, half length h.z: rods to discs.
        h.x = s * rng.range(0.1, 1.0);
        h.z = s;
    }
    let rot = random_rotation(rng);
    Shape::Oriented {
        kind,
        centre: c,
        half_extents_m: h,
        local_from_world: rot.inverse().to_rotation_matrix().into_inner(),
    }
}

/// Frame `index` of world `seed` with keep-out box `keep_out` (see [`keep_out_box`]).
pub fn objects_scene(seed: u64, index: usize, keep_out: &Aabb) -> ObjectsScene {
    let mut rng = Rng::new(&[seed, index as u64, 0x00B1_EC75]);
    let centre = keep_out.centre();
    let sun_azimuth = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
    let sun_elevation = rng.range(0.3, 1.4);
    let sun_dir = Vector3::new(
        sun_elevation.cos() * sun_azimuth.cos(),
        sun_elevation.cos() * sun_azimuth.sin(),
        sun_elevation.sin(),
    );
    let ground = rng.chance(GROUND_PROBABILITY).then(|| {
        let z = keep_out.min.z - log_uniform(&mut rng, MIN_GROUND_GAP_M, MAX_GROUND_GAP_M);
        (z, Material::Pattern(Pattern::random(&mut rng, 0.05, 3.0)))
    });
    let background = if rng.chance(SKY_BACKGROUND_PROBABILITY) {
        Background::Sky
    } else {
        Background::Pattern(Pattern::random(&mut rng, 0.03, 0.6))
    };
    let count = MIN_OBJECTS + rng.index(MAX_OBJECTS - MIN_OBJECTS + 1);
    let mut prims = Vec::with_capacity(count);
    for _ in 0..count {
        let mut dir = random_unit(&mut rng);
        let dist = log_uniform(&mut rng, MIN_OBJECT_DISTANCE_M, MAX_OBJECT_DISTANCE_M);
        if let Some((gz, _)) = ground {
            // Objects whose centre would be under the ground go above it instead.
            if centre.z + dir.z * dist < gz {
                dir.z = dir.z.abs();
            }
        }
        // Near objects are kept a little smaller so they do not hide everything behind them.
        let max_half_angle = MAX_HALF_ANGLE_RAD * (dist / FULL_SIZE_DISTANCE_M).powf(0.25).min(1.0);
        let half_angle = log_uniform(&mut rng, MIN_HALF_ANGLE_RAD, max_half_angle);
        let size = (dist * half_angle.tan()).max(0.03);
        let mut c = centre + dir * dist;
        let shape0 = random_shape(&mut rng, Vector3::zeros(), size);
        let material = random_material(&mut rng, size);
        let at = |c: Vector3<f64>| match shape0 {
            Shape::Sphere { radius_m, .. } => Shape::Sphere {
                centre: c,
                radius_m,
            },
            Shape::Oriented {
                kind,
                half_extents_m,
                local_from_world,
                ..
            } => Shape::Oriented {
                kind,
                centre: c,
                half_extents_m,
                local_from_world,
            },
            other => other,
        };
        let step = 0.05 + 0.1 * size;
        let mut shape = at(c);
        let mut steps = 0;
        while overlaps(&shape.aabb(), keep_out) && steps < PUSH_STEPS {
            c += dir * step;
            shape = at(c);
            steps += 1;
        }
        if overlaps(&shape.aabb(), keep_out) {
            continue;
        }
        let id = u16::try_from(prims.len() + 1).unwrap_or(u16::MAX);
        prims.push(Prim {
            shape,
            material,
            object_origin: c,
            label: PrimLabel::Object(id),
        });
    }
    ObjectsScene {
        prims,
        ground,
        background,
        sun_dir,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objects_stay_out_of_the_keep_out_box_and_are_deterministic() {
        let keep = keep_out_box(&[Vector3::new(0.5, 0.5, 1.8)]);
        for index in 0..20 {
            let a = objects_scene(3, index, &keep);
            let b = objects_scene(3, index, &keep);
            assert!(a.prims.len() >= MIN_OBJECTS - 2 && a.prims.len() <= MAX_OBJECTS);
            assert_eq!(a.prims.len(), b.prims.len());
            for (p, q) in a.prims.iter().zip(&b.prims) {
                assert_eq!(p.shape, q.shape);
                assert_eq!(p.material, q.material);
                assert!(!overlaps(&p.shape.aabb(), &keep));
            }
            if let Some((z, _)) = a.ground {
                assert!(z <= keep.min.z);
            }
        }
    }
}
