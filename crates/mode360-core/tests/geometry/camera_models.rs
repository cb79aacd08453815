//! Camera models against their published formulas: hand-computed projections, round trips
//! over random directions, and `None` (never a wrapped pixel) outside the field of view, off
//! the image and outside the unprojection region.

use mode360_core::geometry::camera::{
    CameraModel, DoubleSphere, DualFisheye, DualLens, Eucm, FisheyeCamera, FisheyeLens, Focal,
    ImageSize, KannalaBrandt,
};
use mode360_core::geometry::erp::PixelCoord;
use mode360_core::geometry::ErpGrid;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Deterministic generator (no extra crates).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform on the unit sphere, scaled by a random length in [0.1, 50).
    fn point(&mut self) -> Vector3<f64> {
        let z = 2.0 * self.next() - 1.0;
        let phi = 2.0 * std::f64::consts::PI * self.next();
        let r = (1.0 - z * z).sqrt();
        Vector3::new(r * phi.cos(), r * phi.sin(), z) * (0.1 + 49.9 * self.next())
    }
}

const ROUND_TRIP_TOL: f64 = 1e-9;
const SAMPLES: usize = 20_000;

fn ds_lens() -> DoubleSphere {
    DoubleSphere::new(Focal::new(380.0, 378.0, 640.0, 512.0).unwrap(), -0.2, 0.6).unwrap()
}
fn kb_lens() -> KannalaBrandt {
    KannalaBrandt::new(
        Focal::new(600.0, 602.0, 960.0, 955.0).unwrap(),
        [0.02, -0.005, 0.001, -0.0002],
    )
    .unwrap()
}
fn eucm_lens() -> Eucm {
    Eucm::new(Focal::new(400.0, 401.0, 640.0, 512.0).unwrap(), 0.62, 1.1).unwrap()
}

fn lenses() -> Vec<(&'static str, FisheyeLens)> {
    vec![
        ("double_sphere", FisheyeLens::DoubleSphere(ds_lens())),
        ("kannala_brandt", FisheyeLens::KannalaBrandt(kb_lens())),
        ("eucm", FisheyeLens::Eucm(eucm_lens())),
    ]
}

fn assert_px(got: Option<PixelCoord>, want: (f64, f64), what: &str) {
    let got = got.unwrap_or_else(|| panic!("{what}: not projected"));
    assert!(
        (got.u - want.0).abs() < 1e-9 && (got.v - want.1).abs() < 1e-9,
        "{what}: got ({}, {}), want {want:?}",
        got.u,
        got.v
    );
}

/// Values computed once with Python's `math` module straight from the published formulas
/// (DS: d1, d2, alpha d2 + (1 - alpha)(xi d1 + z); KB: theta = atan2(r, z), d(theta) with
/// k1..k4; EUCM: d = sqrt(beta (x^2 + y^2) + z^2), alpha d + (1 - alpha) z), printed with
/// 12 decimals, e.g. `fx*x/den+cx`.
#[test]
fn known_projections_match_the_published_formulas() {
    let points = [
        Vector3::new(0.3, -0.2, 1.0),
        Vector3::new(1.0, 0.5, 0.2),
        Vector3::new(-0.4, 0.9, -0.3),
    ];
    let ds = [
        (776.596953220170, 421.414652075045),
        (1215.62176952496, 798.296090632151),
        (310.974346075531, 1248.411364902001),
    ];
    let kb = [
        (1133.158721472058, 839.176055193134),
        (1726.282941813385, 1339.418609143048),
        (495.250679492870, 2004.171591044845),
    ];
    let eucm = [
        (755.069358078407, 435.095312350931),
        (1131.694426987985, 758.461831527727),
        (350.614860563474, 1164.744355141513),
    ];
    for (i, p) in points.iter().enumerate() {
        assert_px(ds_lens().project(p), ds[i], &format!("ds {p:?}"));
        assert_px(kb_lens().project(p), kb[i], &format!("kb {p:?}"));
        assert_px(eucm_lens().project(p), eucm[i], &format!("eucm {p:?}"));
        // The length of the point does not matter.
        assert_px(ds_lens().project(&(p * 7.5)), ds[i], "ds scaled");
    }
    // The third point's pixel lies below a 1024-row image: the bounded camera does not see it.
    let cam = FisheyeCamera::new(
        FisheyeLens::DoubleSphere(ds_lens()),
        ImageSize::new(1280, 1024).unwrap(),
    )
    .unwrap();
    assert!(cam.project(&points[2]).is_none());
    assert!(cam.project(&points[0]).is_some());
    // The optical axis lands on the principal point.
    for (name, lens) in lenses() {
        let f = lens.focal();
        assert_px(lens.project(&Vector3::z()), (f.cx, f.cy), name);
    }
}

