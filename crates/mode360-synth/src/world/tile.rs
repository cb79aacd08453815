//! The static content of one tile of road and one side of it: the sidewalk, the rows of
//! buildings, a tree, a street light and the parked cars, or at an intersection the corners
//! of the cross street.

use super::{
    cross_street_centre_m, is_intersection, StreetLayout, WorldParams, CORNER_SETBACK_M,
    FACADE_COLOURS, TILE_LENGTH_M,
};
use crate::bvh::Shape;
use crate::colour::Rgb;
use crate::material::{Material, SurfacePrim};
use crate::noise::Rng;
use crate::props::{aabox, car, push, tag_ground, tag_object};
use crate::street::{CROSS_STREET_HALF_WIDTH_M, KERB_HEIGHT_M};
use nalgebra::Vector3;

/// Up to `max_count` buildings filling `[x0, x1]` on side `s`, fronts `front_m` (plus a
/// random setback) from the road axis.
#[allow(clippy::too_many_arguments)]
fn building_row(
    out: &mut Vec<SurfacePrim>,
    rng: &mut Rng,
    layout: &StreetLayout,
    x0: f64,
    x1: f64,
    s: f64,
    back_row: bool,
    max_count: usize,
) {
    let front_m = if back_row {
        layout.back_row_front_m
    } else {
        layout.building_front_m
    };
    let count = 1 + rng.index(max_count);
    let mut x = x0;
    for b in 0..count {
        let remaining = x1 - x;
        let width = if b + 1 == count {
            remaining
        } else {
            remaining * rng.range(0.3, 0.7)
        };
        let gap = if rng.chance(0.3) {
            rng.range(1.0, 3.0)
        } else {
            0.0
        };
        let front = front_m
            + if rng.chance(0.4) {
                rng.range(0.5, 3.0)
            } else {
                0.0
            };
        let depth = rng.range(10.0, 16.0);
        let tall = if back_row { 0.4 } else { 0.2 };
        let mut height = if rng.chance(tall) {
            rng.range(22.0, 45.0)
        } else {
            rng.range(7.0, 20.0)
        };
        if layout.building_height_scale != 1.0 {
            height *= layout.building_height_scale;
        }
        let (ya, yb) = lo_hi(s * front, s * (front + depth));
        let bx0 = x + 0.5 * gap;
        let bx1 = (x + width - 0.5 * gap).max(bx0 + 1.0);
        let wall = FACADE_COLOURS[rng.index(FACADE_COLOURS.len())];
        let jitter = rng.range(0.85, 1.1) as f32;
        push(
            out,
            aabox([bx0, ya, 0.0], [bx1, yb, height]),
            Material::Facade {
                wall: [wall[0] * jitter, wall[1] * jitter, wall[2] * jitter],
                floor_height_m: rng.range(2.9, 3.6) as f32,
                bay_width_m: rng.range(2.2, 3.4) as f32,
                seed: (rng.next_u64() >> 40) as u32,
            },
            Vector3::new(bx0, ya, 0.0),
        );
        x += width;
    }
}

/// The span of one tile along x, `[x0_m, x1_m]`, on side `side` (+1 left, -1 right).
#[derive(Clone, Copy, Debug)]
struct TileSide {
    x0_m: f64,
    x1_m: f64,
    side: f64,
}

/// `(a, b)` in ascending order.
fn lo_hi(a: f64, b: f64) -> (f64, f64) {
    if a < b {
        (a, b)
    } else {
        (b, a)
    }
}

/// The sidewalk slab between `ya` and `yb` over `[x0_m, x1_m]`, labelled ground.
fn sidewalk_slab(out: &mut Vec<SurfacePrim>, x0_m: f64, x1_m: f64, ya: f64, yb: f64) {
    push(
        out,
        aabox([x0_m, ya, 0.0], [x1_m, yb, KERB_HEIGHT_M]),
        Material::Paving,
        Vector3::zeros(),
    );
}

/// An intersection tile's side: sidewalk corners up to the cross street, one corner
/// building (front and back rows) on either side of it, and a street light on one corner.
fn intersection_corners(
    out: &mut Vec<SurfacePrim>,
    l: &StreetLayout,
    tile: i64,
    span: TileSide,
    rng: &mut Rng,
) {
    let (x0, x1, s) = (span.x0_m, span.x1_m, span.side);
    let (ya, yb) = lo_hi(s * l.road_half_width_m, s * l.sidewalk_outer_m);
    let c = cross_street_centre_m(tile);
    let start = out.len();
    for (a, b) in [
        (x0, c - CROSS_STREET_HALF_WIDTH_M),
        (c + CROSS_STREET_HALF_WIDTH_M, x1),
    ] {
        sidewalk_slab(out, a, b, ya, yb);
    }
    tag_ground(out, start);
    // Corner buildings (front and back rows) on both sides of the cross street.
    let corner = CROSS_STREET_HALF_WIDTH_M + CORNER_SETBACK_M;
    for (a, b) in [(x0, c - corner), (c + corner, x1)] {
        building_row(out, rng, l, a, b, s, false, 1);
        building_row(out, rng, l, a, b, s, true, 1);
    }
    let px = c - CROSS_STREET_HALF_WIDTH_M - 1.0;
    let py = s * l.pole_y_m;
    let start = out.len();
    push(
        out,
        Shape::Cylinder {
            centre: Vector3::new(px, py, 3.0),
            axis: 2,
            radius_m: 0.09,
            half_length_m: 3.0,
        },
        Material::Metal,
        Vector3::new(px, py, 0.0),
    );
    tag_object(out, start);
}

