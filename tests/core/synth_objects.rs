//! Random-objects scenes and varied streets: determinism per seed, near and far ground truth,
//! an independent brute-force ray check, the cameras' keep-out zone, soiling, render speed,
//! and per-seed street layouts (with the regular street unchanged).

use crate::common::deep360_rig;
use mode360::geometry::{ErpGrid, PixelCoord, Rig};
use mode360::synth::bvh::Ray;
use mode360::synth::objects::{keep_out_box, objects_scene, KEEP_OUT_M};
use mode360::synth::world::{StreetLayout, WorldParams};
use mode360::synth::{SceneKind, StreetStyle, SynthConfig, SynthRenderer};
use nalgebra::Vector3;

const MAX_DEPTH_M: f32 = 1000.0;

fn objects(seed: u64, width: usize, soiled: bool) -> SynthRenderer {
    SynthRenderer::new(SynthConfig {
        seed,
        width,
        soiled,
        scene: SceneKind::Objects,
        ..SynthConfig::default()
    })
    .expect("valid config")
}

fn varied(seed: u64, width: usize) -> SynthRenderer {
    SynthRenderer::new(SynthConfig {
        seed,
        width,
        street: StreetStyle::Varied,
        ..SynthConfig::default()
    })
    .expect("valid config")
}

fn differing_bytes(a: &[image::RgbImage], b: &[image::RgbImage]) -> usize {
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            x.as_raw()
                .iter()
                .zip(y.as_raw())
                .filter(|(p, q)| p != q)
                .count()
        })
        .sum()
}

#[test]
fn objects_frames_are_a_function_of_seed_and_index() {
    let rig = deep360_rig();
    let a = objects(5, 128, false).render_frame(&rig, 2);
    let b = objects(5, 128, false).render_frame(&rig, 2);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    let single = pool.install(|| objects(5, 128, false).render_frame(&rig, 2));
    for other in [&b, &single] {
        assert_eq!(differing_bytes(&a.images, &other.images), 0);
        assert_eq!(a.ground_truth, other.ground_truth);
    }
    let total: usize = a.images.iter().map(|i| i.as_raw().len()).sum();
    for (seed, index) in [(6u64, 2usize), (5, 3)] {
        let c = objects(seed, 128, false).render_frame(&rig, index);
        let d = differing_bytes(&a.images, &c.images);
        assert!(
            d * 2 > total,
            "({seed}, {index}): only {d} of {total} bytes differ"
        );
        let gt_a = a.ground_truth.as_ref().expect("gt");
        let gt_c = c.ground_truth.as_ref().expect("gt");
        let gt_diff = gt_a.data.iter().zip(&gt_c.data).filter(|(p, q)| p != q);
        assert!(gt_diff.count() * 2 > gt_a.data.len());
    }
}

#[test]
fn objects_ground_truth_spans_near_and_far_and_respects_the_keep_out() {
    let rig = deep360_rig();
    let random_rig = mode360::train::rack::random_rig(17).expect("random rig");
    let (mut near, mut far, mut sky, mut total) = (0usize, 0usize, 0usize, 0usize);
    let mut min_range = f32::INFINITY;
    let mut frames_with_near = 0;
    for seed in [1u64, 2, 3] {
        let r = objects(seed, 128, false);
        for index in 0..4 {
            for rig in [&rig, &random_rig] {
                let gt = r.render_frame(rig, index).ground_truth.expect("gt");
                let n = gt.data.iter().filter(|&&d| d < 3.0).count();
                frames_with_near += usize::from(n > 0);
                near += n;
                far += gt.data.iter().filter(|&&d| d > 50.0).count();
                sky += gt.data.iter().filter(|&&d| d >= MAX_DEPTH_M).count();
                total += gt.data.len();
                min_range = gt.data.iter().copied().fold(min_range, f32::min);
                assert!(gt.data.iter().all(|d| d.is_finite() && *d <= MAX_DEPTH_M));
            }
        }
    }
    let frac = |n: usize| n as f64 / total as f64;
    println!(
        "objects GT: {:.1} % below 3 m, {:.1} % beyond 50 m, {:.1} % background, min {min_range:.3} m",
        100.0 * frac(near),
        100.0 * frac(far),
        100.0 * frac(sky)
    );
    assert!(frac(near) > 0.03, "too little near range");
    assert!(frac(far) > 0.05, "too little far range");
    assert!(frac(sky) < 0.5, "background covers {:.2}", frac(sky));
    assert!(
        frames_with_near >= 18,
        "{frames_with_near} of 24 frames have range < 3 m"
    );
    assert!(
        min_range >= KEEP_OUT_M as f32,
        "a surface at {min_range} m from the reference camera"
    );
    // Every camera, not only the reference: its own range image keeps the distance too.
    let r = objects(4, 128, false);
    for index in 0..3 {
        let frame = r.render_frame(&rig, index);
        for (c, cam) in rig.cameras.iter().enumerate() {
            let view = r.render_camera(index, &(r.world_from_rig(index) * cam.rig_from_cam));
            let min = view
                .range_m
                .data
                .iter()
                .copied()
                .fold(f32::INFINITY, f32::min);
            assert!(min >= KEEP_OUT_M as f32, "camera {c}: {min} m");
            // The single view sees the same scene as the rig frame.
            assert_eq!(view.image.as_raw(), frame.images[c].as_raw());
        }
    }
}