#[test]
fn round_trip_over_random_directions() {
    for (name, lens) in lenses() {
        let mut rng = Lcg(7);
        let mut seen = 0;
        let mut worst: f64 = 0.0;
        for _ in 0..SAMPLES {
            let p = rng.point();
            let Some(px) = lens.project(&p) else {
                continue;
            };
            seen += 1;
            let dir = lens.unproject(px).unwrap_or_else(|| {
                panic!("{name}: pixel of a seen point {p:?} does not unproject")
            });
            worst = worst.max((dir.into_inner() - p.normalize()).norm());
        }
        assert!(worst < ROUND_TRIP_TOL, "{name}: worst round trip {worst:e}");
        // Each lens sees well beyond a hemisphere.
        assert!(
            seen > SAMPLES / 2,
            "{name}: only {seen} of {SAMPLES} directions seen"
        );
    }
}

#[test]
fn points_outside_the_field_of_view_are_not_seen() {
    let mut rng = Lcg(11);
    // Double sphere: valid iff z > -w2 |p|, w1 = (1 - alpha) / alpha for alpha > 0.5.
    let (xi, alpha) = (-0.2f64, 0.6f64);
    let w1 = (1.0 - alpha) / alpha;
    let w2 = (w1 + xi) / (2.0 * w1 * xi + xi * xi + 1.0).sqrt();
    // Half field of view: pi/2 + asin(w2), about 122 degrees.
    let ds = ds_lens();
    let eucm = eucm_lens();
    let w_eucm = (1.0 - 0.62) / 0.62;
    let (mut ds_out, mut eucm_out) = (0, 0);
    for _ in 0..SAMPLES {
        let p = rng.point();
        if p.z <= -w2 * p.norm() {
            ds_out += 1;
            assert!(ds.project(&p).is_none(), "ds sees {p:?} outside its FOV");
        } else {
            assert!(ds.project(&p).is_some(), "ds misses {p:?} inside its FOV");
        }
        let d = (1.1 * (p.x * p.x + p.y * p.y) + p.z * p.z).sqrt();
        if p.z <= -w_eucm * d {
            eucm_out += 1;
            assert!(
                eucm.project(&p).is_none(),
                "eucm sees {p:?} outside its FOV"
            );
        }
    }
    assert!(ds_out > 1000 && eucm_out > 1000, "{ds_out} {eucm_out}");
    // Straight behind and the zero vector.
    for (name, lens) in lenses() {
        assert!(lens.project(&-Vector3::z()).is_none(), "{name} sees -z");
        assert!(lens.project(&Vector3::zeros()).is_none(), "{name} sees 0");
    }
    // A pinhole (EUCM alpha = 0) sees nothing at or behind z = 0: a 180-degree limit.
    let pinhole = Eucm::new(Focal::new(300.0, 300.0, 320.0, 240.0).unwrap(), 0.0, 1.0).unwrap();
    assert!(pinhole.project(&Vector3::new(1.0, 0.0, 0.0)).is_none());
    assert!(pinhole.project(&Vector3::new(1.0, 0.2, -0.01)).is_none());
    assert_px(
        pinhole.project(&Vector3::new(0.5, -0.25, 2.0)),
        (320.0 + 300.0 * 0.25, 240.0 - 300.0 * 0.125),
        "pinhole",
    );
}

