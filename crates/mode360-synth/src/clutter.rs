//! Near clutter along the rig's path ([`super::StreetStyle::Cluttered`]): the poles, sign
//! posts, bollards, cones, barriers, fences, rails, tree trunks, people, cyclists, parked
//! cars, low walls and overhanging branches that a vehicle or robot passes close by, each one
//! object instance of the ground truth's labels.
//!
//! Items are anchored in the world, so a sequence sees them approach and pass: slot `k` of
//! [`SLOT_LENGTH_M`] along x holds an item with probability [`ITEM_PROBABILITY`], on either
//! side of the ego lane's centre line `y = ego_y`, at a lateral offset from that line drawn,
//! with probability [`CLOSE_SHARE`], uniformly in [`MIN_LATERAL_M`, `CLOSE_LATERAL_M`],
//! else log-uniformly in [`MIN_LATERAL_M`, `MAX_LATERAL_M`]. With every camera of the rig within
//! [`super::objects::standard_rig_zone`]'s 0.75 m of the line, the nearest item surface is
//! at least `MIN_LATERAL_M - 0.75 m` from a camera, and 0.7 m from the Deep360 rig's (0.5 m
//! off the line). Thin structures go down to [`MIN_THIN_RADIUS_M`] (3 cm across). Some are
//! hard to match: dark glossy paint, pale walls with no texture; the cluttered street also
//! has pale patches of ground and the sun's glare on paint, glass, metal and the wet road
//! (`super::world`, `super::material::gloss`).
//!
//! Things stand in the path too: slot `k` of [`PATH_SLOT_LENGTH_M`] holds, with probability
//! [`PATH_ITEM_PROBABILITY`], a person, cyclist, cone, bollard, pole or sign post within
//! 0.5 m of the centre line; it is part of a frame only while it is at least
//! [`PATH_CLEARANCE_M`] ahead of or behind the rig along x (a sequence sees it approach, then
//! it is gone), so no camera is ever inside it.

use super::bvh::Shape;
use super::colour::Rgb;
use super::material::{Material, SurfacePrim};
use super::noise::Rng;
use super::pattern::{random_colour, Pattern};
use super::props::{aabox, car, pedestrian, push, tag_object};
use nalgebra::Vector3;

/// Length along x of one clutter slot, metres.
pub const SLOT_LENGTH_M: f64 = 1.0;
/// Chance that a slot holds an item.
pub const ITEM_PROBABILITY: f64 = 0.7;
/// Nearest lateral offset of an item's surface from the ego lane's centre line, metres.
pub const MIN_LATERAL_M: f64 = 1.2;
/// Farthest lateral offset of an item from the ego lane's centre line, metres.
pub const MAX_LATERAL_M: f64 = 7.0;
/// Share of the items drawn close by: uniformly within [`MIN_LATERAL_M`, `CLOSE_LATERAL_M`]
/// (the others log-uniformly up to [`MAX_LATERAL_M`]).
pub const CLOSE_SHARE: f64 = 0.4;
/// Outer edge of the close items' lateral offsets, metres.
pub const CLOSE_LATERAL_M: f64 = 2.2;
/// Length along x of one slot of the things standing in the ego lane ahead (or behind).
pub const PATH_SLOT_LENGTH_M: f64 = 8.0;
/// Chance that a path slot holds an item.
pub const PATH_ITEM_PROBABILITY: f64 = 0.6;
/// A thing in the path exists only while its x is at least this far from the rig's: it is
/// there in the frames that see it ahead or behind, and gone while the rig would pass
/// through it (half the rig zone, 0.75 m, plus the largest path item's half length, 0.9 m,
/// plus a gap), metres.
pub const PATH_CLEARANCE_M: f64 = RIG_ZONE_HALF_WIDTH_M + PATH_ITEM_HALF_LENGTH_M + PATH_GAP_M;
/// Half the width of the zone that holds every camera of the rigs here, metres
/// ([`super::objects::standard_rig_zone`]).
const RIG_ZONE_HALF_WIDTH_M: f64 = 0.75;
/// Largest half extent along x of a path item (a cyclist's wheels), metres.
const PATH_ITEM_HALF_LENGTH_M: f64 = 0.9;
/// Gap between the rig zone and a path item, metres.
const PATH_GAP_M: f64 = 0.55;
/// Clutter is generated this far ahead of and behind the rig along x, metres.
pub const CLUTTER_RANGE_M: f64 = 60.0;
/// Radius of the thinnest poles and rails, metres.
pub const MIN_THIN_RADIUS_M: f64 = 0.015;
/// Half width of a person across the walking direction (torso), metres.
const PERSON_HALF_WIDTH_M: f64 = 0.22;
/// Largest half width of a car, metres (`props::car`).
const CAR_HALF_WIDTH_MAX_M: f64 = 0.92;
/// Overhanging branches hang at least this high above the road, metres (above any rig).
const MIN_BRANCH_HEIGHT_M: f64 = 3.2;
/// Traffic-cone orange and barrier red/white (linear RGB).
const CONE_ORANGE: Rgb = [0.85, 0.25, 0.03];
const BARRIER_RED: Rgb = [0.7, 0.05, 0.04];
/// Dark glossy paint and pale flat concrete: surfaces that defeat matching.
const DARK_PAINT: Rgb = [0.03, 0.03, 0.035];
const PALE_CONCRETE: Rgb = [0.55, 0.54, 0.52];

