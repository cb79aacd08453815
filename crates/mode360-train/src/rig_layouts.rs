//! Rig layout families for training (issue 19: one set of weights for every layout the node
//! accepts). `--rig-layouts roof` keeps today's stream: every random ERP rig is a roof rack
//! ([`super::rack::random_rig`]). With `--rig-layouts any`, a random (non-Deep360,
//! non-fisheye) rig of sample `k` is drawn from one of these families, the family from its own
//! stream `Rng::new(&[s, k, LAYOUT_TAG])` ([`draw_family`]), the rig a pure function of the
//! family and the sample's rig seed ([`layout_rig`]):
//!
//! | family | cameras | positions (rig frame: x forward, y left, z up from the road) | rotations |
//! |---|---|---|---|
//! | [`LayoutFamily::RoofRack`] | 2..=5 | today's roof rack: `[-0.75, 0.75]^2` m, 1.5..2.2 m high | roll, pitch, yaw up to 5° |
//! | [`LayoutFamily::VerticalMast`] | [`MAST_MIN_CAMERAS`]..=[`MAST_MAX_CAMERAS`] | one mast anywhere on the rack, base [`MAST_MIN_BASE_HEIGHT_M`]..[`MAST_MAX_BASE_HEIGHT_M`], cameras [`MAST_MIN_GAP_M`]..[`MAST_MAX_GAP_M`] apart upwards, each off the mast's axis by up to [`MAST_JITTER_M`] in x and y | yaw any, roll and pitch up to [`MAST_MAX_TILT_RAD`] |
//! | [`LayoutFamily::TurnedMixedHeights`] | 2..=5 | the roof rack's square, heights [`TURNED_MIN_HEIGHT_M`]..[`TURNED_MAX_HEIGHT_M`] (tilted baselines) | yaw any, roll and pitch up to [`TURNED_MAX_ROLL_PITCH_RAD`] |
//! | [`LayoutFamily::BodyCorners`] | 2..=5 of 6 slots | the car body's corners `(±L, ±W)` at bumper height [`BUMPER_MIN_HEIGHT_M`]..[`BUMPER_MAX_HEIGHT_M`], and two mirrors `(x_m, ±(W + MIRROR_OUTSET_M))` at [`MIRROR_MIN_HEIGHT_M`]..[`MIRROR_MAX_HEIGHT_M`]; `L` in [`BODY_MIN_HALF_LENGTH_M`]..[`BODY_MAX_HALF_LENGTH_M`], `W` in [`BODY_MIN_HALF_WIDTH_M`]..[`BODY_MAX_HALF_WIDTH_M`], `x_m` in [`MIRROR_MIN_X_M`]..[`MIRROR_MAX_X_M`] | yaw outward from the body's centre ± [`BODY_MAX_YAW_JITTER_RAD`], roll and pitch up to [`BODY_MAX_TILT_RAD`] |
//!
//! Families are drawn with the weights [`FAMILY_WEIGHTS`]. Camera 1 is the reference and the
//! output frame in every family (ground truth is camera 1's range, in its frame: a turned
//! camera 1 turns the output too); in the mast and body families the slot that becomes camera 1
//! is random, so the reference is not always the lowest or the front camera. Every rig is
//! built by [`rig_from_poses`] (YAML text validated by [`Rig::from_yaml_str`]).

use super::rack::{
    rack_positions, random_rig, rig_from_poses, CameraPose, MAX_RIG_CAMERAS, MIN_RIG_CAMERAS,
    RACK_HALF_SIZE_M,
};
use mode360_core::geometry::{Rig, RigError};
use mode360_synth::noise::Rng;
use std::f64::consts::PI;

/// Which layouts random training rigs take.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum RigLayouts {
    /// Horizontal roof racks only (the stream of runs before layouts existed).
    #[default]
    Roof,
    /// Every family of this module: roof racks, vertical masts, turned cameras at mixed
    /// heights, cameras on the car body's corners.
    Any,
}

impl RigLayouts {
    pub fn as_str(self) -> &'static str {
        match self {
            RigLayouts::Roof => "roof",
            RigLayouts::Any => "any",
        }
    }
}

/// A family of random rig layouts (see the module docs for the ranges).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LayoutFamily {
    RoofRack,
    VerticalMast,
    TurnedMixedHeights,
    BodyCorners,
}

impl LayoutFamily {
    /// Every family, in the order of [`FAMILY_WEIGHTS`].
    pub const ALL: [LayoutFamily; 4] = [
        LayoutFamily::RoofRack,
        LayoutFamily::VerticalMast,
        LayoutFamily::TurnedMixedHeights,
        LayoutFamily::BodyCorners,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            LayoutFamily::RoofRack => "roof_rack",
            LayoutFamily::VerticalMast => "vertical_mast",
            LayoutFamily::TurnedMixedHeights => "turned_mixed_heights",
            LayoutFamily::BodyCorners => "body_corners",
        }
    }
}

