//! Geometry against independent ground truth: GEER's epipolar property, angular disparity to
//! range, and sweep sampling tables.

use mode360_core::geometry::erp::PixelCoord;
use mode360_core::geometry::{
    DepthHypotheses, DepthRange, ErpGrid, GeerPair, Rig, SweepGeometry, SweepTable,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::PI;

/// A small deterministic generator so the tests need no extra crates.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

fn pose(t: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

/// Camera pairs: horizontal, vertical, diagonal, each with rotated cameras.
fn pairs() -> Vec<(&'static str, Isometry3<f64>, Isometry3<f64>)> {
    vec![
        (
            "horizontal",
            pose([0.5, 0.5, 1.8], [0.0; 3]),
            pose([0.5, -0.5, 1.8], [0.0; 3]),
        ),
        (
            "horizontal rotated",
            pose([0.0, 0.0, 1.0], [0.1, -0.2, 1.3]),
            pose([-1.2, 0.3, 1.0], [-0.3, 0.05, -2.0]),
        ),
        (
            "vertical",
            pose([0.0, 0.0, 2.0], [0.0; 3]),
            pose([0.0, 0.0, 1.0], [0.0, 0.0, 0.7]),
        ),
        (
            "diagonal rotated",
            pose([0.3, -0.4, 1.5], [0.2, 0.4, -0.9]),
            pose([-0.5, 0.6, 0.7], [1.0, -0.3, 2.5]),
        ),
    ]
}

/// Independent ERP projection: lon/lat of the camera-frame direction, then the pixel formula.
fn erp_pixel(grid: ErpGrid, rig_from_cam: &Isometry3<f64>, p_rig: &Vector3<f64>) -> PixelCoord {
    let d = rig_from_cam
        .inverse_transform_point(&Point3::from(*p_rig))
        .coords;
    let lon = d.y.atan2(d.x);
    let lat = (d.z / d.norm()).asin();
    let (w, h) = (grid.width() as f64, grid.height() as f64);
    PixelCoord {
        u: (1.0 - lon / PI) * w / 2.0 - 0.5,
        v: (PI / 2.0 - lat) * h / PI - 0.5,
    }
}

/// GEER row (and column) of a point as imaged by one camera: from that camera's ERP pixel,
/// back to a camera ray, into rig axes, into GEER angles.
fn geer_pixel_via_erp(
    pair: &GeerPair,
    grid: ErpGrid,
    rig_from_cam: &Isometry3<f64>,
    p_rig: &Vector3<f64>,
) -> PixelCoord {
    let px = erp_pixel(grid, rig_from_cam, p_rig);
    let dir_cam = grid.dir_from_pixel(px);
    let dir_rig = rig_from_cam.rotation * dir_cam;
    pair.pixel_from_angles(pair.angles_from_dir_rig(&dir_rig))
}

#[test]
fn geer_epipolar_lines_are_rows_for_any_pair() {
    let grid = ErpGrid::new(1024).unwrap();
    let mut rng = Lcg(7);
    for (name, rig_from_l, rig_from_r) in pairs() {
        let pair = GeerPair::new(
            rig_from_l.translation.vector,
            rig_from_r.translation.vector,
            Vector3::z(),
            512,
        )
        .unwrap();
        for _ in 0..500 {
            let p = Vector3::new(
                rng.range(-30.0, 30.0),
                rng.range(-30.0, 30.0),
                rng.range(-3.0, 12.0),
            );
            let l = geer_pixel_via_erp(&pair, grid, &rig_from_l, &p);
            let r = geer_pixel_via_erp(&pair, grid, &rig_from_r, &p);
            // Rows wrap at theta = +-pi; compare modulo the image height.
            let h = pair.height() as f64;
            let dv = (l.v - r.v).rem_euclid(h);
            let dv = dv.min(h - dv);
            assert!(dv < 1e-6, "{name}: point {p:?} on rows {} and {}", l.v, r.v);
            // The left camera, nearer along the baseline direction, has the larger phi.
            assert!(l.u >= r.u - 1e-9, "{name}: disparity must be non-negative");
        }
    }
}

#[test]
fn angular_disparity_gives_range() {
    let grid = ErpGrid::new(2048).unwrap();
    let mut rng = Lcg(11);
    for (name, rig_from_l, rig_from_r) in pairs() {
        let pair = GeerPair::new(
            rig_from_l.translation.vector,
            rig_from_r.translation.vector,
            Vector3::z(),
            1024,
        )
        .unwrap();
        for _ in 0..300 {
            let p = Vector3::new(
                rng.range(-40.0, 40.0),
                rng.range(-40.0, 40.0),
                rng.range(-2.0, 10.0),
            );
            let l = pair.angles_from_pixel(geer_pixel_via_erp(&pair, grid, &rig_from_l, &p));
            let r = pair.angles_from_pixel(geer_pixel_via_erp(&pair, grid, &rig_from_r, &p));
            let truth = (p - rig_from_l.translation.vector).norm();
            let rho = pair.range_from_disparity(r.phi_rad, l.phi_rad - r.phi_rad);
            let rho = rho.unwrap_or(f64::INFINITY);
            assert!(
                (rho - truth).abs() <= 1e-6 * truth.max(1.0) * truth,
                "{name}: range {rho} vs truth {truth}"
            );
        }
    }
}

fn test_rig() -> Rig {
    Rig::from_yaml_str(
        r#"
reference_camera: c1
output:
  frame_id: out
  rig_from_output: {translation: [0.1, 0.2, 1.7], rotation_rpy: [0.0, 0.0, 0.3]}
cameras:
  - {name: c1, topic: /c1, frame_id: c1, rig_from_cam: {translation: [0.5, 0.5, 1.8], rotation_rpy: [0, 0, 0]}}
  - {name: c2, topic: /c2, frame_id: c2, rig_from_cam: {translation: [0.5, -0.5, 1.8], rotation_rpy: [0.2, 0, 1.0]}}
  - {name: c3, topic: /c3, frame_id: c3, rig_from_cam: {translation: [-0.5, 0.5, 1.9], rotation_rpy: [0, -0.3, 3.0]}}
"#,
        "test_rig",
    )
    .unwrap()
}

/// Known 3D points on sphere i along output pixel k must land where each camera sees them,
/// including spheres nearer than the 1 m baseline.
#[test]
fn sweep_tables_put_known_points_on_the_right_pixels() {
    let rig = test_rig();
    let out = ErpGrid::new(32).unwrap();
    let cam_grids = vec![
        ErpGrid::new(64).unwrap(),
        ErpGrid::new(48).unwrap(),
        ErpGrid::new(64).unwrap(),
    ];
    let hyps = DepthHypotheses::new(DepthRange::new(0.3, 100.0).unwrap(), 12).unwrap();
    let table = SweepTable::build(SweepGeometry::new(&rig, out, cam_grids.clone(), hyps).unwrap());
    let mut near_checked = 0;
    for sphere in 0..hyps.count() {
        let rho = hyps.depth_m(sphere as f64);
        if rho < 1.0 {
            near_checked += 1;
        }
        for k in 0..out.len() {
            // Independent construction of the 3D point, in rig coordinates.
            let (u, v) = ((k % out.width()) as f64, (k / out.width()) as f64);
            let lon = PI * (1.0 - 2.0 * (u + 0.5) / out.width() as f64);
            let lat = PI / 2.0 - PI * (v + 0.5) / out.height() as f64;
            let dir_out = Vector3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
            let p_rig = (rig.rig_from_output * Point3::from(dir_out * rho)).coords;
            for (cam, grid) in cam_grids.iter().enumerate() {
                let expect = erp_pixel(*grid, &rig.cameras[cam].rig_from_cam, &p_rig);
                let [su, sv] = table.coords(cam, sphere)[k];
                let w = grid.width() as f64;
                let du = (su as f64 - expect.u).rem_euclid(w);
                let du = du.min(w - du);
                assert!(du < 1e-3 && (sv as f64 - expect.v).abs() < 1e-3,
                    "cam {cam} sphere {sphere} (rho {rho:.3} m) pixel {k}: table ({su}, {sv}) vs ({}, {})", expect.u, expect.v);
            }
        }
    }
    assert!(
        near_checked >= 2,
        "the test must cover spheres nearer than the baseline"
    );
}

/// A bright dot painted where a camera sees a point is what the table's taps read back for
/// that point's pixel and sphere, and not for the neighbouring spheres.
#[test]
fn sweep_taps_read_back_a_painted_point() {
    let rig = test_rig();
    let out = ErpGrid::new(64).unwrap();
    let grid = ErpGrid::new(128).unwrap();
    let hyps = DepthHypotheses::new(DepthRange::new(0.4, 50.0).unwrap(), 16).unwrap();
    let geom = SweepGeometry::new(&rig, out, vec![grid; 3], hyps).unwrap();
    let table = SweepTable::build(geom);
    let k = 20 * out.width() + 5; // a pixel below the horizon
    for sphere in [1usize, 8, 15] {
        let p_out =
            out.dir_from_pixel(PixelCoord { u: 5.0, v: 20.0 }) * hyps.depth_m(sphere as f64);
        let p_rig = (rig.rig_from_output * Point3::from(p_out)).coords;
        let cam = 1;
        let px = erp_pixel(grid, &rig.cameras[cam].rig_from_cam, &p_rig);
        let mut img = vec![0.0f32; grid.len()];
        let (pu, pv) = (
            px.u.round().rem_euclid(grid.width() as f64) as usize,
            px.v.round() as usize,
        );
        img[pv * grid.width() + pu] = 1.0;
        let hit = table.taps(cam, sphere, k).sample(&img);
        assert!(hit > 0.2, "sphere {sphere}: dot read back as {hit}");
        for other in [sphere.saturating_sub(1), (sphere + 1).min(15)] {
            if other != sphere {
                let miss = table.taps(cam, other, k).sample(&img);
                assert!(
                    miss < hit,
                    "sphere {other} should not see sphere {sphere}'s dot"
                );
            }
        }
    }
}

#[test]
fn hypotheses_are_uniform_in_inverse_depth() {
    let h = DepthHypotheses::new(DepthRange::paper(), 192).unwrap();
    assert!((h.depth_m(0.0) - 1000.0).abs() < 1e-9);
    assert!((h.depth_m(191.0) - 0.5).abs() < 1e-9);
    let d = h.depths_m();
    let steps: Vec<f64> = d.windows(2).map(|w| 1.0 / w[1] - 1.0 / w[0]).collect();
    for s in &steps {
        assert!((s - steps[0]).abs() < 1e-12);
    }
    assert!((h.index_of_depth(h.depth_m(57.3)) - 57.3).abs() < 1e-9);
    assert!(DepthHypotheses::new(DepthRange::paper(), 1).is_err());
    assert!(DepthRange::new(2.0, 1.0).is_err());
}

#[test]
fn deep360_rig_file_is_the_papers_layout() {
    let rig = Rig::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    ))
    .unwrap();
    assert_eq!(rig.cameras.len(), 4);
    assert_eq!(rig.reference, 0);
    let o: Vec<Vector3<f64>> = (0..4).map(|i| rig.camera_origin(i)).collect();
    // A horizontal 1 m square.
    assert!(((o[0] - o[1]).norm() - 1.0).abs() < 1e-12);
    assert!(((o[0] - o[2]).norm() - 1.0).abs() < 1e-12);
    assert!(((o[0] - o[3]).norm() - 2f64.sqrt()).abs() < 1e-12);
    assert!(o.iter().all(|p| (p.z - o[0].z).abs() < 1e-12));
    assert!(rig
        .cameras
        .iter()
        .all(|c| c.rig_from_cam.rotation.angle() < 1e-12));
    assert_eq!(rig.output_frame_id, rig.cameras[0].frame_id);
}