/// The kinds of clutter, drawn uniformly.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Item {
    Pole,
    SignPost,
    Bollard,
    Cone,
    Barrier,
    Fence,
    TreeTrunk,
    Person,
    Cyclist,
    ParkedCar,
    LowWall,
    Branch,
}

/// What may stand in the path (at most [`PATH_ITEM_HALF_LENGTH_M`] along x).
const PATH_ITEMS: [Item; 6] = [
    Item::Person,
    Item::Cyclist,
    Item::Cone,
    Item::Bollard,
    Item::Pole,
    Item::SignPost,
];

const ITEMS: [Item; 12] = [
    Item::Pole,
    Item::SignPost,
    Item::Bollard,
    Item::Cone,
    Item::Barrier,
    Item::Fence,
    Item::TreeTrunk,
    Item::Person,
    Item::Cyclist,
    Item::ParkedCar,
    Item::LowWall,
    Item::Branch,
];

fn log_uniform(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    rng.range(lo.ln(), hi.ln()).exp()
}

/// A vertical cylinder standing on the road at `(x, y)`.
fn post(x: f64, y: f64, radius_m: f64, height_m: f64) -> Shape {
    Shape::Cylinder {
        centre: Vector3::new(x, y, 0.5 * height_m),
        axis: 2,
        radius_m,
        half_length_m: 0.5 * height_m,
    }
}

/// A paint or pattern for signs and barriers: mostly a pattern, sometimes flat.
fn sign_material(rng: &mut Rng) -> Material {
    if rng.chance(0.7) {
        Material::Pattern(Pattern::random(rng, 0.02, 0.2))
    } else {
        Material::CarPaint(random_colour(rng))
    }
}

/// Where one item stands: at `x` along the path, on side `side` (+1 left, -1 right) of the
/// centre line `ego_y_m`, its near side `lateral_m` from that line.
#[derive(Clone, Copy, Debug)]
struct Placement {
    x: f64,
    ego_y_m: f64,
    side: f64,
    lateral_m: f64,
}

impl Placement {
    /// The y of a point `d_m` beyond the near side.
    fn y_at(&self, d_m: f64) -> f64 {
        self.ego_y_m + self.side * (self.lateral_m + d_m)
    }

    /// The item's origin: on the road at `x`, on its near side.
    fn origin(&self) -> Vector3<f64> {
        Vector3::new(self.x, self.y_at(0.0), 0.0)
    }
}

/// A pole of metal or painted metal, 3 cm to 24 cm across and 2.2 m to 5 m tall.
fn pole(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let r = log_uniform(rng, MIN_THIN_RADIUS_M, 0.12);
    let h = rng.range(2.2, 5.0);
    let m = if rng.chance(0.5) {
        Material::Metal
    } else {
        Material::CarPaint(random_colour(rng))
    };
    push(out, post(at.x, at.y_at(r), r, h), m, at.origin());
}