/// Probability of each family of [`LayoutFamily::ALL`] with `--rig-layouts any` (sums to 1).
pub const FAMILY_WEIGHTS: [f64; 4] = [0.25, 0.25, 0.25, 0.25];

/// Fewest and most cameras on a vertical mast.
pub const MAST_MIN_CAMERAS: usize = 2;
pub const MAST_MAX_CAMERAS: usize = 3;
/// Height of the mast's lowest camera above the road, metres.
pub const MAST_MIN_BASE_HEIGHT_M: f64 = 1.0;
pub const MAST_MAX_BASE_HEIGHT_M: f64 = 1.9;
/// Vertical gap between neighbouring cameras on the mast, metres.
pub const MAST_MIN_GAP_M: f64 = 0.2;
pub const MAST_MAX_GAP_M: f64 = 0.6;
/// Largest horizontal offset (per axis) of a mast camera from the mast's axis, metres.
pub const MAST_JITTER_M: f64 = 0.05;
/// Largest roll and pitch of a mast camera, radians (5°).
pub const MAST_MAX_TILT_RAD: f64 = 5.0 * PI / 180.0;

/// Camera heights of the turned family, metres.
pub const TURNED_MIN_HEIGHT_M: f64 = 1.2;
pub const TURNED_MAX_HEIGHT_M: f64 = 2.4;
/// Largest roll and pitch of a turned camera, radians (30°); its yaw is uniform.
pub const TURNED_MAX_ROLL_PITCH_RAD: f64 = 30.0 * PI / 180.0;

/// Half length (bumper corners at `x = ±L`) of the car body, metres.
pub const BODY_MIN_HALF_LENGTH_M: f64 = 1.9;
pub const BODY_MAX_HALF_LENGTH_M: f64 = 2.4;
/// Half width (bumper corners at `y = ±W`) of the car body, metres.
pub const BODY_MIN_HALF_WIDTH_M: f64 = 0.8;
pub const BODY_MAX_HALF_WIDTH_M: f64 = 1.0;
/// Bumper camera heights above the road, metres.
pub const BUMPER_MIN_HEIGHT_M: f64 = 0.5;
pub const BUMPER_MAX_HEIGHT_M: f64 = 0.9;
/// Mirror camera heights above the road, metres.
pub const MIRROR_MIN_HEIGHT_M: f64 = 0.9;
pub const MIRROR_MAX_HEIGHT_M: f64 = 1.3;
/// Mirror position along x (forward of the body's centre), metres.
pub const MIRROR_MIN_X_M: f64 = 0.4;
pub const MIRROR_MAX_X_M: f64 = 1.0;
/// How far a mirror sticks out beyond the body's side, metres.
pub const MIRROR_OUTSET_M: f64 = 0.1;
/// Largest deviation of a body camera's yaw from the outward direction, radians (20°).
pub const BODY_MAX_YAW_JITTER_RAD: f64 = 20.0 * PI / 180.0;
/// Largest roll and pitch of a body camera, radians (5°).
pub const BODY_MAX_TILT_RAD: f64 = 5.0 * PI / 180.0;
/// Camera slots on the body: four bumper corners and two mirrors.
const BODY_SLOTS: usize = 6;

/// Domain separation of the family stream (per sample) and of the layout rigs (per seed).
pub(super) const LAYOUT_TAG: u64 = 0x7A41_0006;
const LAYOUT_RIG_TAG: u64 = 0x7A41_1A70;

/// The family of training sample `index` of stream `seed` under `--rig-layouts any`.
pub fn draw_family(seed: u64, index: u64) -> LayoutFamily {
    let u = Rng::new(&[seed, index, LAYOUT_TAG]).unit();
    let mut acc = 0.0;
    for (family, w) in LayoutFamily::ALL.iter().zip(FAMILY_WEIGHTS) {
        acc += w;
        if u < acc {
            return *family;
        }
    }
    LayoutFamily::ALL[LayoutFamily::ALL.len() - 1]
}

/// The rig of `family` for rig seed `seed` (a pure function of both).
pub fn layout_rig(family: LayoutFamily, seed: u64) -> Result<Rig, RigError> {
    let source = format!("<random {} rig {seed}>", family.as_str());
    match family {
        LayoutFamily::RoofRack => random_rig(seed),
        LayoutFamily::VerticalMast => rig_from_poses(&mast_poses(seed), &source),
        LayoutFamily::TurnedMixedHeights => rig_from_poses(&turned_poses(seed), &source),
        LayoutFamily::BodyCorners => rig_from_poses(&body_poses(seed), &source),
    }
}

fn family_rng(family: LayoutFamily, seed: u64) -> Rng {
    Rng::new(&[seed, LAYOUT_RIG_TAG, family as u64])
}

