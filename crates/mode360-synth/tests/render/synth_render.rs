//! Synthetic street renderer: determinism, analytic ground truth, multi-view consistency,
//! soiling coverage, and a quick speed measurement.

use crate::common::deep360_rig;
use mode360_core::geometry::{ErpGrid, PixelCoord, Rig};
use mode360_synth::{SynthConfig, SynthRenderer};

fn renderer(seed: u64, width: usize, soiled: bool) -> SynthRenderer {
    SynthRenderer::new(SynthConfig {
        seed,
        width,
        soiled,
        ..SynthConfig::default()
    })
    .expect("valid config")
}

/// The Deep360 rig with `cam` as reference (and so output) camera.
fn rig_with_reference(cam: &str) -> Rig {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    );
    let text = std::fs::read_to_string(path).expect("rig yaml");
    let text = text.replace(
        "reference_camera: cam1",
        &format!("reference_camera: {cam}"),
    );
    Rig::from_yaml_str(&text, "rig with other reference").expect("rig")
}

#[test]
fn same_seed_same_bytes_other_seed_differs() {
    let rig = deep360_rig();
    let a = renderer(3, 128, true).render_frame(&rig, 7);
    let b = renderer(3, 128, true).render_frame(&rig, 7);
    let c = renderer(4, 128, true).render_frame(&rig, 7);
    // The same bytes on a single thread.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    let single = pool.install(|| renderer(3, 128, true).render_frame(&rig, 7));
    for (x, y) in a.images.iter().zip(&single.images) {
        assert_eq!(x.as_raw(), y.as_raw());
    }
    assert_eq!(a.ground_truth, single.ground_truth);
    assert_eq!(a.stamp_ns, b.stamp_ns);
    for (x, y) in a.images.iter().zip(&b.images) {
        assert_eq!(x.as_raw(), y.as_raw());
    }
    assert_eq!(a.ground_truth, b.ground_truth);
    let differing = a
        .images
        .iter()
        .zip(&c.images)
        .map(|(x, y)| {
            x.as_raw()
                .iter()
                .zip(y.as_raw())
                .filter(|(p, q)| p != q)
                .count()
        })
        .sum::<usize>();
    let total: usize = a.images.iter().map(|i| i.as_raw().len()).sum();
    assert!(
        differing * 2 > total,
        "only {differing} of {total} bytes differ between seeds"
    );
    // Stamps advance by the frame period.
    let r = renderer(3, 64, false);
    assert_eq!(r.frame_stamp_ns(10) - r.frame_stamp_ns(0), 1_000_000_000);
}

#[test]
fn ground_truth_matches_road_plane_and_sky() {
    let rig = deep360_rig();
    let r = renderer(11, 256, false);
    let grid = ErpGrid::new(256).expect("grid");
    for index in [0usize, 40] {
        let frame = r.render_frame(&rig, index);
        let gt = frame.ground_truth.expect("ground truth");
        let world_from_out = r.world_from_rig(index) * rig.rig_from_output;
        let o = world_from_out.translation.vector;
        let (mut road_checked, mut sky_checked) = (0, 0);
        for v in 0..grid.height() {
            for u in 0..grid.width() {
                let p = PixelCoord {
                    u: u as f64,
                    v: v as f64,
                };
                let d = world_from_out.rotation * grid.dir_from_pixel(p);
                let lat = grid.lonlat_from_pixel(p).lat_rad;
                let got = gt.get(u, v) as f64;
                if d.z < -0.2 {
                    // Where the ray meets z = 0 inside the ego lane, nothing can be in between.
                    let expected = o.z / (-lat).sin();
                    let hit = o + d * expected;
                    if hit.y > -3.8 && hit.y < -0.2 && (hit.x - o.x).abs() < 12.0 {
                        assert!(
                            ((got - expected) / expected).abs() < 1e-3,
                            "frame {index} pixel ({u},{v}): {got} vs road plane {expected}"
                        );
                        road_checked += 1;
                    }
                }
                if lat > 80f64.to_radians() {
                    assert_eq!(got, 1000.0, "sky pixel ({u},{v})");
                    sky_checked += 1;
                }
                assert!(got > 0.0 && got <= 1000.0);
            }
        }
        assert!(road_checked > 1000, "road pixels checked: {road_checked}");
        assert!(sky_checked > 1000, "sky pixels checked: {sky_checked}");
    }
}

