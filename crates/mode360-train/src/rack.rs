//! Random roof racks, the base of every random training rig: `2..=5` cameras placed uniformly
//! in a `RACK_HALF_SIZE_M`-square around the rig origin (at least `MIN_CAMERA_SEPARATION_M`
//! apart), heights in `[MIN_HEIGHT_M, MAX_HEIGHT_M]`, small random roll/pitch/yaw per camera;
//! camera 1 is the reference and output frame. The other families
//! ([`super::rig_layouts`], [`super::fisheye_rigs`]) reuse the placement and the constants.

use mode360_core::geometry::rig::DEFAULT_RIG_FRAME;
use mode360_core::geometry::{Projection, Rig, RigCamera, RigError};
use mode360_synth::noise::Rng;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// Fewest cameras of a random rig.
pub const MIN_RIG_CAMERAS: usize = 2;
/// Most cameras of a random rig.
pub const MAX_RIG_CAMERAS: usize = 5;
/// Cameras are placed in `[-RACK_HALF_SIZE_M, RACK_HALF_SIZE_M]^2` (a 1.5 m roof rack).
pub const RACK_HALF_SIZE_M: f64 = 0.75;
/// Two cameras of a random rig are at least this far apart horizontally.
pub const MIN_CAMERA_SEPARATION_M: f64 = 0.3;
/// Camera heights above the road, metres.
pub const MIN_HEIGHT_M: f64 = 1.5;
pub const MAX_HEIGHT_M: f64 = 2.2;
/// Largest random roll, pitch and yaw of a camera, radians (5 degrees).
pub const MAX_TILT_RAD: f64 = 0.087;
/// Placement attempts per camera before the separation constraint is relaxed.
const PLACEMENT_ATTEMPTS: usize = 64;
/// Domain-separation word of a random roof rack's stream.
const RIG_SEED_WORD: u64 = 0x416;

/// One camera's place on a rig: `rig_from_cam` as a translation (metres) and roll, pitch, yaw
/// (radians, `R = Rz(yaw) Ry(pitch) Rx(roll)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraPose {
    pub translation_m: [f64; 3],
    pub rpy_rad: [f64; 3],
}

/// An ERP rig of `cam1..camN` at `poses` (camera 1 the reference and output frame), validated
/// by [`Rig::new`]; errors name `source`. The one place where training builds ERP rigs.
pub fn rig_from_poses(poses: &[CameraPose], source: &str) -> Result<Rig, RigError> {
    let cameras = poses
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let ([x, y, z], [roll, pitch, yaw]) = (pose.translation_m, pose.rpy_rad);
            let c = k + 1;
            RigCamera {
                name: format!("cam{c}"),
                topic: format!("/cam{c}/image_raw"),
                frame_id: format!("cam{c}_link"),
                projection: Projection::Equirectangular,
                rig_from_cam: Isometry3::from_parts(
                    Translation3::new(x, y, z),
                    UnitQuaternion::from_euler_angles(roll, pitch, yaw),
                ),
            }
        })
        .collect();
    Rig::new(DEFAULT_RIG_FRAME, cameras, 0, None).map_err(|e| e.in_source(source))
}

/// The roof rack's poses (what [`random_rig`] builds), drawn from `rng`.
pub fn roof_poses(rng: &mut Rng) -> Vec<CameraPose> {
    let n = MIN_RIG_CAMERAS + rng.index(MAX_RIG_CAMERAS - MIN_RIG_CAMERAS + 1);
    let xy = rack_positions(rng, n);
    xy.iter()
        .map(|p| {
            let z = rng.range(MIN_HEIGHT_M, MAX_HEIGHT_M);
            let rpy_rad = [
                rng.range(-MAX_TILT_RAD, MAX_TILT_RAD),
                rng.range(-MAX_TILT_RAD, MAX_TILT_RAD),
                rng.range(-MAX_TILT_RAD, MAX_TILT_RAD),
            ];
            CameraPose {
                translation_m: [p[0], p[1], z],
                rpy_rad,
            }
        })
        .collect()
}

/// `n` camera positions on the roof rack (`[x, y]`, metres), at least
/// `MIN_CAMERA_SEPARATION_M` apart where `PLACEMENT_ATTEMPTS` draws allow.
pub fn rack_positions(rng: &mut Rng, n: usize) -> Vec<[f64; 2]> {
    let mut xy: Vec<[f64; 2]> = Vec::with_capacity(n);
    for _ in 0..n {
        let mut best = [0.0, 0.0];
        let mut best_sep = f64::NEG_INFINITY;
        for _ in 0..PLACEMENT_ATTEMPTS {
            let p = [
                rng.range(-RACK_HALF_SIZE_M, RACK_HALF_SIZE_M),
                rng.range(-RACK_HALF_SIZE_M, RACK_HALF_SIZE_M),
            ];
            let sep = xy
                .iter()
                .map(|q| (p[0] - q[0]).hypot(p[1] - q[1]))
                .fold(f64::INFINITY, f64::min);
            if sep > best_sep {
                best = p;
                best_sep = sep;
            }
            if sep >= MIN_CAMERA_SEPARATION_M {
                break;
            }
        }
        xy.push(best);
    }
    xy
}

/// A random roof-rack rig (see the module docs), built by [`rig_from_poses`].
pub fn random_rig(seed: u64) -> Result<Rig, RigError> {
    let mut rng = Rng::new(&[seed, RIG_SEED_WORD]);
    rig_from_poses(&roof_poses(&mut rng), &format!("<random rig {seed}>"))
}