/// Fisher-Yates shuffle of `items` from `rng`.
fn shuffle<T>(items: &mut [T], rng: &mut Rng) {
    for i in (1..items.len()).rev() {
        items.swap(i, rng.index(i + 1));
    }
}

fn mast_poses(seed: u64) -> Vec<CameraPose> {
    let mut rng = family_rng(LayoutFamily::VerticalMast, seed);
    let n = MAST_MIN_CAMERAS + rng.index(MAST_MAX_CAMERAS - MAST_MIN_CAMERAS + 1);
    let axis = [
        rng.range(-RACK_HALF_SIZE_M, RACK_HALF_SIZE_M),
        rng.range(-RACK_HALF_SIZE_M, RACK_HALF_SIZE_M),
    ];
    let mut z = rng.range(MAST_MIN_BASE_HEIGHT_M, MAST_MAX_BASE_HEIGHT_M);
    let mut poses = Vec::with_capacity(n);
    for k in 0..n {
        if k > 0 {
            z += rng.range(MAST_MIN_GAP_M, MAST_MAX_GAP_M);
        }
        poses.push(CameraPose {
            translation_m: [
                axis[0] + rng.range(-MAST_JITTER_M, MAST_JITTER_M),
                axis[1] + rng.range(-MAST_JITTER_M, MAST_JITTER_M),
                z,
            ],
            rpy_rad: [
                rng.range(-MAST_MAX_TILT_RAD, MAST_MAX_TILT_RAD),
                rng.range(-MAST_MAX_TILT_RAD, MAST_MAX_TILT_RAD),
                rng.range(-PI, PI),
            ],
        });
    }
    shuffle(&mut poses, &mut rng);
    poses
}

fn turned_poses(seed: u64) -> Vec<CameraPose> {
    let mut rng = family_rng(LayoutFamily::TurnedMixedHeights, seed);
    let n = MIN_RIG_CAMERAS + rng.index(MAX_RIG_CAMERAS - MIN_RIG_CAMERAS + 1);
    let xy = rack_positions(&mut rng, n);
    xy.iter()
        .map(|p| CameraPose {
            translation_m: [
                p[0],
                p[1],
                rng.range(TURNED_MIN_HEIGHT_M, TURNED_MAX_HEIGHT_M),
            ],
            rpy_rad: [
                rng.range(-TURNED_MAX_ROLL_PITCH_RAD, TURNED_MAX_ROLL_PITCH_RAD),
                rng.range(-TURNED_MAX_ROLL_PITCH_RAD, TURNED_MAX_ROLL_PITCH_RAD),
                rng.range(-PI, PI),
            ],
        })
        .collect()
}

fn body_poses(seed: u64) -> Vec<CameraPose> {
    let mut rng = family_rng(LayoutFamily::BodyCorners, seed);
    let n = MIN_RIG_CAMERAS + rng.index(MAX_RIG_CAMERAS - MIN_RIG_CAMERAS + 1);
    let half_length = rng.range(BODY_MIN_HALF_LENGTH_M, BODY_MAX_HALF_LENGTH_M);
    let half_width = rng.range(BODY_MIN_HALF_WIDTH_M, BODY_MAX_HALF_WIDTH_M);
    let mirror_x = rng.range(MIRROR_MIN_X_M, MIRROR_MAX_X_M);
    let mirror_y = half_width + MIRROR_OUTSET_M;
    // Slots 0..4: bumper corners (front left, front right, rear left, rear right); 4, 5: the
    // left and right mirrors.
    let mut slots: Vec<usize> = (0..BODY_SLOTS).collect();
    shuffle(&mut slots, &mut rng);
    slots[..n]
        .iter()
        .map(|&slot| {
            let (x, y, z) = match slot {
                0..=3 => (
                    if slot < 2 { half_length } else { -half_length },
                    if slot % 2 == 0 {
                        half_width
                    } else {
                        -half_width
                    },
                    rng.range(BUMPER_MIN_HEIGHT_M, BUMPER_MAX_HEIGHT_M),
                ),
                _ => (
                    mirror_x,
                    if slot == 4 { mirror_y } else { -mirror_y },
                    rng.range(MIRROR_MIN_HEIGHT_M, MIRROR_MAX_HEIGHT_M),
                ),
            };
            let outward = y.atan2(x);
            CameraPose {
                translation_m: [x, y, z],
                rpy_rad: [
                    rng.range(-BODY_MAX_TILT_RAD, BODY_MAX_TILT_RAD),
                    rng.range(-BODY_MAX_TILT_RAD, BODY_MAX_TILT_RAD),
                    outward + rng.range(-BODY_MAX_YAW_JITTER_RAD, BODY_MAX_YAW_JITTER_RAD),
                ],
            }
        })
        .collect()
}