/// With k1 = -0.1 (others 0), d'(theta) = 1 - 0.3 theta^2 vanishes at theta = sqrt(1 / 0.3):
/// beyond it the polynomial folds back, so those rays are not seen and their pixels never
/// reappear as wrapped ones.
#[test]
fn kannala_brandt_stops_where_its_polynomial_folds() {
    let kb = KannalaBrandt::new(
        Focal::new(500.0, 500.0, 800.0, 800.0).unwrap(),
        [-0.1, 0.0, 0.0, 0.0],
    )
    .unwrap();
    let theta_max = (1.0f64 / 0.3).sqrt();
    assert!(
        (kb.theta_max_rad() - theta_max).abs() < 1e-12,
        "{}",
        kb.theta_max_rad()
    );
    let at = |theta: f64| Vector3::new(theta.sin(), 0.0, theta.cos());
    assert!(kb.project(&at(theta_max - 1e-6)).is_some());
    assert!(kb.project(&at(theta_max + 1e-6)).is_none());
    assert!(kb.project(&at(2.5)).is_none());
    // Pixels beyond d(theta_max) = theta_max (1 - 0.1 theta_max^2) do not unproject.
    let r_max = theta_max * (1.0 - 0.1 * theta_max * theta_max);
    let px = |r: f64| PixelCoord {
        u: 800.0 + 500.0 * r,
        v: 800.0,
    };
    assert!(kb.unproject(px(r_max * 0.999)).is_some());
    assert!(kb.unproject(px(r_max * 1.001)).is_none());
    // Without a fold (all k zero) the model sees everything but the backward axis.
    let equi =
        KannalaBrandt::new(Focal::new(500.0, 500.0, 800.0, 800.0).unwrap(), [0.0; 4]).unwrap();
    assert_eq!(equi.theta_max_rad(), std::f64::consts::PI);
    let d = equi
        .unproject(PixelCoord {
            u: 800.0 + 500.0 * 3.0,
            v: 800.0,
        })
        .unwrap();
    assert!((d.z - 3.0f64.cos()).abs() < 1e-12 && (d.x - 3.0f64.sin()).abs() < 1e-12);
}

#[test]
fn pixels_off_the_image_or_outside_the_model_do_not_unproject() {
    for (name, lens) in lenses() {
        let f = lens.focal();
        let cam = FisheyeCamera::new(lens.clone(), ImageSize::new(1920, 1910).unwrap())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        for px in [
            PixelCoord { u: -0.6, v: 10.0 },
            PixelCoord { u: 10.0, v: -0.6 },
            PixelCoord { u: 1919.6, v: 10.0 },
            PixelCoord { u: 10.0, v: 1909.6 },
        ] {
            assert!(
                cam.unproject(px).is_none(),
                "{name}: {px:?} is off the image"
            );
        }
        assert!(cam.unproject(PixelCoord { u: f.cx, v: f.cy }).is_some());
    }
    // Double sphere with alpha = 0.6: only r^2 <= 1 / (2 alpha - 1) = 5 unprojects.
    let ds = ds_lens();
    let px = |mx: f64| PixelCoord {
        u: 640.0 + 380.0 * mx,
        v: 512.0,
    };
    assert!(ds.unproject(px(5f64.sqrt() * 0.99)).is_some());
    assert!(ds.unproject(px(5f64.sqrt() * 1.01)).is_none());
    // EUCM alpha = 0.62, beta = 1.1: r^2 <= 1 / (beta (2 alpha - 1)).
    let eucm = eucm_lens();
    let r_max = (1.0f64 / (1.1 * (2.0 * 0.62 - 1.0))).sqrt();
    let px = |mx: f64| PixelCoord {
        u: 640.0 + 400.0 * mx,
        v: 512.0,
    };
    assert!(eucm.unproject(px(r_max * 0.99)).is_some());
    assert!(eucm.unproject(px(r_max * 1.01)).is_none());
}

/// Lens 0 looks along the camera's +x, lens 1 along -x; each optical frame has x to the
/// image's right and y down. Columns of `cam_from_lens` are the lens axes in the camera frame.
fn dual(translation_m: f64) -> DualFisheye {
    let lens = |cx: f64| {
        FisheyeLens::KannalaBrandt(
            KannalaBrandt::new(
                Focal::new(580.0, 580.0, cx, 960.0).unwrap(),
                [0.01, 0.0, 0.0, 0.0],
            )
            .unwrap(),
        )
    };
    let rot = |x: [f64; 3], y: [f64; 3], z: [f64; 3]| {
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
            Matrix3::from_columns(&[x.into(), y.into(), z.into()]),
        ))
    };
    let front = Isometry3::from_parts(
        Translation3::new(translation_m, 0.0, 0.0),
        rot([0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]),
    );
    let back = Isometry3::from_parts(
        Translation3::new(-translation_m, 0.0, 0.0),
        rot([0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]),
    );
    DualFisheye::new(
        [
            DualLens {
                model: lens(960.0),
                cam_from_lens: front,
            },
            DualLens {
                model: lens(2880.0),
                cam_from_lens: back,
            },
        ],
        ImageSize::new(3840, 1920).unwrap(),
    )
    .unwrap()
}