/// A tree on the sidewalk of `span`: a trunk under two to four foliage blobs, one instance.
fn tree(out: &mut Vec<SurfacePrim>, l: &StreetLayout, span: TileSide, rng: &mut Rng) {
    let start = out.len();
    let tx = span.x0_m + rng.range(3.0, 9.0);
    let ty = span.side * (l.tree_y_m + rng.range(-0.2, 0.2));
    let trunk_h = rng.range(2.8, 3.8);
    let origin = Vector3::new(tx, ty, 0.0);
    push(
        out,
        Shape::Cylinder {
            centre: Vector3::new(tx, ty, 0.5 * trunk_h),
            axis: 2,
            radius_m: rng.range(0.14, 0.24),
            half_length_m: 0.5 * trunk_h,
        },
        Material::Bark,
        origin,
    );
    let green: Rgb = [
        rng.range(0.08, 0.16) as f32,
        rng.range(0.2, 0.32) as f32,
        rng.range(0.04, 0.1) as f32,
    ];
    let blobs = 2 + rng.index(3);
    for _ in 0..blobs {
        let r = rng.range(1.3, 2.2);
        let rz = r * rng.range(0.8, 1.2);
        let c = Vector3::new(
            tx + rng.range(-0.8, 0.8),
            ty + rng.range(-0.5, 0.5),
            trunk_h + rz * 0.5 + rng.range(0.0, 1.2),
        );
        push(
            out,
            Shape::Ellipsoid {
                centre: c,
                radii_m: Vector3::new(r, r * 0.85, rz),
            },
            Material::Foliage(green),
            origin,
        );
    }
    tag_object(out, start);
}

/// A street light on the kerb of `span`: pole, arm over the parking strip, lamp head, one
/// instance.
fn street_light(out: &mut Vec<SurfacePrim>, l: &StreetLayout, span: TileSide, rng: &mut Rng) {
    let s = span.side;
    let start = out.len();
    let px = span.x0_m + rng.range(14.0, 20.0);
    let py = s * l.pole_y_m;
    let h = rng.range(6.5, 8.0);
    let origin = Vector3::new(px, py, 0.0);
    push(
        out,
        Shape::Cylinder {
            centre: Vector3::new(px, py, 0.5 * h),
            axis: 2,
            radius_m: 0.09,
            half_length_m: 0.5 * h,
        },
        Material::Metal,
        origin,
    );
    let arm_end = s * (l.pole_y_m - 1.6);
    let (ya, yb) = lo_hi(py, arm_end);
    push(
        out,
        aabox([px - 0.05, ya, h - 0.1], [px + 0.05, yb, h]),
        Material::Metal,
        origin,
    );
    let (la, lb) = lo_hi(arm_end, arm_end + s * 0.6);
    push(
        out,
        aabox([px - 0.2, la, h - 0.22], [px + 0.2, lb, h - 0.1]),
        Material::Lamp,
        origin,
    );
    tag_object(out, start);
}

/// Cars in the parking bays of `span`, each bay taken with the layout's probability.
fn parked_cars(out: &mut Vec<SurfacePrim>, l: &StreetLayout, span: TileSide, rng: &mut Rng) {
    let mut cx = span.x0_m + rng.range(1.0, 4.0);
    while cx < span.x1_m - 3.0 {
        if rng.chance(l.parked_car_probability) {
            car(out, cx + 2.5, span.side * l.parked_car_y_m, rng);
        }
        cx += rng.range(5.5, 7.0);
    }
}

/// Static content of tile `tile` on side `side` (+1 left, -1 right).
pub(super) fn tile_content(out: &mut Vec<SurfacePrim>, params: &WorldParams, tile: i64, side: f64) {
    let mut rng = Rng::new(&[params.seed, tile as u64, side.to_bits(), 0x77]);
    let x0 = tile as f64 * TILE_LENGTH_M;
    let span = TileSide {
        x0_m: x0,
        x1_m: x0 + TILE_LENGTH_M,
        side,
    };
    let l = &params.layout;
    if is_intersection(params, tile) {
        intersection_corners(out, l, tile, span, &mut rng);
        return;
    }
    // Sidewalk slab (kerb face towards the road).
    let (ya, yb) = lo_hi(side * l.road_half_width_m, side * l.sidewalk_outer_m);
    let start = out.len();
    sidewalk_slab(out, span.x0_m, span.x1_m, ya, yb);
    tag_ground(out, start);
    // Buildings: one to three per tile with small gaps, and a taller row behind.
    building_row(out, &mut rng, l, span.x0_m, span.x1_m, side, false, 3);
    building_row(out, &mut rng, l, span.x0_m, span.x1_m, side, true, 2);
    if rng.chance(l.tree_probability) {
        tree(out, l, span, &mut rng);
    }
    // Street light: pole, arm over the parking strip, lamp head.
    if rng.chance(0.8) {
        street_light(out, l, span, &mut rng);
    }
    parked_cars(out, l, span, &mut rng);
}