/// Bilinear colour sample with longitude wrap.
fn sample_rgb(img: &image::RgbImage, grid: &ErpGrid, p: PixelCoord) -> [f32; 3] {
    let taps = grid.bilinear_taps(p);
    let raw = img.as_raw();
    let mut out = [0.0f32; 3];
    for (idx, w) in taps.index.iter().zip(taps.weight) {
        for (c, o) in out.iter_mut().enumerate() {
            *o += raw[*idx as usize * 3 + c] as f32 * w;
        }
    }
    out
}

#[test]
fn colours_agree_across_views() {
    let width = 512;
    let rig1 = deep360_rig();
    let r = renderer(5, width, false);
    let grid = ErpGrid::new(width).expect("grid");
    let index = 12;
    let f1 = r.render_frame(&rig1, index);
    let gt1 = f1.ground_truth.clone().expect("gt");
    for (cam_index, cam_name) in [(1usize, "cam2"), (2, "cam3"), (3, "cam4")] {
        // Ground truth of the other camera, for the occlusion test.
        let rig_other = rig_with_reference(cam_name);
        let f_other = r.render_frame(&rig_other, index);
        let gt_other = f_other.ground_truth.expect("gt");
        assert_eq!(
            f_other.images[cam_index].as_raw(),
            f1.images[cam_index].as_raw()
        );
        let out_from_rig = rig1.rig_from_output.inverse();
        let other_from_rig = rig1.cameras[cam_index].rig_from_cam.inverse();
        let mut diffs = Vec::new();
        for v in (0..grid.height()).step_by(2) {
            for u in (0..grid.width()).step_by(2) {
                let p = PixelCoord {
                    u: u as f64,
                    v: v as f64,
                };
                let range = gt1.get(u, v) as f64;
                if range >= 100.0 {
                    continue;
                }
                let point_out = grid.dir_from_pixel(p) * range;
                let point_rig = out_from_rig.inverse() * nalgebra::Point3::from(point_out);
                let point_other = other_from_rig * point_rig;
                let q = grid.pixel_from_dir(&point_other.coords);
                let visible = gt_other.get(
                    (q.u.round() as i64).rem_euclid(width as i64) as usize,
                    (q.v.round().clamp(0.0, (grid.height() - 1) as f64)) as usize,
                ) as f64;
                let dist = point_other.coords.norm();
                if (visible - dist).abs() > 0.01 * dist {
                    continue; // occluded in the other view
                }
                let a = f1.images[0].get_pixel(u as u32, v as u32).0;
                let b = sample_rgb(&f1.images[cam_index], &grid, q);
                let diff = (0..3).map(|c| (a[c] as f32 - b[c]).abs()).sum::<f32>() / 3.0;
                diffs.push(diff);
            }
        }
        diffs.sort_by(f32::total_cmp);
        let n = diffs.len();
        assert!(n > 5000, "{cam_name}: only {n} co-visible pixels");
        let median = diffs[n / 2];
        let p80 = diffs[n * 4 / 5];
        println!("{cam_name}: {n} co-visible pixels, median |diff| {median:.2}, p80 {p80:.2}");
        assert!(
            median < 6.0,
            "{cam_name}: median colour difference {median}"
        );
        assert!(
            p80 < 16.0,
            "{cam_name}: 80th percentile colour difference {p80}"
        );
    }
}

#[test]
fn soiling_covers_5_to_20_percent_of_chosen_cameras_only() {
    let rig = deep360_rig();
    let clean = renderer(21, 256, false);
    let soiled = renderer(21, 256, true);
    let mut soiled_cams = 0;
    for index in 0..6 {
        let (fc, rc) = clean.render_frame_with_report(&rig, index);
        let (fs, rs) = soiled.render_frame_with_report(&rig, index);
        assert_eq!(
            fc.ground_truth, fs.ground_truth,
            "soiling must not touch ground truth"
        );
        assert!(rc.soiling.iter().all(|s| s.coverage == 0.0));
        let mut n = 0;
        for (c, s) in rs.soiling.iter().enumerate() {
            let changed = fc.images[c]
                .as_raw()
                .chunks(3)
                .zip(fs.images[c].as_raw().chunks(3))
                .filter(|(a, b)| a != b)
                .count() as f64
                / (256.0 * 128.0);
            if s.coverage > 0.0 {
                n += 1;
                assert!(
                    (0.05..=0.20).contains(&s.coverage),
                    "coverage {}",
                    s.coverage
                );
                assert!(
                    changed >= 0.8 * s.coverage,
                    "changed {changed} vs {}",
                    s.coverage
                );
            } else {
                assert_eq!(
                    changed, 0.0,
                    "clean camera {c} of frame {index} was modified"
                );
            }
        }
        assert!((1..=2).contains(&n), "frame {index}: {n} soiled cameras");
        soiled_cams += n;
    }
    assert!(soiled_cams >= 6);
}