/// A thin metal post carrying a sign plate at its top, the plate facing along x or across it.
fn sign_post(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let x = at.x;
    let r = log_uniform(rng, MIN_THIN_RADIUS_M, 0.05);
    let h = rng.range(2.0, 3.0);
    push(out, post(x, at.y_at(r), r, h), Material::Metal, at.origin());
    let half_w = rng.range(0.2, 0.45);
    let plate_h = rng.range(0.3, 0.8);
    // The plate faces along x or across it.
    let (hx, hy) = if rng.chance(0.5) {
        (0.01, half_w)
    } else {
        (half_w, 0.01)
    };
    // Centred so that its near edge is no nearer than the post's.
    let c = Vector3::new(x, at.y_at(hy.max(r)), h - 0.5 * plate_h);
    push(
        out,
        aabox(
            [c.x - hx, c.y - hy, c.z - 0.5 * plate_h],
            [c.x + hx, c.y + hy, c.z + 0.5 * plate_h],
        ),
        sign_material(rng),
        c,
    );
}

/// A short concrete or dark glossy bollard.
fn bollard(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let r = rng.range(0.05, 0.15);
    let m = if rng.chance(0.5) {
        Material::Concrete
    } else {
        Material::CarPaint(DARK_PAINT)
    };
    let h = rng.range(0.6, 1.2);
    push(out, post(at.x, at.y_at(r), r, h), m, at.origin());
}

/// An orange traffic cone: a wide lower cylinder under a narrower top.
fn cone(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let (x, origin) = (at.x, at.origin());
    let r = rng.range(0.1, 0.18);
    let h = rng.range(0.45, 0.75);
    let (y, m) = (at.y_at(r), Material::CarPaint(CONE_ORANGE));
    push(out, post(x, y, r, 0.5 * h), m, origin);
    let top = Shape::Cylinder {
        centre: Vector3::new(x, y, 0.75 * h),
        axis: 2,
        radius_m: 0.5 * r,
        half_length_m: 0.25 * h,
    };
    push(out, top, m, origin);
}

/// A row of thin metal posts along x carrying a painted board (`board`, a barrier) or two
/// metal rails (a fence).
fn barrier_or_fence(out: &mut Vec<SurfacePrim>, at: &Placement, board: bool, rng: &mut Rng) {
    let (x, origin) = (at.x, at.origin());
    let len = rng.range(1.5, 5.0);
    let h = rng.range(0.8, 1.2);
    let post_r = log_uniform(rng, MIN_THIN_RADIUS_M, 0.05);
    // The barrier's board is 6 cm thick, centred on the posts.
    let y = at.y_at(post_r.max(0.03));
    let posts = 2 + (len / 1.5) as usize;
    for i in 0..posts {
        let px = x - 0.5 * len + len * i as f64 / (posts - 1) as f64;
        push(out, post(px, y, post_r, h), Material::Metal, origin);
    }
    if board {
        let m = Material::CarPaint(if rng.chance(0.5) {
            BARRIER_RED
        } else {
            [0.8, 0.8, 0.78]
        });
        let board = aabox(
            [x - 0.5 * len, y - 0.03, h - 0.35],
            [x + 0.5 * len, y + 0.03, h - 0.05],
        );
        push(out, board, m, origin);
    } else {
        for rail_z in [0.45 * h, 0.95 * h] {
            let rail = Shape::Cylinder {
                centre: Vector3::new(x, y, rail_z),
                axis: 0,
                radius_m: post_r,
                half_length_m: 0.5 * len,
            };
            push(out, rail, Material::Metal, origin);
        }
    }
}

/// A bare tree trunk, 20 cm to 60 cm across and 2 m to 4 m tall.
fn tree_trunk(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let r = rng.range(0.1, 0.3);
    let h = rng.range(2.0, 4.0);
    push(
        out,
        post(at.x, at.y_at(r), r, h),
        Material::Bark,
        at.origin(),
    );
}

