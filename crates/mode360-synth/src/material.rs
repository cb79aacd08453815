//! Procedural materials: albedo as a function of position (world or object coordinates),
//! surface normal and pixel footprint (the sky at infinity is [`super::sky`]).
//!
//! Band limiting: every fractal octave is faded out when its frequency times the pixel
//! footprint nears Nyquist ([`super::noise::octave_weight`]), and periodic stripes (lane
//! markings, windows, paving joints) are box-filtered over the footprint
//! ([`super::colour::periodic_coverage`]), so distant detail averages instead of aliasing.

use super::bvh::Prim;
use super::colour::{mix, periodic_coverage, scale, stripe_coverage, Rgb};
use super::noise::{fbm2, fbm3, lattice_unit, octave_weight, value2};
use super::street::CROSS_STREET_HALF_WIDTH_M;
use nalgebra::Vector3;

/// A primitive of the rendered scenes: a shape with its material.
pub type SurfacePrim = Prim<Material>;

/// Width of painted lines, metres.
const LINE_WIDTH_M: f64 = 0.15;
/// Centre-line dash length and period, metres.
const DASH_LENGTH_M: f64 = 3.0;
const DASH_PERIOD_M: f64 = 9.0;
/// Zebra crossing bar period across the road, metres.
const ZEBRA_PERIOD_M: f64 = 1.0;
/// Paving slab size, metres, and joint width.
const PAVING_SLAB_M: f64 = 0.6;
const PAVING_JOINT_M: f64 = 0.04;
/// Frequency of the asphalt's gravel speckle, cycles per metre.
const ASPHALT_SPECKLE_PER_M: f32 = 24.0;
/// Ground-floor height of buildings, metres.
const GROUND_FLOOR_M: f64 = 4.0;

/// What a surface is made of, with its per-object parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Road surface with lane markings (the ground plane between the kerbs); lanes are
    /// `[-lane_width_m, 0]` and `[0, lane_width_m]`, parking strips beyond.
    Asphalt {
        lane_width_m: f32,
    },
    /// Ground plane of a cross street (local x = 0 on its centre line): asphalt with zebra
    /// crossings over the main road (kerbs at `|y| = road_half_width_m`) and a dashed centre
    /// line.
    CrossStreet {
        road_half_width_m: f32,
    },
    /// Ground beyond the sidewalks.
    Grass,
    /// Sidewalk: paving slabs on top, concrete kerb on the sides.
    Paving,
    Concrete,
    /// Building: coloured wall with a grid of windows, `seed` varies window states.
    Facade {
        wall: Rgb,
        floor_height_m: f32,
        bay_width_m: f32,
        seed: u32,
    },
    CarPaint(Rgb),
    CarGlass,
    Tyre,
    Bark,
    Foliage(Rgb),
    Metal,
    Lamp,
    Clothes(Rgb),
    Skin(Rgb),
    /// A high-contrast procedural pattern in object coordinates (random-objects scenes).
    Pattern(super::pattern::Pattern),
    /// A pale surface with almost no texture (fresh concrete, snow): `colour` with 2 %
    /// variation, which defeats matching.
    Plain(Rgb),
}

/// How shiny a material is: a specular lobe `strength * max(0, r . v)^exponent` of the sun
/// (`r` the sun's mirror direction, `v` towards the viewer), added where the surface is sunlit
/// in scenes that render gloss (cluttered streets). `None`: matte.
pub fn gloss(material: &Material) -> Option<(f32, i32)> {
    match material {
        Material::CarPaint(_) => Some((0.6, 40)),
        Material::CarGlass => Some((1.2, 200)),
        Material::Metal => Some((0.5, 20)),
        // Wet road.
        Material::Asphalt { .. } | Material::CrossStreet { .. } => Some((0.35, 12)),
        _ => None,
    }
}

fn p32(p: &Vector3<f64>) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// Texture coordinates of a point on an axis-aligned face: the two axes other than the
/// dominant normal axis.
fn face_uv(p: &Vector3<f64>, n: &Vector3<f64>) -> (f64, f64) {
    let a = n.abs();
    if a.z >= a.x && a.z >= a.y {
        (p.x, p.y)
    } else if a.x >= a.y {
        (p.y, p.z)
    } else {
        (p.x, p.z)
    }
}

