//! The procedural street: static content generated per 24 m tile of road from the seed, and
//! moving traffic and pedestrians as periodic streams evaluated at a time, so any stretch of
//! an unbounded road can be produced lazily and identically for every frame.
//!
//! Regular layout across the road (y, REP 103 left positive): ego lane `[-4, 0]` (driving
//! +x), oncoming lane `[0, 4]`, parking strips `4..7.5`, kerb and sidewalk `7.5..13.5` (0.15 m
//! high), buildings from about 13 m outwards. Parked cars stand at `|y| = 6.4`, oncoming cars
//! at `y = 2.4`, so nothing comes within about 3 m of a camera of a rig in the ego lane.
//! Varied streets ([`StreetStyle::Varied`]) draw these widths, setbacks, building heights and
//! the density of parked cars and trees per world seed ([`StreetLayout::varied`]).

use super::clutter;
use super::colour::Rgb;
use super::material::{Material, SurfacePrim};
use super::noise::{hash_words, unit_from_hash, Rng};
use super::props::{car, pedestrian};
use super::street::{StreetStyle, CROSS_STREET_HALF_WIDTH_M, LANE_WIDTH_M, ROAD_HALF_WIDTH_M};
use nalgebra::Vector3;

mod tile;

use tile::tile_content;

/// Length of a tile of static content along x, metres.
pub const TILE_LENGTH_M: f64 = 24.0;
/// y of the ego lane centre, metres.
pub const EGO_LANE_Y_M: f64 = -2.0;
/// Sidewalk outer edge, metres.
const SIDEWALK_OUTER_M: f64 = 13.5;
/// Building fronts start this far from the road axis (plus a random setback).
const BUILDING_FRONT_M: f64 = 13.0;
/// Front of the second row of buildings behind the street, metres from the axis.
const BACK_ROW_FRONT_M: f64 = 32.0;
/// Corner buildings stand this far back from a cross street's edge, metres.
const CORNER_SETBACK_M: f64 = 1.5;
const PARKED_CAR_Y_M: f64 = 6.4;
const ONCOMING_CAR_Y_M: f64 = 2.4;
const ONCOMING_SPEED_MPS: f64 = 9.0;
const ONCOMING_SLOT_M: f64 = 32.0;
const TREE_Y_M: f64 = 8.7;
const POLE_Y_M: f64 = 8.0;
/// Regular pedestrian streams: lateral position (magnitude), speed along x (signed) and slot
/// spacing.
const PEDESTRIAN_STREAMS: [PedestrianStream; 2] = [
    PedestrianStream {
        y_m: 10.2,
        speed_mps: 1.3,
        slot_m: 11.0,
    },
    PedestrianStream {
        y_m: 11.6,
        speed_mps: -1.2,
        slot_m: 13.0,
    },
];

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PedestrianStream {
    y_m: f64,
    speed_mps: f64,
    slot_m: f64,
}

const FACADE_COLOURS: [Rgb; 8] = [
    [0.62, 0.48, 0.36],
    [0.72, 0.68, 0.6],
    [0.55, 0.3, 0.24],
    [0.78, 0.74, 0.62],
    [0.45, 0.47, 0.5],
    [0.7, 0.58, 0.42],
    [0.6, 0.62, 0.55],
    [0.82, 0.8, 0.76],
];
/// Probability that a tile holds a cross street (no buildings, zebra crossings).
pub const INTERSECTION_PROBABILITY: f64 = 0.12;
/// Whether `tile` is an intersection with a cross street (a pure function of seed and tile).
pub fn is_intersection(params: &WorldParams, tile: i64) -> bool {
    unit_from_hash(hash_words(&[params.seed, tile as u64, 0x1A7E])) < INTERSECTION_PROBABILITY
}

/// The tile holding world x.
pub fn tile_of(x_m: f64) -> i64 {
    (x_m / TILE_LENGTH_M).floor() as i64
}

