//! Random fisheye and dual-fisheye roof racks for training, so that one set of weights serves
//! 360° cameras, wide fisheyes (OmniMVS-like) and dual-fisheye 360° cameras.
//!
//! A rig of seed `s` (a pure function of `s` and the ERP width): 3 to 5 cameras placed like
//! [`super::rack::random_rig`]'s; with probability [`DUAL_FISHEYE_CHANCE`] every camera is a
//! dual-fisheye 360° camera (two Kannala-Brandt lenses of [`DUAL_LENS_HALF_FOV_RAD`] back to
//! back, upright, random yaw), otherwise a single Kannala-Brandt fisheye whose half field of
//! view is drawn from [`MIN_HALF_FOV_RAD`, `MAX_HALF_FOV_RAD`], looking outward from the rack's
//! centre (yaw jitter [`MAX_YAW_JITTER_RAD`], tilt [`MAX_TILT_RAD`]). The equidistant lens maps
//! `r = f theta`: `f = r_edge / half_fov` puts the field-of-view circle on the image's sides.
//! Images are square, [`FISHEYE_SIDE_FRACTION`] of the ERP width (dual: two such squares).
//! Depth is estimated in `rack_center`, a REP 103 frame at the rack's centre at the mean
//! camera height, as on such rigs in practice (no camera's optical frame is upright).

use super::rack::{rack_positions, MAX_HEIGHT_M, MIN_HEIGHT_M};
use mode360_core::geometry::camera::{
    DualFisheye, DualLens, FisheyeCamera, FisheyeLens, Focal, KannalaBrandt,
};
use mode360_core::geometry::rig::DEFAULT_RIG_FRAME;
use mode360_core::geometry::{
    ImageSize, IntrinsicsError, Projection, Rig, RigCamera, RigError, RigOutput,
};
use mode360_synth::noise::Rng;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::f64::consts::{FRAC_PI_2, PI};

/// Fewest cameras of a random fisheye rig (a 220° lens needs a partner on every side).
pub const MIN_FISHEYE_CAMERAS: usize = 3;
/// Most cameras of a random fisheye rig.
pub const MAX_FISHEYE_CAMERAS: usize = 5;
/// Share of random fisheye rigs made of dual-fisheye 360° cameras.
pub const DUAL_FISHEYE_CHANCE: f64 = 0.35;
/// Half field of view of a single fisheye lens: 190° to 230°.
pub const MIN_HALF_FOV_RAD: f64 = 95.0 * PI / 180.0;
pub const MAX_HALF_FOV_RAD: f64 = 115.0 * PI / 180.0;
/// Half field of view of a dual-fisheye lens (200°).
pub const DUAL_LENS_HALF_FOV_RAD: f64 = 100.0 * PI / 180.0;
/// Distance between the two lenses of a dual-fisheye camera, metres.
pub const DUAL_LENS_SEPARATION_M: f64 = 0.03;
/// Largest deviation of a fisheye's yaw from the outward direction (20°).
pub const MAX_YAW_JITTER_RAD: f64 = 20.0 * PI / 180.0;
/// Largest up or down tilt of a fisheye's axis (8°).
pub const MAX_TILT_RAD: f64 = 8.0 * PI / 180.0;
/// Side of a fisheye image as a fraction of the ERP width (even-rounded).
pub const FISHEYE_SIDE_FRACTION: f64 = 0.75;
/// Smallest fisheye image side, pixels.
const MIN_FISHEYE_SIDE_PX: usize = 16;
/// The output frame of a fisheye rack: REP 103 at the rack's centre, mean camera height.
pub const RACK_CENTRE_FRAME: &str = "rack_center";
/// Domain separation of the fisheye rig stream.
const FISHEYE_RIG_TAG: u64 = 0x7A41_0F15;

/// The side of a fisheye image for ERP width `width`.
pub fn fisheye_side_px(width: usize) -> usize {
    let side = (width as f64 * FISHEYE_SIDE_FRACTION / 2.0).round() as usize * 2;
    side.max(MIN_FISHEYE_SIDE_PX)
}

/// An undistorted Kannala-Brandt lens putting `half_fov_rad` on a circle of radius `side / 2`
/// around `(cx, cy)`.
fn kb_lens(
    side: usize,
    half_fov_rad: f64,
    cx: f64,
    cy: f64,
) -> Result<FisheyeLens, IntrinsicsError> {
    let f = (side as f64 / 2.0) / half_fov_rad;
    let focal = Focal::new(f, f, cx, cy)?;
    Ok(FisheyeLens::KannalaBrandt(KannalaBrandt::new(
        focal, [0.0; 4],
    )?))
}