/// Albedo of `material` at world point `p_world` (object coordinates `p_obj`) with unit normal
/// `n`, seen with a pixel footprint of `footprint_m` metres.
pub fn albedo(
    material: &Material,
    p_world: &Vector3<f64>,
    p_obj: &Vector3<f64>,
    n: &Vector3<f64>,
    footprint_m: f64,
    seed: u32,
) -> Rgb {
    let fp = footprint_m as f32;
    match *material {
        Material::Asphalt { lane_width_m } => {
            asphalt(p_world, f64::from(lane_width_m), footprint_m, seed)
        }
        Material::CrossStreet { road_half_width_m } => cross_street(
            p_world,
            p_obj,
            f64::from(road_half_width_m),
            footprint_m,
            seed,
        ),
        Material::Grass => {
            let g = fbm2(p_world.x as f32, p_world.y as f32, seed ^ 0x61, 0.5, 6, fp);
            let d = fbm2(p_world.x as f32, p_world.y as f32, seed ^ 0x62, 0.11, 3, fp);
            mix(
                [0.10, 0.16, 0.05],
                [0.30, 0.36, 0.12],
                g * 0.7 + d * 0.6 - 0.15,
            )
        }
        Material::Paving => {
            if n.z > 0.5 {
                paving(p_world, footprint_m, seed)
            } else {
                concrete(p_world, n, fp, seed, [0.55, 0.54, 0.5])
            }
        }
        Material::Concrete => concrete(p_world, n, fp, seed, [0.5, 0.5, 0.48]),
        Material::Facade {
            wall,
            floor_height_m,
            bay_width_m,
            seed: bseed,
        } => facade(
            p_obj,
            n,
            footprint_m,
            wall,
            floor_height_m as f64,
            bay_width_m as f64,
            bseed,
        ),
        Material::CarPaint(c) => {
            let q = p32(p_obj);
            let v = fbm3(q, seed ^ 0x71, 2.0, 3, fp);
            // Door seams and a darker sill stripe keep cars textured for matching.
            let seam = periodic_coverage(p_obj.x, 1.3, 0.0, 0.04, footprint_m) as f32;
            let base = scale(c, 0.8 + 0.4 * v);
            mix(base, scale(c, 0.3), seam)
        }
        Material::CarGlass => {
            let v = fbm3(p32(p_obj), seed ^ 0x72, 1.5, 3, fp);
            [0.05 + 0.1 * v, 0.07 + 0.1 * v, 0.09 + 0.12 * v]
        }
        Material::Tyre => {
            let v = fbm3(p32(p_obj), seed ^ 0x73, 8.0, 2, fp);
            [0.03 + 0.04 * v, 0.03 + 0.04 * v, 0.03 + 0.04 * v]
        }
        Material::Bark => {
            let q = p32(p_obj);
            let v = fbm3(
                [q[0] * 3.0, q[1] * 3.0, q[2] * 0.6],
                seed ^ 0x74,
                2.0,
                4,
                fp,
            );
            mix([0.12, 0.08, 0.05], [0.32, 0.24, 0.16], v)
        }
        Material::Foliage(c) => {
            let v = fbm3(p32(p_world), seed ^ 0x75, 1.5, 5, fp);
            let w = fbm3(p32(p_world), seed ^ 0x76, 0.4, 2, fp);
            scale(c, 0.45 + 1.1 * v * (0.6 + 0.8 * w))
        }
        Material::Metal => {
            let v = fbm3(p32(p_world), seed ^ 0x77, 3.0, 3, fp);
            [0.25 + 0.15 * v, 0.26 + 0.15 * v, 0.28 + 0.15 * v]
        }
        Material::Lamp => [0.95, 0.92, 0.8],
        Material::Clothes(c) => {
            let v = fbm3(p32(p_obj), seed ^ 0x78, 4.0, 2, fp);
            scale(c, 0.7 + 0.6 * v)
        }
        Material::Skin(c) => c,
        Material::Pattern(pat) => pat.albedo(p_obj, footprint_m),
        Material::Plain(c) => {
            let v = fbm3(p32(p_world), seed ^ 0x79, 0.7, 2, fp);
            scale(c, 0.99 + 0.02 * v)
        }
    }
}

fn concrete(p: &Vector3<f64>, n: &Vector3<f64>, fp: f32, seed: u32, base: Rgb) -> Rgb {
    let (u, v) = face_uv(p, n);
    let t = fbm2(u as f32, v as f32, seed ^ 0x81, 1.0, 6, fp);
    scale(base, 0.7 + 0.6 * t)
}