/// Centre x of the cross street of `tile` (if it has one).
pub fn cross_street_centre_m(tile: i64) -> f64 {
    (tile as f64 + 0.5) * TILE_LENGTH_M
}

/// Whether world x lies on a cross street (with `margin_m` added to its half width).
pub fn on_cross_street(params: &WorldParams, x_m: f64, margin_m: f64) -> bool {
    let tile = tile_of(x_m);
    is_intersection(params, tile)
        && (x_m - cross_street_centre_m(tile)).abs() <= CROSS_STREET_HALF_WIDTH_M + margin_m
}

/// Cluttered streets: the ground is pale and almost textureless (fresh concrete, snow) in
/// cells of this size with probability [`PALE_PATCH_PROBABILITY`], metres.
const PALE_PATCH_CELL_M: f64 = 6.0;
const PALE_PATCH_PROBABILITY: f64 = 0.15;
const PALE_PATCH_COLOUR: Rgb = [0.5, 0.5, 0.48];

/// Whether `p` lies in a pale patch of the ground of world `seed`.
fn pale_patch(seed: u64, p: &Vector3<f64>) -> bool {
    let cell = |c: f64| (c / PALE_PATCH_CELL_M).floor() as i64 as u64;
    let h = hash_words(&[seed, cell(p.x), cell(p.y), 0xA1E]);
    unit_from_hash(h) < PALE_PATCH_PROBABILITY
}

/// What the ground plane is at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundSurface {
    pub material: Material,
    /// Origin of the material's local coordinates (the cross street's centre for
    /// [`Material::CrossStreet`], else the world origin).
    pub texture_origin: Vector3<f64>,
}

/// The ground plane `z = 0` at `p`: cross street, road (`|y| <= road_half_width_m`) or grass.
pub fn ground_material(params: &WorldParams, p: &Vector3<f64>) -> GroundSurface {
    let l = &params.layout;
    if on_cross_street(params, p.x, 0.0) {
        let c = cross_street_centre_m(tile_of(p.x));
        return GroundSurface {
            material: Material::CrossStreet {
                road_half_width_m: l.road_half_width_m as f32,
            },
            texture_origin: Vector3::new(c, 0.0, 0.0),
        };
    }
    if params.clutter && pale_patch(params.seed, p) {
        return GroundSurface {
            material: Material::Plain(PALE_PATCH_COLOUR),
            texture_origin: Vector3::zeros(),
        };
    }
    let material = if p.y.abs() <= l.road_half_width_m {
        Material::Asphalt {
            lane_width_m: l.lane_width_m as f32,
        }
    } else {
        Material::Grass
    };
    GroundSurface {
        material,
        texture_origin: Vector3::zeros(),
    }
}

/// The street's cross-section and furniture density (distances from the road axis, metres).
#[derive(Clone, Debug, PartialEq)]
pub struct StreetLayout {
    /// Width of each of the two lanes.
    pub lane_width_m: f64,
    /// Kerb line: lanes plus parking strips.
    pub road_half_width_m: f64,
    /// Outer edge of the sidewalk.
    pub sidewalk_outer_m: f64,
    /// Building fronts (plus a random setback per building).
    pub building_front_m: f64,
    /// Front of the second row of buildings.
    pub back_row_front_m: f64,
    /// Multiplies every building height.
    pub building_height_scale: f64,
    /// Chance of a car in each parking bay.
    pub parked_car_probability: f64,
    /// Chance of a tree per tile and side.
    pub tree_probability: f64,
    pub parked_car_y_m: f64,
    pub oncoming_car_y_m: f64,
    pub tree_y_m: f64,
    pub pole_y_m: f64,
    /// Centre of the ego lane (the rig's y).
    pub ego_lane_y_m: f64,
    pub pedestrian_streams: [PedestrianStream; 2],
    /// Rig frame height above the road, added to the cameras' YAML heights.
    pub rig_height_offset_m: f64,
    /// Rig roll and pitch (radians) in the world.
    pub rig_roll_rad: f64,
    pub rig_pitch_rad: f64,
}