/// `rig_from_cam` as a translation and roll, pitch, yaw (`R = Rz(yaw) Ry(pitch) Rx(roll)`).
fn pose(translation_m: [f64; 3], [roll, pitch, yaw]: [f64; 3]) -> Isometry3<f64> {
    let [x, y, z] = translation_m;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

/// The random fisheye rig of `seed` for ERP width `width` (see the module docs).
pub fn random_fisheye_rig(seed: u64, width: usize) -> Result<Rig, RigError> {
    let source = format!("<random fisheye rig {seed}>");
    let mut rng = Rng::new(&[seed, FISHEYE_RIG_TAG]);
    let n = MIN_FISHEYE_CAMERAS + rng.index(MAX_FISHEYE_CAMERAS - MIN_FISHEYE_CAMERAS + 1);
    let xy = rack_positions(&mut rng, n);
    let dual = rng.chance(DUAL_FISHEYE_CHANCE);
    let side = fisheye_side_px(width);
    let centre = (side as f64 - 1.0) / 2.0;
    let heights: Vec<f64> = (0..n)
        .map(|_| rng.range(MIN_HEIGHT_M, MAX_HEIGHT_M))
        .collect();
    let mean_height = heights.iter().sum::<f64>() / n as f64;
    let mut cameras = Vec::with_capacity(n);
    for (k, (p, z)) in xy.iter().zip(&heights).enumerate() {
        let c = k + 1;
        let name = format!("cam{c}");
        let intrinsics_err = |e: IntrinsicsError| RigError::Camera {
            file: source.clone(),
            camera: name.clone(),
            field: e.field,
            problem: e.problem,
        };
        let outward = p[1].atan2(p[0]);
        let yaw = outward + rng.range(-MAX_YAW_JITTER_RAD, MAX_YAW_JITTER_RAD);
        let (projection, rig_from_cam) = if dual {
            let lens = |i: usize, x: f64, lens_yaw: f64| -> Result<DualLens, IntrinsicsError> {
                Ok(DualLens {
                    model: kb_lens(
                        side,
                        DUAL_LENS_HALF_FOV_RAD,
                        centre + (i * side) as f64,
                        centre,
                    )?,
                    cam_from_lens: pose([x, 0.0, 0.0], [-FRAC_PI_2, 0.0, lens_yaw]),
                })
            };
            let lenses = [
                lens(0, DUAL_LENS_SEPARATION_M / 2.0, -FRAC_PI_2).map_err(intrinsics_err)?,
                lens(1, -DUAL_LENS_SEPARATION_M / 2.0, FRAC_PI_2).map_err(intrinsics_err)?,
            ];
            let size = ImageSize::new(2 * side as u32, side as u32).map_err(intrinsics_err)?;
            let camera = DualFisheye::new(lenses, size).map_err(intrinsics_err)?;
            (
                Projection::DualFisheye(camera),
                pose([p[0], p[1], *z], [0.0, 0.0, yaw]),
            )
        } else {
            let half_fov = rng.range(MIN_HALF_FOV_RAD, MAX_HALF_FOV_RAD);
            let tilt = rng.range(-MAX_TILT_RAD, MAX_TILT_RAD);
            let size = ImageSize::new(side as u32, side as u32).map_err(intrinsics_err)?;
            let lens = kb_lens(side, half_fov, centre, centre).map_err(intrinsics_err)?;
            let camera = FisheyeCamera::new(lens, size).map_err(intrinsics_err)?;
            // The optical axis (z) along `yaw`, the image's top up, tilted by `tilt`.
            (
                Projection::Fisheye(camera),
                pose([p[0], p[1], *z], [-FRAC_PI_2 + tilt, 0.0, yaw - FRAC_PI_2]),
            )
        };
        cameras.push(RigCamera {
            topic: format!("/cam{c}/image_raw"),
            frame_id: format!("cam{c}_link"),
            name,
            projection,
            rig_from_cam,
        });
    }
    let output = RigOutput {
        frame_id: RACK_CENTRE_FRAME.into(),
        rig_from_output: Isometry3::translation(0.0, 0.0, mean_height),
    };
    Rig::new(DEFAULT_RIG_FRAME, cameras, 0, Some(output)).map_err(|e| e.in_source(&source))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::panorama::{poorly_seen_fraction, rig_panoramas};
    use mode360_core::geometry::ErpGrid;
    use nalgebra::Vector3;

    #[test]
    fn random_fisheye_rigs_load_and_see_around() {
        let grid = ErpGrid::new(64).unwrap();
        let mut duals = 0;
        let mut poorly_seen = Vec::new();
        for seed in 0..12 {
            let rig = random_fisheye_rig(seed, 128).unwrap();
            assert!(rig.cameras.len() >= MIN_FISHEYE_CAMERAS);
            assert!(rig
                .cameras
                .iter()
                .all(|c| !c.projection.is_equirectangular()));
            duals += usize::from(rig.cameras[0].projection.name() == "dual_fisheye");
            // Each single fisheye looks outward: its panorama's forward is within the jitter
            // of the direction from the rack's centre.
            for (cam, pano) in rig.cameras.iter().zip(rig_panoramas(&rig)) {
                let fwd = pano.rig_from_panorama.rotation * Vector3::x();
                if cam.projection.name() != "dual_fisheye" {
                    let out = cam.rig_from_cam.translation.vector;
                    let angle =
                        (fwd.y.atan2(fwd.x) - out.y.atan2(out.x) + 3.0 * PI) % (2.0 * PI) - PI;
                    assert!(angle.abs() <= MAX_YAW_JITTER_RAD + 1e-9, "{angle}");
                    assert!(fwd.z.abs() <= MAX_TILT_RAD.sin() + 1e-9);
                }
            }
            poorly_seen.push(poorly_seen_fraction(&rig, grid, 50.0));
        }
        assert!(duals > 0 && duals < 12, "{duals}");
        // Far away, most rigs see nearly every direction with two cameras; a few clustered
        // racks leave gaps (the network learns low confidence there).
        poorly_seen.sort_by(f64::total_cmp);
        assert!(poorly_seen[poorly_seen.len() / 2] < 0.1, "{poorly_seen:?}");
        assert!(poorly_seen[poorly_seen.len() - 1] < 0.6, "{poorly_seen:?}");
    }
}