#[test]
fn renders_finite_ground_truth_everywhere_and_saves_previews() {
    // Speed is measured by `cargo bench --bench render`, not here.
    let rig = deep360_rig();
    let r = renderer(1, 512, false);
    let frames = 5;
    let mut finite = 0usize;
    for i in 0..frames {
        let f = r.render_frame(&rig, 10 * i);
        finite += f
            .ground_truth
            .map_or(0, |g| g.data.iter().filter(|d| d.is_finite()).count());
    }
    assert_eq!(finite, frames * 512 * 256);
    if std::env::var_os("SYNTH_PREVIEW").is_some() {
        let width: usize = std::env::var("SYNTH_PREVIEW_WIDTH")
            .ok()
            .and_then(|w| w.parse().ok())
            .unwrap_or(512);
        let soiled = renderer(1, width, true);
        // Also a frame 6 m before the first intersection ahead.
        let params = mode360_synth::world::WorldParams::new(1);
        let tile = (1..1000i64)
            .find(|&t| mode360_synth::world::is_intersection(&params, t))
            .unwrap_or(1);
        let x = mode360_synth::world::cross_street_centre_m(tile) - 6.0;
        let crossing = (x / (8.0 * 0.1)).round() as usize;
        for i in [0usize, 30, crossing] {
            let f = soiled.render_frame(&rig, i);
            for (c, img) in f.images.iter().enumerate() {
                let _ = img.save(format!("/tmp/synth_f{i}_cam{}.png", c + 1));
            }
            if let Some(gt) = f.ground_truth {
                let px: Vec<u8> = gt
                    .data
                    .iter()
                    .map(|d| (255.0 * (1.0 - (d.ln() / 1000f32.ln()).clamp(0.0, 1.0))) as u8)
                    .collect();
                if let Some(img) = image::GrayImage::from_raw(width as u32, width as u32 / 2, px) {
                    let _ = img.save(format!("/tmp/synth_f{i}_gt.png"));
                }
            }
        }
    }
}