/// A person with two bicycle wheels, tagged as one instance from prim `start` on.
fn cyclist(out: &mut Vec<SurfacePrim>, at: &Placement, start: usize, rng: &mut Rng) {
    let (x, origin) = (at.x, at.origin());
    let y = at.y_at(PERSON_HALF_WIDTH_M);
    pedestrian(out, x, y, rng.range(0.0, 6.3), rng);
    for dx in [-0.55, 0.55] {
        let wheel = Shape::Cylinder {
            centre: Vector3::new(x + dx, y, 0.34),
            axis: 1,
            radius_m: 0.34,
            half_length_m: 0.02,
        };
        push(out, wheel, Material::Tyre, origin);
    }
    // The pedestrian tagged itself; the wheels join it.
    tag_object(out, start);
}

/// A low wall along x of concrete, paving or pale textureless concrete.
fn low_wall(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let x = at.x;
    let len = rng.range(2.0, 6.0);
    let thick = rng.range(0.15, 0.35);
    let h = rng.range(0.4, 1.1);
    let y = at.y_at(0.5 * thick);
    let m = match rng.index(3) {
        0 => Material::Concrete,
        1 => Material::Paving,
        // Fresh pale concrete: almost no texture to match.
        _ => Material::Plain(PALE_CONCRETE),
    };
    let wall = aabox(
        [x - 0.5 * len, y - 0.5 * thick, 0.0],
        [x + 0.5 * len, y + 0.5 * thick, h],
    );
    push(out, wall, m, at.origin());
}

/// An overhanging branch: a flattened ellipsoid of foliage at least
/// [`MIN_BRANCH_HEIGHT_M`] above the road.
fn branch(out: &mut Vec<SurfacePrim>, at: &Placement, rng: &mut Rng) {
    let z = rng.range(MIN_BRANCH_HEIGHT_M, 4.5);
    let r = rng.range(0.5, 1.2);
    let green: Rgb = [
        rng.range(0.08, 0.16) as f32,
        rng.range(0.2, 0.32) as f32,
        rng.range(0.04, 0.1) as f32,
    ];
    let blob = Shape::Ellipsoid {
        centre: Vector3::new(at.x, at.y_at(0.0), z + r),
        radii_m: Vector3::new(r, 0.8 * r, 0.5 * r),
    };
    push(out, blob, Material::Foliage(green), at.origin());
}

/// One item of kind `item` placed `at`, tagged as one object instance.
fn item(out: &mut Vec<SurfacePrim>, item: Item, at: &Placement, rng: &mut Rng) {
    let start = out.len();
    match item {
        Item::Pole => pole(out, at, rng),
        Item::SignPost => sign_post(out, at, rng),
        Item::Bollard => bollard(out, at, rng),
        Item::Cone => cone(out, at, rng),
        Item::Barrier | Item::Fence => barrier_or_fence(out, at, item == Item::Barrier, rng),
        Item::TreeTrunk => tree_trunk(out, at, rng),
        Item::Person => pedestrian(
            out,
            at.x,
            at.y_at(PERSON_HALF_WIDTH_M),
            rng.range(0.0, 6.3),
            rng,
        ),
        Item::Cyclist => cyclist(out, at, start, rng),
        Item::ParkedCar => car(out, at.x, at.y_at(CAR_HALF_WIDTH_MAX_M), rng),
        Item::LowWall => low_wall(out, at, rng),
        Item::Branch => branch(out, at, rng),
    }
    // Items built from push calls are one instance (people and cars tag themselves).
    if !matches!(item, Item::Person | Item::Cyclist | Item::ParkedCar) {
        tag_object(out, start);
    }
}

/// The occupied slots of length `slot_m` within [`CLUTTER_RANGE_M`] of `x_centre_m`: for each
/// slot `k` whose draw from `Rng::new(&[seed, k, tag])` passes `probability`, `k` and that
/// generator (for the item's own draws).
fn occupied_slots(
    seed: u64,
    tag: u64,
    slot_m: f64,
    probability: f64,
    x_centre_m: f64,
) -> impl Iterator<Item = (i64, Rng)> {
    let first = ((x_centre_m - CLUTTER_RANGE_M) / slot_m).floor() as i64;
    let last = ((x_centre_m + CLUTTER_RANGE_M) / slot_m).ceil() as i64;
    (first..=last).filter_map(move |k| {
        let mut rng = Rng::new(&[seed, k as u64, tag]);
        rng.chance(probability).then_some((k, rng))
    })
}

