//! Fisheye and dual-fisheye rigs (issue 12): the bundled rig files, their coverage, and the
//! renderer's fisheye images checked against the ERP ground truth of the output frame.

use crate::common::repo_path;
use mode360_core::geometry::{ErpGrid, PixelCoord, Projection, Rig};
use mode360_synth::{SceneKind, SynthConfig, SynthRenderer};
use nalgebra::{Point3, Vector3};

const OMNIMVS_RIG: &str = "launch_configs/rig_omnimvs.yaml";
const DUAL_RIG: &str = "launch_configs/rig_dual_fisheye.yaml";
/// Camera height above the road in both rigs, metres.
const CAMERA_HEIGHT_M: f64 = 1.8;

fn rig(rel: &str) -> Rig {
    Rig::from_file(repo_path(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn renderer(seed: u64, width: usize, soiled: bool, scene: SceneKind) -> SynthRenderer {
    SynthRenderer::new(SynthConfig {
        seed,
        width,
        soiled,
        scene,
        ..SynthConfig::default()
    })
    .expect("valid config")
}

/// `n` directions spread evenly over the sphere (Fibonacci lattice).
fn sphere_directions(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f64;
            Vector3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

/// How many cameras of `rig` see the output-frame point `p_out`.
fn cameras_seeing(rig: &Rig, p_out: &Vector3<f64>) -> usize {
    let p_rig = rig.rig_from_output * Point3::from(*p_out);
    rig.cameras
        .iter()
        .filter(|c| {
            let p_cam = c.rig_from_cam.inverse_transform_point(&p_rig).coords;
            match &c.projection {
                Projection::Equirectangular => true,
                p => p.fisheye_model().and_then(|m| m.project(&p_cam)).is_some(),
            }
        })
        .count()
}

#[test]
fn fisheye_rigs_load_with_a_rep103_output_frame_at_the_rack_centre() {
    for (rel, model, size) in [
        (OMNIMVS_RIG, "double_sphere", (384, 384)),
        (DUAL_RIG, "dual_fisheye", (512, 256)),
    ] {
        let rig = rig(rel);
        assert_eq!(rig.cameras.len(), 4, "{rel}");
        assert_eq!(rig.output_frame_id, "rack_center", "{rel}");
        let t = rig.rig_from_output.translation.vector;
        assert!((t - Vector3::new(0.0, 0.0, CAMERA_HEIGHT_M)).norm() < 1e-12);
        assert!(rig.rig_from_output.rotation.angle() < 1e-12, "{rel}");
        for c in &rig.cameras {
            assert_eq!(c.projection.name(), model, "{rel} {}", c.name);
            let s = c.projection.image_size().expect("fisheye size");
            assert_eq!((s.width, s.height), size, "{rel} {}", c.name);
            // Corners of the 1 m square at camera height.
            let p = c.rig_from_cam.translation.vector;
            assert!((p.x.abs() - 0.5).abs() < 1e-12 && (p.y.abs() - 0.5).abs() < 1e-12);
            assert!((p.z - CAMERA_HEIGHT_M).abs() < 1e-12);
        }
    }
    // The OmniMVS-like cameras look outward along their corner's diagonal, image top up.
    let omni = rig(OMNIMVS_RIG);
    for c in &omni.cameras {
        let axis = c.rig_from_cam.rotation * Vector3::z();
        let outward = c.rig_from_cam.translation.vector.xy().normalize();
        assert!(
            (axis.xy() - outward).norm() < 1e-9 && axis.z.abs() < 1e-9,
            "{}",
            c.name
        );
        let down = c.rig_from_cam.rotation * Vector3::y();
        assert!((down + Vector3::z()).norm() < 1e-9, "{}", c.name);
    }
}

#[test]
fn every_direction_is_seen_by_two_omnimvs_cameras() {
    let omni = rig(OMNIMVS_RIG);
    let dual = rig(DUAL_RIG);
    let dirs = sphere_directions(4000);
    // (Nearer than about 1.8 m, straight below the rack is outside every lens circle: that is
    // under the car's roof.)
    for range_m in [5.0, 50.0] {
        let counts: Vec<usize> = dirs
            .iter()
            .map(|d| cameras_seeing(&omni, &(d * range_m)))
            .collect();
        let min = *counts.iter().min().expect("directions");
        let two = counts.iter().filter(|&&n| n == 2).count();
        assert!(
            min >= 2,
            "at {range_m} m some direction is seen by {min} cameras"
        );
        // Not trivially everything: the rear of a front camera is not seen by it.
        assert!(
            two > dirs.len() / 10,
            "at {range_m} m only {two} directions seen twice"
        );
        // Each dual-fisheye camera alone sees the whole sphere.
        for d in &dirs {
            assert_eq!(
                cameras_seeing(&dual, &(d * range_m)),
                4,
                "{d:?} at {range_m} m"
            );
        }
    }
}

/// Compares camera `camera`'s rendered range along each sampled pixel's ray with the ground
/// truth's range at the same world point; returns (compared pixels, agreeing pixels).
fn range_agreement(rig: &Rig, r: &SynthRenderer, index: usize, camera: usize) -> (usize, usize) {
    let frame = r.render_frame(rig, index);
    let gt = frame.ground_truth.expect("ground truth");
    let grid = ErpGrid::new(gt.width).expect("grid");
    let view = r.render_rig_camera(rig, index, camera).expect("camera");
    assert_eq!(
        view.image, frame.images[camera],
        "same image as in the frame"
    );
    let model = rig.cameras[camera].projection.clone();
    let max_depth = r.config().max_depth_m as f32;
    let (w, h) = (view.range_m.width, view.range_m.height);
    let (mut compared, mut agree) = (0, 0);
    for v in (0..h).step_by(3) {
        for u in (0..w).step_by(3) {
            let range = view.range_m.get(u, v);
            if range.is_nan() || range >= max_depth {
                continue;
            }
            let px = PixelCoord {
                u: u as f64,
                v: v as f64,
            };
            let (origin, dir) = match &model {
                Projection::DualFisheye(d) => {
                    let ray = d.unproject_ray(px).expect("seen pixel");
                    (ray.origin.coords, ray.dir.into_inner())
                }
                p => {
                    let m = p.fisheye_model().expect("fisheye");
                    (
                        Vector3::zeros(),
                        m.unproject(px).expect("seen pixel").into_inner(),
                    )
                }
            };
            let p_cam = origin + dir * f64::from(range);
            let p_rig = rig.cameras[camera].rig_from_cam * Point3::from(p_cam);
            let p_out = rig.rig_from_output.inverse_transform_point(&p_rig).coords;
            let q = grid.pixel_from_dir(&p_out);
            let gu = (q.u.round() as usize) % grid.width();
            let gv = (q.v.round().max(0.0) as usize).min(grid.height() - 1);
            let expected = p_out.norm() as f32;
            compared += 1;
            if (gt.get(gu, gv) - expected).abs() <= 0.03 * expected + 0.02 {
                agree += 1;
            }
        }
    }
    (compared, agree)
}

#[test]
fn fisheye_ranges_match_the_ground_truth_of_the_output_frame() {
    // Quarter resolution (96 x 96) against a 512-wide ground truth.
    let omni = rig(OMNIMVS_RIG).scaled(0.25).expect("scaled rig");
    let r = renderer(5, 512, false, SceneKind::Street);
    for camera in [0, 3] {
        let (compared, agree) = range_agreement(&omni, &r, 2, camera);
        let share = agree as f64 / compared as f64;
        println!("omnimvs camera {camera}: {agree} of {compared} agree ({share:.3})");
        assert!(compared > 300, "only {compared} pixels with a surface");
        assert!(share > 0.9, "only {agree} of {compared} agree");
    }
    let dual = rig(DUAL_RIG).scaled(0.5).expect("scaled rig");
    let (compared, agree) = range_agreement(&dual, &r, 2, 1);
    let share = agree as f64 / compared as f64;
    println!("dual camera 1: {agree} of {compared} agree ({share:.3})");
    assert!(compared > 300 && share > 0.9, "{agree} of {compared}");
}

#[test]
fn pixels_outside_the_lens_are_black_and_rendering_is_deterministic() {
    let omni = rig(OMNIMVS_RIG).scaled(0.25).expect("scaled rig");
    let dual = rig(DUAL_RIG).scaled(0.25).expect("scaled rig");
    for scene in [SceneKind::Street, SceneKind::Objects] {
        for rig in [&omni, &dual] {
            let a = renderer(9, 64, true, scene).render_frame(rig, 4);
            let b = renderer(9, 64, true, scene).render_frame(rig, 4);
            assert_eq!(a.ground_truth, b.ground_truth);
            let gt = a.ground_truth.as_ref().expect("ground truth");
            assert_eq!(
                (gt.width, gt.height),
                (64, 32),
                "ERP ground truth at --width"
            );
            for (ci, (img, again)) in a.images.iter().zip(&b.images).enumerate() {
                assert_eq!(img.as_raw(), again.as_raw(), "camera {ci} deterministic");
                let cam = &rig.cameras[ci];
                let size = cam.projection.image_size().expect("fisheye");
                assert_eq!(img.dimensions(), (size.width, size.height));
                let model = cam.projection.fisheye_model().expect("fisheye");
                let (mut unseen, mut dark_seen, mut seen) = (0, 0, 0);
                for (x, y, p) in img.enumerate_pixels() {
                    let px = PixelCoord {
                        u: x as f64,
                        v: y as f64,
                    };
                    if model.unproject(px).is_none() {
                        assert_eq!(p.0, [0, 0, 0], "camera {ci} pixel {x},{y} outside the lens");
                        unseen += 1;
                    } else {
                        seen += 1;
                        if p.0 == [0, 0, 0] {
                            dark_seen += 1;
                        }
                    }
                }
                // The corners are outside every lens circle; the lens circles are lit.
                assert_eq!(img.get_pixel(0, 0).0, [0, 0, 0]);
                assert!(unseen > 0 && seen > 4 * unseen, "{seen} seen, {unseen} not");
                assert!(dark_seen * 100 < seen, "{dark_seen} black pixels of {seen}");
            }
        }
    }
    // Another seed changes the images.
    let a = renderer(9, 64, false, SceneKind::Objects).render_frame(&omni, 4);
    let c = renderer(10, 64, false, SceneKind::Objects).render_frame(&omni, 4);
    assert_ne!(a.images[0].as_raw(), c.images[0].as_raw());
}

#[test]
fn scaled_rig_keeps_poses_and_scales_fisheye_sizes() {
    let omni = rig(OMNIMVS_RIG);
    let half = omni.scaled(0.5).expect("half");
    for (a, b) in omni.cameras.iter().zip(&half.cameras) {
        assert_eq!(a.rig_from_cam, b.rig_from_cam);
        let s = b.projection.image_size().expect("fisheye");
        assert_eq!((s.width, s.height), (192, 192));
    }
    assert_eq!(half.rig_from_output, omni.rig_from_output);
    // The scaled rig survives the YAML round trip a bag makes.
    let back = Rig::from_yaml_str(&half.to_yaml(), "scaled").expect("yaml");
    for (a, b) in back.cameras.iter().zip(&half.cameras) {
        assert_eq!(a.projection, b.projection);
        assert!(a.rig_from_cam.rotation.angle_to(&b.rig_from_cam.rotation) < 1e-12);
    }
    let dual = rig(DUAL_RIG).scaled(0.3).expect("dual");
    let s = dual.cameras[0].projection.image_size().expect("dual size");
    assert_eq!((s.width, s.height), (154, 77), "width rounded to even");
    let e = omni.scaled(0.0).expect_err("zero factor");
    assert!(e.to_string().contains("front_left"), "{e}");
}