#[test]
fn ground_truth_of_an_output_frame_between_the_cameras() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    );
    let text = std::fs::read_to_string(path).expect("rig yaml");
    let output_height_m = 1.5;
    let text = format!(
        "{text}\noutput:\n  frame_id: rig_centre\n  rig_from_output: {{translation: [0.0, 0.0, {output_height_m}], rotation_rpy: [0.0, 0.0, 0.3]}}\n"
    );
    let rig = Rig::from_yaml_str(&text, "centre output").expect("rig");
    let r = renderer(2, 128, false);
    let grid = ErpGrid::new(128).expect("grid");
    let gt = r.render_frame(&rig, 3).ground_truth.expect("gt");
    let world_from_out = r.world_from_rig(3) * rig.rig_from_output;
    let mut checked = 0;
    for v in 0..grid.height() {
        for u in 0..grid.width() {
            let p = PixelCoord {
                u: u as f64,
                v: v as f64,
            };
            let d = world_from_out.rotation * grid.dir_from_pixel(p);
            if d.z < -0.3 {
                let expected = output_height_m / -d.z;
                let hit = world_from_out.translation.vector + d * expected;
                if hit.y > -3.8 && hit.y < -0.2 {
                    let got = gt.get(u, v) as f64;
                    assert!(
                        ((got - expected) / expected).abs() < 1e-3,
                        "{got} vs {expected}"
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 100, "checked {checked}");
}

#[test]
fn objects_keep_clear_of_the_cameras_and_traffic_moves() {
    use mode360_synth::world::{scene_prims, WorldParams};
    let rig = deep360_rig();
    let r = renderer(9, 64, false);
    let params = WorldParams::new(9);
    let mut min_dist = f64::INFINITY;
    for index in (0..400).step_by(9) {
        let world_from_rig = r.world_from_rig(index);
        let t = r.frame_time_s(index);
        let prims = scene_prims(&params, world_from_rig.translation.x, 40.0, t);
        for cam in &rig.cameras {
            let c = (world_from_rig * cam.rig_from_cam).translation.vector;
            for p in &prims {
                let b = p.shape.aabb();
                let q = c.sup(&b.min).inf(&b.max);
                min_dist = min_dist.min((q - c).norm());
            }
        }
    }
    println!("closest object to any camera: {min_dist:.2} m");
    assert!(
        min_dist > 2.9,
        "an object came within {min_dist} m of a camera"
    );
    // Moving objects: the same stretch of road at two times holds primitives at different places.
    let a = scene_prims(&params, 0.0, 60.0, 0.0);
    let b = scene_prims(&params, 0.0, 60.0, 1.0);
    let moved = a
        .iter()
        .zip(&b)
        .filter(|(p, q)| p.shape.aabb() != q.shape.aabb())
        .count();
    assert!(moved > 10, "only {moved} primitives moved in one second");
}

/// Fraction of pixels of `img`, box-downsampled by `factor`, whose 3x3 luminance standard
/// deviation exceeds `min_std` grey levels (columns wrap, rows clamp).
fn textured_fraction(
    img: &image::RgbImage,
    factor: usize,
    min_std: f32,
    rows: std::ops::Range<f64>,
) -> f64 {
    let (w, h) = (
        img.width() as usize / factor,
        img.height() as usize / factor,
    );
    let mut lum = vec![0f32; w * h];
    for (i, p) in img.pixels().enumerate() {
        let (x, y) = (
            i % img.width() as usize / factor,
            i / img.width() as usize / factor,
        );
        if x < w && y < h {
            let l = 0.299 * p.0[0] as f32 + 0.587 * p.0[1] as f32 + 0.114 * p.0[2] as f32;
            lum[y * w + x] += l / (factor * factor) as f32;
        }
    }
    let (y0, y1) = (
        (rows.start * h as f64) as usize,
        (rows.end * h as f64) as usize,
    );
    let mut textured = 0usize;
    for y in y0..y1 {
        for x in 0..w {
            let mut vals = [0f32; 9];
            let mut k = 0;
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
                    let xx = (x as i64 + dx).rem_euclid(w as i64) as usize;
                    vals[k] = lum[yy * w + xx];
                    k += 1;
                }
            }
            let mean = vals.iter().sum::<f32>() / 9.0;
            let var = vals.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / 9.0;
            if var.sqrt() > min_std {
                textured += 1;
            }
        }
    }
    textured as f64 / ((y1 - y0) * w) as f64
}

#[test]
fn textures_are_rich_at_matching_resolution() {
    let rig = deep360_rig();
    let r = renderer(8, 512, false);
    let f = r.render_frame(&rig, 25);
    for (name, rows) in [("sky", 0.0..0.4), ("street", 0.4..0.6), ("road", 0.6..1.0)] {
        let full = textured_fraction(&f.images[0], 1, 1.0, rows.clone());
        let quarter = textured_fraction(&f.images[0], 4, 1.0, rows);
        println!("{name}: textured fraction {full:.3} at 512x256, {quarter:.3} at 128x64");
        assert!(full > 0.5 && quarter > 0.9, "{name}: {full} / {quarter}");
    }
}

#[test]
fn single_camera_view_matches_the_rig_frame() {
    let rig = deep360_rig();
    let r = renderer(6, 128, false);
    let frame = r.render_frame(&rig, 17);
    for (c, cam) in rig.cameras.iter().enumerate() {
        let view = r.render_camera(17, &(r.world_from_rig(17) * cam.rig_from_cam));
        assert_eq!(view.image.as_raw(), frame.images[c].as_raw(), "camera {c}");
        if c == rig.reference {
            assert_eq!(Some(&view.range_m), frame.ground_truth.as_ref());
        }
    }
}