/// Brute-force closest hit over the scene's primitives and ground plane (no BVH, no renderer).
fn brute_force_range(seed: u64, index: usize, rig: &Rig, o: Vector3<f64>, d: Vector3<f64>) -> f64 {
    let mut centres: Vec<Vector3<f64>> = rig
        .cameras
        .iter()
        .map(|c| c.rig_from_cam.translation.vector)
        .collect();
    centres.push(rig.rig_from_output.translation.vector);
    let scene = objects_scene(seed, index, &keep_out_box(&centres));
    let ray = Ray::new(o, d);
    let mut t = f64::INFINITY;
    for p in &scene.prims {
        if let Some(h) = p.shape.intersect(&ray, t) {
            t = h.t;
        }
    }
    if let Some((z, _)) = scene.ground {
        if d.z < 0.0 {
            t = t.min((z - o.z) / d.z);
        }
    }
    t.min(f64::from(MAX_DEPTH_M))
}

#[test]
fn objects_ground_truth_matches_a_brute_force_ray_cast() {
    let rig = deep360_rig();
    let width = 96;
    let grid = ErpGrid::new(width).expect("grid");
    let mut checked = 0;
    for (seed, index) in [(7u64, 0usize), (8, 5)] {
        let r = objects(seed, width, false);
        let gt = r.render_frame(&rig, index).ground_truth.expect("gt");
        let world_from_out = r.world_from_rig(index) * rig.rig_from_output;
        for v in (0..grid.height()).step_by(3) {
            for u in (0..grid.width()).step_by(5) {
                let p = PixelCoord {
                    u: u as f64,
                    v: v as f64,
                };
                let d = world_from_out.rotation * grid.dir_from_pixel(p);
                let expected =
                    brute_force_range(seed, index, &rig, world_from_out.translation.vector, d);
                let got = f64::from(gt.get(u, v));
                assert!(
                    (got - expected).abs() <= 1e-5 * expected.max(1.0),
                    "seed {seed} frame {index} pixel ({u},{v}): {got} vs {expected}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 500);
}

#[test]
fn soiling_changes_objects_images_but_not_ground_truth() {
    let rig = deep360_rig();
    for index in [0usize, 1] {
        let clean = objects(9, 128, false).render_frame(&rig, index);
        let (soiled, report) = objects(9, 128, true).render_frame_with_report(&rig, index);
        assert_eq!(clean.ground_truth, soiled.ground_truth);
        let mut soiled_cams = 0;
        for (c, s) in report.soiling.iter().enumerate() {
            let d = differing_bytes(
                std::slice::from_ref(&clean.images[c]),
                std::slice::from_ref(&soiled.images[c]),
            );
            if s.coverage > 0.0 {
                soiled_cams += 1;
                assert!(d > 0, "camera {c} soiled but unchanged");
            } else {
                assert_eq!(d, 0, "camera {c} clean but changed");
            }
        }
        assert!((1..=2).contains(&soiled_cams));
    }
}

#[test]
fn varied_streets_differ_per_seed_and_regular_streets_do_not() {
    let layouts: Vec<StreetLayout> = (0..24)
        .map(|s| WorldParams::with_style(s, StreetStyle::Varied).layout)
        .collect();
    let spread = |f: fn(&StreetLayout) -> f64| {
        let v: Vec<f64> = layouts.iter().map(f).collect();
        v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - v.iter().copied().fold(f64::INFINITY, f64::min)
    };
    assert!(spread(|l| l.lane_width_m) > 0.8);
    assert!(spread(|l| l.road_half_width_m) > 2.0);
    assert!(spread(|l| l.building_front_m) > 5.0);
    assert!(spread(|l| l.building_height_scale) > 0.8);
    assert!(spread(|l| l.rig_height_offset_m) > 0.5);
    assert!(layouts.iter().any(|l| l.parked_car_probability == 0.0));
    assert!(layouts.iter().any(|l| l.parked_car_probability > 0.4));
    for seed in 0..24 {
        assert_eq!(WorldParams::new(seed).layout, StreetLayout::regular());
        assert_eq!(
            WorldParams::with_style(seed, StreetStyle::Varied).layout,
            layouts[seed as usize]
        );
    }
    let regular = SynthRenderer::new(SynthConfig::default()).expect("config");
    let pose = regular.world_from_rig(10);
    assert_eq!(pose.translation.vector, Vector3::new(8.0, -2.0, 0.0));
    assert_eq!(pose.rotation, nalgebra::UnitQuaternion::identity());
}

#[test]
fn varied_street_ground_truth_is_exact_below_the_rig_and_clear_of_the_cameras() {
    let rig = deep360_rig();
    let width = 128;
    let grid = ErpGrid::new(width).expect("grid");
    let mut below = Vec::new();
    for seed in [2u64, 3, 4, 5] {
        let r = varied(seed, width);
        let l = &r.world_params().layout;
        for index in [0usize, 25] {
            let gt = r.render_frame(&rig, index).ground_truth.expect("gt");
            let min = gt.data.iter().copied().fold(f32::INFINITY, f32::min);
            assert!(min > 1.0, "seed {seed} frame {index}: {min} m");
            let world_from_out = r.world_from_rig(index) * rig.rig_from_output;
            let o = world_from_out.translation.vector;
            assert!((o.z - (1.8 + l.rig_height_offset_m)).abs() < 0.1);
            // The bottom rows look at the road just under the rig: range to z = 0.
            for v in grid.height() - 3..grid.height() {
                for u in 0..grid.width() {
                    let p = PixelCoord {
                        u: u as f64,
                        v: v as f64,
                    };
                    let d = world_from_out.rotation * grid.dir_from_pixel(p);
                    let expected = -o.z / d.z;
                    let got = f64::from(gt.get(u, v));
                    assert!(
                        ((got - expected) / expected).abs() < 1e-4,
                        "seed {seed} ({u},{v}): {got} vs {expected}"
                    );
                }
            }
            below.push(gt.get(0, grid.height() - 1));
        }
    }
    // Different seeds put the rig at different heights.
    let spread = below.iter().copied().fold(f32::NEG_INFINITY, f32::max)
        - below.iter().copied().fold(f32::INFINITY, f32::min);
    assert!(
        spread > 0.1,
        "range below the rig varies by only {spread} m"
    );
}

/// FNV-1a over every image byte and every ground-truth float (little endian).
fn frame_checksum(frame: &mode360::frame::RigFrame) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |b: u8| {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    };
    for img in &frame.images {
        img.as_raw().iter().for_each(|&b| eat(b));
    }
    if let Some(gt) = &frame.ground_truth {
        gt.data
            .iter()
            .for_each(|d| d.to_le_bytes().into_iter().for_each(&mut eat));
    }
    h
}

#[test]
fn regular_streets_render_exactly_as_before_scene_kinds() {
    // Checksums of frames rendered by the commit before scene kinds and street styles existed
    // (x86-64 Linux); the default configuration must keep reproducing them byte for byte.
    let rig = deep360_rig();
    for (seed, soiled, index, expected) in [
        (1u64, false, 0usize, 0x2f2e_0bdd_4390_fd12u64),
        (3, true, 7, 0xa205_3e58_cd88_c78e),
        (11, false, 40, 0x1c6e_46cd_359f_4a58),
    ] {
        let r = SynthRenderer::new(SynthConfig {
            seed,
            width: 128,
            soiled,
            ..SynthConfig::default()
        })
        .expect("config");
        let got = frame_checksum(&r.render_frame(&rig, index));
        assert_eq!(got, expected, "seed {seed} frame {index}: {got:016x}");
    }
}