fn asphalt_base(p: &Vector3<f64>, fp_m: f64, seed: u32) -> Rgb {
    let fp = fp_m as f32;
    let (x, y) = (p.x as f32, p.y as f32);
    let grain = fbm2(x, y, seed ^ 0x11, 4.0, 5, fp);
    let patches = fbm2(x, y, seed ^ 0x12, 0.08, 3, fp);
    // Gravel speckle: rough fine octaves, faded out by the footprint.
    let speckle = rough_detail(x, y, seed ^ 0x14, ASPHALT_SPECKLE_PER_M, fp);
    let g = (0.15 + 0.22 * (grain - 0.5) + 0.1 * (patches - 0.5) + 0.1 * speckle).max(0.02);
    [g, g, g * 1.04]
}

/// Cross street: plain asphalt, zebra crossings (bars along x, 0.5 m wide every 1 m) over
/// the main road next to the cross street's edges, and a dashed centre line along y.
fn cross_street(
    p: &Vector3<f64>,
    local: &Vector3<f64>,
    road_half_width_m: f64,
    fp_m: f64,
    seed: u32,
) -> Rgb {
    let c = asphalt_base(p, fp_m, seed);
    let half = CROSS_STREET_HALF_WIDTH_M;
    let lx = local.x.abs();
    let zebra = if p.y.abs() <= road_half_width_m - 0.5 {
        stripe_coverage(lx, half - 3.0, half - 0.5, fp_m)
            * periodic_coverage(p.y, ZEBRA_PERIOD_M, 0.0, 0.5 * ZEBRA_PERIOD_M, fp_m)
    } else {
        0.0
    };
    let centre = if p.y.abs() > road_half_width_m + 1.0 {
        stripe_coverage(local.x, -0.5 * LINE_WIDTH_M, 0.5 * LINE_WIDTH_M, fp_m)
            * periodic_coverage(p.y, DASH_PERIOD_M, 0.0, DASH_LENGTH_M, fp_m)
    } else {
        0.0
    };
    mix(c, [0.85, 0.85, 0.84], (zebra + centre).min(1.0) as f32)
}

fn asphalt(p: &Vector3<f64>, lane_width_m: f64, fp_m: f64, seed: u32) -> Rgb {
    let (x, y) = (p.x as f32, p.y as f32);
    let mut c = asphalt_base(p, fp_m, seed);
    // Parking strips are slightly lighter and bluish.
    if p.y.abs() > lane_width_m {
        c = scale(c, 1.12);
    }
    let half_line = 0.5 * LINE_WIDTH_M;
    // Dashed centre line (yellowish white) and solid white edge lines at the lane borders.
    let centre = stripe_coverage(p.y, -half_line, half_line, fp_m)
        * periodic_coverage(p.x, DASH_PERIOD_M, 0.0, DASH_LENGTH_M, fp_m);
    let edge = stripe_coverage(
        p.y.abs(),
        lane_width_m - half_line,
        lane_width_m + half_line,
        fp_m,
    );
    // Parking bays: short transverse ticks every 6 m in the parking strips.
    let bay = if p.y.abs() > lane_width_m + half_line {
        periodic_coverage(p.x, 6.0, 0.0, 0.12, fp_m)
            * stripe_coverage(p.y.abs(), lane_width_m, lane_width_m + 2.0, fp_m)
    } else {
        0.0
    };
    let wear = 0.75 + 0.25 * value2(x * 0.7, y * 3.0, seed ^ 0x13);
    c = mix(c, scale([0.85, 0.8, 0.55], wear), centre as f32);
    c = mix(
        c,
        scale([0.85, 0.85, 0.85], wear),
        (edge + bay).min(1.0) as f32,
    );
    c
}

/// Fine detail with equal amplitude per octave (rougher than fbm): octaves at `f`, `f/2`,
/// `f/4` cycles per metre, each faded by the footprint; centred on 0, within `[-1.5, 1.5]`.
fn rough_detail(x: f32, y: f32, seed: u32, f: f32, fp: f32) -> f32 {
    let mut sum = 0.0;
    let mut freq = f;
    for k in 0..3u32 {
        let w = octave_weight(freq, fp);
        if w > 0.0 {
            sum += w * (value2(x * freq, y * freq, seed.wrapping_add(k)) - 0.5);
        }
        freq *= 0.5;
    }
    sum
}