impl StreetLayout {
    /// The fixed layout of [`StreetStyle::Regular`] (the module documentation's numbers).
    pub fn regular() -> Self {
        Self {
            lane_width_m: LANE_WIDTH_M,
            road_half_width_m: ROAD_HALF_WIDTH_M,
            sidewalk_outer_m: SIDEWALK_OUTER_M,
            building_front_m: BUILDING_FRONT_M,
            back_row_front_m: BACK_ROW_FRONT_M,
            building_height_scale: 1.0,
            parked_car_probability: 0.55,
            tree_probability: 0.75,
            parked_car_y_m: PARKED_CAR_Y_M,
            oncoming_car_y_m: ONCOMING_CAR_Y_M,
            tree_y_m: TREE_Y_M,
            pole_y_m: POLE_Y_M,
            ego_lane_y_m: EGO_LANE_Y_M,
            pedestrian_streams: PEDESTRIAN_STREAMS,
            rig_height_offset_m: 0.0,
            rig_roll_rad: 0.0,
            rig_pitch_rad: 0.0,
        }
    }

    /// A layout drawn from `seed`: lanes 2.8 to 4.2 m, parking strips 1 to 3.5 m (cars only
    /// in strips of 2.2 m or more), sidewalks 1.5 to 7 m, setbacks 0 to 8 m, heights x0.4 to
    /// x2, rig 0.4 m lower to 0.6 m higher and tilted up to 3 degrees. Trees, cars and kerbs
    /// keep clear of cameras within 0.75 m of the ego lane's centre.
    pub fn varied(seed: u64) -> Self {
        // Widths are rounded to f32 so materials (which hold f32) agree with the geometry.
        let f = |x: f64| f64::from(x as f32);
        let mut rng = Rng::new(&[seed, 0x1A40]);
        let lane = f(rng.range(2.8, 4.2));
        let parking = f(rng.range(1.0, 3.5));
        let road_half = f(lane + parking);
        let sidewalk = rng.range(1.5, 7.0);
        let sidewalk_outer = road_half + sidewalk;
        let building_front = sidewalk_outer - 0.5 + rng.range(0.0, 8.0);
        let back_row = building_front + rng.range(19.0, 35.0);
        let parked = if parking >= 2.2 {
            rng.range(0.0, 0.9)
        } else {
            0.0
        };
        let streams = [
            PedestrianStream {
                y_m: road_half + 0.45 * sidewalk,
                speed_mps: rng.range(0.9, 1.6),
                slot_m: rng.range(7.0, 20.0),
            },
            PedestrianStream {
                y_m: road_half + 0.75 * sidewalk,
                speed_mps: -rng.range(0.9, 1.6),
                slot_m: rng.range(7.0, 20.0),
            },
        ];
        Self {
            lane_width_m: lane,
            road_half_width_m: road_half,
            sidewalk_outer_m: sidewalk_outer,
            building_front_m: building_front,
            back_row_front_m: back_row,
            building_height_scale: rng.range(0.4, 2.0),
            parked_car_probability: parked,
            tree_probability: rng.range(0.0, 1.0),
            parked_car_y_m: road_half - 1.1,
            oncoming_car_y_m: 0.6 * lane,
            tree_y_m: road_half + 1.2,
            pole_y_m: road_half + 0.5,
            ego_lane_y_m: -0.5 * lane,
            pedestrian_streams: streams,
            rig_height_offset_m: rng.range(-0.4, 0.6),
            rig_roll_rad: rng.range(-0.05, 0.05),
            rig_pitch_rad: rng.range(-0.05, 0.05),
        }
    }
}

/// Global, seed-dependent scene parameters.
#[derive(Clone, Debug)]
pub struct WorldParams {
    pub seed: u64,
    /// Unit vector towards the sun.
    pub sun_dir: Vector3<f64>,
    /// Texture seed (32-bit).
    pub tex_seed: u32,
    /// Cross-section and density of the street.
    pub layout: StreetLayout,
    /// Near clutter along the rig's path ([`StreetStyle::Cluttered`]).
    pub clutter: bool,
}

