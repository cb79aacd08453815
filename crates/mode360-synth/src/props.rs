//! Street furniture built from primitives: cars and pedestrians, and small helpers.

use super::bvh::{Aabb, Prim, PrimLabel, Shape};
use super::colour::Rgb;
use super::material::{Material, SurfacePrim};
use super::noise::Rng;
use super::street::KERB_HEIGHT_M;
use nalgebra::Vector3;

const CAR_COLOURS: [Rgb; 8] = [
    [0.6, 0.05, 0.04],
    [0.05, 0.12, 0.4],
    [0.7, 0.7, 0.72],
    [0.08, 0.08, 0.09],
    [0.85, 0.85, 0.82],
    [0.15, 0.3, 0.15],
    [0.55, 0.45, 0.1],
    [0.3, 0.32, 0.35],
];
const CLOTHES_COLOURS: [Rgb; 6] = [
    [0.1, 0.1, 0.3],
    [0.5, 0.1, 0.1],
    [0.1, 0.1, 0.1],
    [0.6, 0.55, 0.4],
    [0.2, 0.4, 0.2],
    [0.7, 0.7, 0.7],
];
const SKIN_COLOURS: [Rgb; 3] = [[0.8, 0.6, 0.5], [0.55, 0.38, 0.28], [0.35, 0.22, 0.15]];

pub(crate) fn aabox(min: [f64; 3], max: [f64; 3]) -> Shape {
    Shape::Box(Aabb {
        min: Vector3::from(min),
        max: Vector3::from(max),
    })
}

pub(crate) fn push(
    out: &mut Vec<SurfacePrim>,
    shape: Shape,
    material: Material,
    origin: Vector3<f64>,
) {
    out.push(Prim {
        shape,
        material,
        object_origin: origin,
        label: PrimLabel::Structure,
    });
}

/// The id the next object instance of `out` gets: one more than the last object's (objects
/// are appended whole, so ids rise along `out`).
fn next_object_id(out: &[SurfacePrim]) -> u16 {
    out.iter()
        .rev()
        .find_map(|p| match p.label {
            PrimLabel::Object(id) => Some(id.saturating_add(1)),
            _ => None,
        })
        .unwrap_or(1)
}

/// Makes `out[start..]` (the primitives of one thing just pushed) one new object instance.
pub(crate) fn tag_object(out: &mut [SurfacePrim], start: usize) {
    let id = next_object_id(&out[..start.min(out.len())]);
    for p in out.iter_mut().skip(start) {
        p.label = PrimLabel::Object(id);
    }
}

/// Marks `out[start..]` as part of the ground surface (sidewalk slabs).
pub(crate) fn tag_ground(out: &mut [SurfacePrim], start: usize) {
    for p in out.iter_mut().skip(start) {
        p.label = PrimLabel::Ground;
    }
}

/// A car of length `len` centred at `(x, y)` facing along x.
pub(crate) fn car(out: &mut Vec<SurfacePrim>, x: f64, y: f64, rng: &mut Rng) {
    let start = out.len();
    let len = rng.range(3.9, 4.8);
    let half_w = rng.range(0.82, 0.92);
    let colour = CAR_COLOURS[rng.index(CAR_COLOURS.len())];
    let roof = rng.range(1.4, 1.6);
    let origin = Vector3::new(x, y, 0.0);
    let body_top = 0.95;
    push(
        out,
        aabox(
            [x - len / 2.0, y - half_w, 0.3],
            [x + len / 2.0, y + half_w, body_top],
        ),
        Material::CarPaint(colour),
        origin,
    );
    let cab_front = x + len * rng.range(0.05, 0.15);
    let cab_back = x - len * rng.range(0.3, 0.4);
    push(
        out,
        aabox(
            [cab_back, y - half_w + 0.1, body_top],
            [cab_front, y + half_w - 0.1, roof - 0.06],
        ),
        Material::CarGlass,
        origin,
    );
    push(
        out,
        aabox(
            [cab_back + 0.05, y - half_w + 0.12, roof - 0.06],
            [cab_front - 0.05, y + half_w - 0.12, roof],
        ),
        Material::CarPaint(colour),
        origin,
    );
    let wheel_r = 0.33;
    for dx in [-0.33 * len, 0.31 * len] {
        for sy in [-1.0, 1.0] {
            push(
                out,
                Shape::Cylinder {
                    centre: Vector3::new(x + dx, y + sy * (half_w - 0.12), wheel_r),
                    axis: 1,
                    radius_m: wheel_r,
                    half_length_m: 0.12,
                },
                Material::Tyre,
                origin,
            );
        }
    }
    tag_object(out, start);
}

/// A pedestrian standing at `(x, y)` on the sidewalk, walking along x with gait phase `phase`.
pub(crate) fn pedestrian(out: &mut Vec<SurfacePrim>, x: f64, y: f64, phase: f64, rng: &mut Rng) {
    let start = out.len();
    let z0 = KERB_HEIGHT_M;
    let height = rng.range(1.6, 1.9);
    let clothes = CLOTHES_COLOURS[rng.index(CLOTHES_COLOURS.len())];
    let trousers = CLOTHES_COLOURS[rng.index(CLOTHES_COLOURS.len())];
    let skin = SKIN_COLOURS[rng.index(SKIN_COLOURS.len())];
    let origin = Vector3::new(x, y, z0);
    let leg_h = 0.47 * height;
    let swing = 0.18 * phase.sin();
    for (sy, dx) in [(-1.0, swing), (1.0, -swing)] {
        push(
            out,
            aabox(
                [x + dx - 0.07, y + sy * 0.11 - 0.07, z0],
                [x + dx + 0.07, y + sy * 0.11 + 0.07, z0 + leg_h],
            ),
            Material::Clothes(trousers),
            origin,
        );
    }
    let torso_top = z0 + 0.82 * height;
    push(
        out,
        aabox(
            [x - 0.13, y - 0.22, z0 + leg_h],
            [x + 0.13, y + 0.22, torso_top],
        ),
        Material::Clothes(clothes),
        origin,
    );
    let head_r = 0.5 * (height * 0.18 - 0.02);
    push(
        out,
        Shape::Sphere {
            centre: Vector3::new(x, y, torso_top + 0.02 + head_r),
            radius_m: head_r,
        },
        Material::Skin(skin),
        origin,
    );
    tag_object(out, start);
}