fn paving(p: &Vector3<f64>, fp_m: f64, seed: u32) -> Rgb {
    let fp = fp_m as f32;
    let (ix, iy) = (
        (p.x / PAVING_SLAB_M).floor() as i32,
        (p.y / PAVING_SLAB_M).floor() as i32,
    );
    // Per-slab tint, faded to its mean when slabs shrink below a few pixels.
    let slab_vis = (1.0 - (fp_m / PAVING_SLAB_M - 0.25) / 0.5).clamp(0.0, 1.0) as f32;
    let tint = 0.5 + slab_vis * (lattice_unit(ix, iy, 1, seed ^ 0x21) - 0.5);
    let grain = fbm2(p.x as f32, p.y as f32, seed ^ 0x22, 2.0, 5, fp);
    let base = mix(
        [0.42, 0.40, 0.37],
        [0.62, 0.58, 0.52],
        tint * 0.7 + grain * 0.5,
    );
    let joint = 1.0
        - (1.0 - periodic_coverage(p.x, PAVING_SLAB_M, 0.0, PAVING_JOINT_M, fp_m))
            * (1.0 - periodic_coverage(p.y, PAVING_SLAB_M, 0.0, PAVING_JOINT_M, fp_m));
    mix(base, [0.2, 0.2, 0.19], joint as f32)
}

fn facade(
    p: &Vector3<f64>,
    n: &Vector3<f64>,
    fp_m: f64,
    wall: Rgb,
    floor_h: f64,
    bay_w: f64,
    seed: u32,
) -> Rgb {
    let fp = fp_m as f32;
    if n.z > 0.5 {
        // Roof: gravel with vents.
        let g = fbm2(p.x as f32, p.y as f32, seed ^ 0x31, 1.0, 6, fp);
        return [0.2 + 0.2 * g, 0.2 + 0.2 * g, 0.21 + 0.2 * g];
    }
    let (s, h) = if n.x.abs() > n.y.abs() {
        (p.y, p.z)
    } else {
        (p.x, p.z)
    };
    let plaster = fbm2(s as f32, h as f32, seed ^ 0x32, 0.7, 7, fp);
    let stains = fbm2(s as f32, h as f32, seed ^ 0x33, 0.1, 3, fp);
    let mut c = scale(wall, 0.55 + 0.8 * (plaster - 0.5) + 0.4 * stains);
    // Cornice stripe between floors.
    let bay = (s / bay_w).floor() as i32;
    if h < GROUND_FLOOR_M {
        // Shop windows and doors on the ground floor.
        let door_bay = lattice_unit(bay, 0, 3, seed) < 0.3;
        let (lo, hi) = if door_bay { (0.0, 2.4) } else { (0.8, 3.2) };
        let cov = periodic_coverage(s, bay_w, 0.12 * bay_w, 0.88 * bay_w, fp_m)
            * stripe_coverage(h, lo, hi, fp_m);
        let glass = if door_bay {
            [0.25, 0.16, 0.1]
        } else {
            let l = lattice_unit(bay, 0, 4, seed);
            [0.1 + 0.3 * l, 0.12 + 0.25 * l, 0.14 + 0.2 * l]
        };
        c = mix(c, glass, cov as f32);
        let band = stripe_coverage(h, GROUND_FLOOR_M - 0.35, GROUND_FLOOR_M, fp_m);
        return mix(c, scale(wall, 0.45), band as f32);
    }
    let hf = h - GROUND_FLOOR_M;
    let floor = (hf / floor_h).floor() as i32;
    let win = periodic_coverage(s, bay_w, 0.25 * bay_w, 0.75 * bay_w, fp_m)
        * periodic_coverage(hf, floor_h, 0.3 * floor_h, 0.8 * floor_h, fp_m);
    let r = lattice_unit(bay, floor, 5, seed);
    let blind = lattice_unit(bay, floor, 6, seed);
    // Window glass: dark blue-grey, some lit warm, some with light blinds in the upper part.
    let mut glass: Rgb = [0.06 + 0.12 * r, 0.08 + 0.13 * r, 0.12 + 0.15 * r];
    if r > 0.85 {
        glass = [0.7, 0.6, 0.4];
    }
    if blind > 0.6 {
        let frac = ((hf.rem_euclid(floor_h) / floor_h - 0.3) / 0.5).clamp(0.0, 1.0);
        if frac > 1.0 - (blind as f64 - 0.6) * 2.0 {
            glass = [0.6, 0.58, 0.52];
        }
    }
    let sill = periodic_coverage(hf, floor_h, 0.25 * floor_h, 0.3 * floor_h, fp_m)
        * periodic_coverage(s, bay_w, 0.2 * bay_w, 0.8 * bay_w, fp_m);
    c = mix(c, glass, win as f32);
    mix(c, scale(wall, 1.3), sill as f32)
}