/// The clutter of world `seed` within [`CLUTTER_RANGE_M`] of `x_centre_m`, beside the ego
/// lane's centre line `ego_y_m`, and the things in the path.
pub fn clutter_prims(out: &mut Vec<SurfacePrim>, seed: u64, x_centre_m: f64, ego_y_m: f64) {
    for (k, mut rng) in occupied_slots(seed, 0xC1_7733, SLOT_LENGTH_M, ITEM_PROBABILITY, x_centre_m)
    {
        let kind = ITEMS[rng.index(ITEMS.len())];
        let side = if rng.chance(0.5) { 1.0 } else { -1.0 };
        let lateral = if rng.chance(CLOSE_SHARE) {
            rng.range(MIN_LATERAL_M, CLOSE_LATERAL_M)
        } else {
            log_uniform(&mut rng, MIN_LATERAL_M, MAX_LATERAL_M)
        };
        let at = Placement {
            x: (k as f64 + rng.range(0.2, 0.8)) * SLOT_LENGTH_M,
            ego_y_m,
            side,
            lateral_m: lateral,
        };
        item(out, kind, &at, &mut rng);
    }
    let path = occupied_slots(
        seed,
        0x9A7B,
        PATH_SLOT_LENGTH_M,
        PATH_ITEM_PROBABILITY,
        x_centre_m,
    );
    for (k, mut rng) in path {
        let kind = PATH_ITEMS[rng.index(PATH_ITEMS.len())];
        let x = (k as f64 + rng.range(0.2, 0.8)) * PATH_SLOT_LENGTH_M;
        if (x - x_centre_m).abs() < PATH_CLEARANCE_M {
            continue;
        }
        // Near side 0.5 m left of the line to on it.
        let at = Placement {
            x,
            ego_y_m,
            side: 1.0,
            lateral_m: rng.range(-0.5, 0.0),
        };
        item(out, kind, &at, &mut rng);
    }
}

#[cfg(test)]
mod tests {
    use super::super::bvh::PrimLabel;
    use super::*;

    #[test]
    fn items_are_instances_beside_the_path() {
        let mut out = Vec::new();
        clutter_prims(&mut out, 7, 0.0, -2.0);
        assert!(out.len() > 30, "{} prims", out.len());
        let mut ids: Vec<u16> = out
            .iter()
            .map(|p| match p.label {
                PrimLabel::Object(id) => id,
                other => panic!("clutter labelled {other:?}"),
            })
            .collect();
        ids.dedup();
        // Ids rise along the list: every item's prims are contiguous and one instance.
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");
        let slots = (2.0 * CLUTTER_RANGE_M / SLOT_LENGTH_M) as usize;
        let path_slots = (2.0 * CLUTTER_RANGE_M / PATH_SLOT_LENGTH_M) as usize;
        assert!(
            ids.len() > slots / 2 && ids.len() <= slots + path_slots + 4,
            "{} items",
            ids.len()
        );
        // Nothing below the branches' height comes within MIN_LATERAL_M of the line, but
        // things in the path, which keep their distance along x.
        for p in &out {
            let b = p.shape.aabb();
            if b.min.z >= MIN_BRANCH_HEIGHT_M {
                continue;
            }
            let along = b.min.x.abs().min(b.max.x.abs());
            let clear_of_rig = b.min.x > 0.0 || b.max.x < 0.0;
            if clear_of_rig && along >= PATH_CLEARANCE_M - PATH_ITEM_HALF_LENGTH_M - 1e-9 {
                continue;
            }
            let near = if b.min.y > -2.0 {
                b.min.y - (-2.0)
            } else {
                -2.0 - b.max.y
            };
            assert!(near >= MIN_LATERAL_M - 1e-9, "{:?} at {near} m", p.shape);
        }
    }
}