impl WorldParams {
    /// The regular street of `seed`.
    pub fn new(seed: u64) -> Self {
        Self::with_style(seed, StreetStyle::Regular)
    }

    /// The street of `seed` in `style`.
    pub fn with_style(seed: u64, style: StreetStyle) -> Self {
        let mut rng = Rng::new(&[seed, 0x5u64]);
        let azimuth = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
        let elevation = rng.range(0.45, 1.05);
        Self {
            seed,
            sun_dir: Vector3::new(
                elevation.cos() * azimuth.cos(),
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
            ),
            tex_seed: (hash_words(&[seed, 0x7]) >> 32) as u32,
            layout: match style {
                StreetStyle::Regular => StreetLayout::regular(),
                StreetStyle::Varied | StreetStyle::Cluttered => StreetLayout::varied(seed),
            },
            clutter: style == StreetStyle::Cluttered,
        }
    }
}

/// Every primitive within `range_m` of `x_centre_m` along the road at time `t_s`.
pub fn scene_prims(
    params: &WorldParams,
    x_centre_m: f64,
    range_m: f64,
    t_s: f64,
) -> Vec<SurfacePrim> {
    let mut out = Vec::new();
    let first = ((x_centre_m - range_m) / TILE_LENGTH_M).floor() as i64;
    let last = ((x_centre_m + range_m) / TILE_LENGTH_M).ceil() as i64;
    for tile in first..=last {
        for side in [1.0, -1.0] {
            tile_content(&mut out, params, tile, side);
        }
    }
    // Oncoming traffic: slot k's car is at k * slot + jitter - speed * t.
    let shift = -ONCOMING_SPEED_MPS * t_s;
    let k0 = ((x_centre_m - range_m - shift) / ONCOMING_SLOT_M).floor() as i64;
    let k1 = ((x_centre_m + range_m - shift) / ONCOMING_SLOT_M).ceil() as i64;
    for k in k0..=k1 {
        let mut rng = Rng::new(&[params.seed, k as u64, 0x0C0C]);
        if rng.chance(0.6) {
            let x = k as f64 * ONCOMING_SLOT_M + rng.range(0.0, 0.5 * ONCOMING_SLOT_M) + shift;
            car(&mut out, x, params.layout.oncoming_car_y_m, &mut rng);
        }
    }
    if params.clutter {
        clutter::clutter_prims(
            &mut out,
            params.seed,
            x_centre_m,
            params.layout.ego_lane_y_m,
        );
    }
    // Pedestrians on both sidewalks.
    for (si, side) in [1.0f64, -1.0].iter().enumerate() {
        for (pi, st) in params.layout.pedestrian_streams.iter().enumerate() {
            let shift = st.speed_mps * t_s;
            let k0 = ((x_centre_m - range_m - shift) / st.slot_m).floor() as i64;
            let k1 = ((x_centre_m + range_m - shift) / st.slot_m).ceil() as i64;
            for k in k0..=k1 {
                let mut rng = Rng::new(&[params.seed, k as u64, si as u64, pi as u64, 0xFEE7]);
                if rng.chance(0.5) {
                    let x = k as f64 * st.slot_m + rng.range(0.0, 0.6 * st.slot_m) + shift;
                    // Nobody walks (at sidewalk height) across a cross street.
                    if on_cross_street(params, x, 0.5) {
                        continue;
                    }
                    let y = side * (st.y_m + rng.range(-0.3, 0.3));
                    // Gait: one stride (two steps) per 1.4 m travelled.
                    let phase = x / 1.4 * std::f64::consts::TAU + rng.range(0.0, 6.0);
                    pedestrian(&mut out, x, y, phase, &mut rng);
                }
            }
        }
    }
    out
}