#[test]
fn dual_fisheye_sees_the_whole_sphere_and_round_trips() {
    // 580 px per radian with k1 = 0.01 reaches 90 degrees at 580 d(pi/2) = 933 px, inside the
    // 960 px half-width: the two lenses overlap and see every direction.
    let cam = dual(0.0);
    assert_px(cam.project(&Vector3::x()), (960.0, 960.0), "forward");
    assert_px(cam.project(&-Vector3::x()), (2880.0, 960.0), "backward");
    // Up is towards the top of both lenses' images; left (+y) is to the left of the front lens.
    let up = cam.project(&Vector3::new(1.0, 0.0, 0.5)).unwrap();
    assert!(up.v < 960.0 && (up.u - 960.0).abs() < 1e-9);
    let left = cam.project(&Vector3::new(1.0, 0.5, 0.0)).unwrap();
    assert!(left.u < 960.0 && (left.v - 960.0).abs() < 1e-9);
    let mut rng = Lcg(3);
    let mut worst: f64 = 0.0;
    for _ in 0..SAMPLES {
        let p = rng.point();
        let px = cam.project(&p).unwrap_or_else(|| panic!("{p:?} unseen"));
        let d = cam.unproject(px).unwrap();
        worst = worst.max((d.into_inner() - p.normalize()).norm());
    }
    assert!(worst < ROUND_TRIP_TOL, "worst {worst:e}");
    // With the lenses 4 cm apart the ray starts at the lens centre and passes through the point.
    let cam = dual(0.02);
    let mut rng = Lcg(5);
    for _ in 0..2000 {
        let p = rng.point();
        if p.norm() < 0.5 {
            continue;
        }
        let px = cam.project(&p).unwrap();
        let ray = cam.unproject_ray(px).unwrap();
        let to_p = p - ray.origin.coords;
        let off_ray = (to_p - ray.dir.into_inner() * to_p.dot(&ray.dir)).norm();
        assert!(off_ray < 1e-9 * p.norm().max(1.0), "{p:?}: {off_ray:e}");
        assert!(to_p.dot(&ray.dir) > 0.0);
    }
    // A pixel off the image, and one in lens 0's half beyond its model, are not seen.
    assert!(cam.unproject(PixelCoord { u: 3839.6, v: 5.0 }).is_none());
    assert_eq!(cam.lens_of_pixel(PixelCoord { u: 1919.4, v: 5.0 }), Some(0));
    assert_eq!(cam.lens_of_pixel(PixelCoord { u: 1919.5, v: 5.0 }), Some(1));
}

#[test]
fn principal_points_must_lie_in_the_image() {
    let lens = |cx: f64, cy: f64| {
        FisheyeLens::Eucm(Eucm::new(Focal::new(400.0, 400.0, cx, cy).unwrap(), 0.6, 1.0).unwrap())
    };
    let size = ImageSize::new(1280, 1024).unwrap();
    let e = FisheyeCamera::new(lens(1500.0, 500.0), size).unwrap_err();
    assert_eq!(e.field, "cx");
    assert!(
        e.problem.contains("1500") && e.problem.contains("outside the image"),
        "{e}"
    );
    assert_eq!(
        FisheyeCamera::new(lens(600.0, -3.0), size)
            .unwrap_err()
            .field,
        "cy"
    );
    assert!(Focal::new(-400.0, 400.0, 1.0, 1.0)
        .unwrap_err()
        .problem
        .contains("positive"));
    assert_eq!(
        Focal::new(400.0, f64::NAN, 1.0, 1.0).unwrap_err().field,
        "fy"
    );
    assert_eq!(
        DoubleSphere::new(Focal::new(1.0, 1.0, 0.0, 0.0).unwrap(), 0.0, 1.5)
            .unwrap_err()
            .field,
        "alpha"
    );
    assert_eq!(
        Eucm::new(Focal::new(1.0, 1.0, 0.0, 0.0).unwrap(), 0.5, -1.0)
            .unwrap_err()
            .field,
        "beta"
    );
    assert!(ImageSize::new(0, 10).is_err());
}

#[test]
fn erp_grid_is_a_camera_model_that_sees_every_direction() {
    let g = ErpGrid::new(64).unwrap();
    let mut rng = Lcg(9);
    for _ in 0..2000 {
        let p = rng.point();
        let px = CameraModel::project(&g, &p).unwrap();
        let d = CameraModel::unproject(&g, px).unwrap();
        assert!((d.into_inner() - p.normalize()).norm() < ROUND_TRIP_TOL);
    }
    assert!(CameraModel::project(&g, &Vector3::zeros()).is_none());
    assert!(CameraModel::unproject(&g, PixelCoord { u: 10.0, v: 31.6 }).is_none());
}
