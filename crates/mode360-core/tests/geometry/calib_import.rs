//! Calibration import against fixtures in Kalibr's and Basalt's published formats, written by
//! tests/fixtures/calib/make_fixtures.py (plain Python, which also composes the Kalibr chain
//! and projects test points with each tool's own model formula into expected.json).

use mode360_core::geometry::camera::FisheyeLens;
use mode360_core::geometry::import::{
    rig_from_basalt_json, rig_from_kalibr_camchain, ImportError, ImportOptions,
};
use mode360_core::geometry::{Projection, Rig};
use nalgebra::{Point3, Vector3};
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/fixtures/calib"
    ))
    .join(name)
}

fn expected() -> serde_json::Value {
    let text = std::fs::read_to_string(fixture("expected.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// rig_from_cam and the pixels of the rig-frame points, camera by camera, against Python's.
fn check_against_expected(rig: &Rig, tool: &str) {
    let e = expected();
    let cams = e[tool].as_array().unwrap();
    assert_eq!(rig.cameras.len(), cams.len());
    let points: Vec<Point3<f64>> = e["points_rig"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            Point3::new(
                p[0].as_f64().unwrap(),
                p[1].as_f64().unwrap(),
                p[2].as_f64().unwrap(),
            )
        })
        .collect();
    let mut worst_px: f64 = 0.0;
    for (cam, want) in rig.cameras.iter().zip(cams) {
        assert_eq!(cam.name, want["name"].as_str().unwrap());
        let m = cam.rig_from_cam.to_homogeneous();
        for r in 0..4 {
            for c in 0..4 {
                let w = want["rig_from_cam"][r][c].as_f64().unwrap();
                assert!(
                    (m[(r, c)] - w).abs() < 1e-12,
                    "{tool} {}: rig_from_cam[{r}][{c}] {} vs {w}",
                    cam.name,
                    m[(r, c)]
                );
            }
        }
        let model = cam.projection.fisheye_model().unwrap();
        for (p, px) in points.iter().zip(want["pixels"].as_array().unwrap()) {
            let p_cam = cam.rig_from_cam.inverse_transform_point(p).coords;
            let got = model
                .project(&p_cam)
                .unwrap_or_else(|| panic!("{tool} {}: {p} unseen", cam.name));
            let (u, v) = (px[0].as_f64().unwrap(), px[1].as_f64().unwrap());
            worst_px = worst_px.max((got.u - u).abs()).max((got.v - v).abs());
        }
    }
    assert!(
        worst_px < 1e-9,
        "{tool}: worst pixel difference {worst_px:e}"
    );
}

#[test]
fn kalibr_camchain_imports_with_the_chain_composed() {
    let rig = rig_from_kalibr_camchain(fixture("kalibr_camchain.yaml"), &ImportOptions::default())
        .unwrap();
    check_against_expected(&rig, "kalibr");
    let kinds: Vec<&str> = rig.cameras.iter().map(|c| c.projection.name()).collect();
    assert_eq!(kinds, ["double_sphere", "kannala_brandt", "eucm", "eucm"]);
    // cam0 is the rig frame.
    assert!(rig.cameras[0]
        .rig_from_cam
        .to_homogeneous()
        .is_identity(0.0));
    // Intrinsics carried over as Kalibr orders them ([xi, alpha, fu, fv, pu, pv] for ds).
    let Projection::Fisheye(c0) = &rig.cameras[0].projection else {
        panic!()
    };
    let FisheyeLens::DoubleSphere(ds) = c0.lens() else {
        panic!()
    };
    assert_eq!((ds.xi(), ds.alpha()), (-0.18, 0.59));
    assert_eq!(
        (ds.focal().fx, ds.focal().fy, ds.focal().cx, ds.focal().cy),
        (350.1, 349.8, 640.5, 511.2)
    );
    let Projection::Fisheye(c1) = &rig.cameras[1].projection else {
        panic!()
    };
    let FisheyeLens::KannalaBrandt(kb) = c1.lens() else {
        panic!()
    };
    assert_eq!(kb.coefficients(), [0.012, -0.004, 0.0011, -0.0002]);
    // Mei's xi = 0.9 becomes alpha = 0.9 / 1.9, beta = 1, focal lengths / 1.9.
    let Projection::Fisheye(c2) = &rig.cameras[2].projection else {
        panic!()
    };
    let FisheyeLens::Eucm(omni) = c2.lens() else {
        panic!()
    };
    assert!((omni.alpha() - 0.9 / 1.9).abs() < 1e-15 && omni.beta() == 1.0);
    assert!((omni.focal().fx - 720.0 / 1.9).abs() < 1e-12);
    // Topics from rostopic, optical frame ids, and the depth output at cam0 in REP 103.
    assert_eq!(rig.cameras[2].topic, "/camera2/image_raw");
    assert_eq!(rig.cameras[2].frame_id, "cam2_optical_frame");
    assert_eq!(rig.output_frame_id, "cam0_depth");
    let fwd = rig.rig_from_output.rotation * Vector3::x();
    let up = rig.rig_from_output.rotation * Vector3::z();
    assert!((fwd - Vector3::z()).norm() < 1e-12 && (up + Vector3::y()).norm() < 1e-12);
    // The written YAML reads back as the same rig.
    let back = Rig::from_yaml_str(&rig.to_yaml(), "back.yaml").unwrap();
    check_against_expected(&back, "kalibr");
}

#[test]
fn basalt_calibration_imports_with_the_imu_as_rig_frame() {
    let opts = ImportOptions {
        rig_frame: "imu".into(),
        topic_prefix: Some("/stereo/".into()),
    };
    let rig = rig_from_basalt_json(fixture("basalt_calibration.json"), &opts).unwrap();
    check_against_expected(&rig, "basalt");
    let kinds: Vec<&str> = rig.cameras.iter().map(|c| c.projection.name()).collect();
    assert_eq!(kinds, ["double_sphere", "kannala_brandt", "eucm", "eucm"]);
    assert_eq!(rig.rig_frame, "imu");
    assert_eq!(rig.cameras[1].topic, "/stereo/cam1/image_raw");
    // ucm's alpha is EUCM's with beta = 1; pinhole is EUCM with alpha = 0.
    let alpha_beta = |i: usize| match &rig.cameras[i].projection {
        Projection::Fisheye(c) => match c.lens() {
            FisheyeLens::Eucm(m) => (m.alpha(), m.beta()),
            _ => panic!(),
        },
        _ => panic!(),
    };
    assert_eq!(alpha_beta(2), (0.64, 1.0));
    assert_eq!(alpha_beta(3), (0.0, 1.0));
}

fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn kalibr_err(text: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let p = write(&dir, "camchain.yaml", text);
    let e = rig_from_kalibr_camchain(&p, &ImportOptions::default()).unwrap_err();
    let s = e.to_string();
    assert!(s.contains("camchain.yaml"), "{s}");
    s
}

fn camchain() -> String {
    std::fs::read_to_string(fixture("kalibr_camchain.yaml")).unwrap()
}

#[test]
fn kalibr_bad_input_is_a_clear_error() {
    let base = camchain();
    // An unknown camera model names the camera and the model.
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        &dir,
        "camchain.yaml",
        &base.replacen("camera_model: eucm", "camera_model: fisheye62", 1),
    );
    let e = rig_from_kalibr_camchain(&p, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(&e, ImportError::UnknownModel { camera, model, .. } if camera == "cam3" && model == "fisheye62"),
        "{e}"
    );
    assert!(
        e.to_string().contains("unknown camera model 'fisheye62'")
            && e.to_string().contains("'cam3'")
    );
    // Distortion with no exact counterpart.
    let e = kalibr_err(&base.replacen(
        "distortion_coeffs: [0.0, 0.0, 0.0, 0.0]",
        "distortion_coeffs: [0.01, 0.0, 0.0, 0.0]",
        1,
    ));
    assert!(
        e.contains("'cam2'")
            && e.contains("omni/radtan")
            && e.contains("cannot be represented exactly"),
        "{e}"
    );
    // A principal point outside the image.
    let e = kalibr_err(&base.replacen("640.5, 511.2]", "1640.5, 511.2]", 1));
    assert!(
        e.contains("'cam0'") && e.contains("cx") && e.contains("outside the image"),
        "{e}"
    );
    // The wrong number of intrinsics, a missing chain link, a gap in the chain.
    let e = kalibr_err(&base.replacen("[0.61, 1.05, 380.0", "[1.05, 380.0", 1));
    assert!(
        e.contains("'cam3'") && e.contains("intrinsics") && e.contains("expected 6 numbers"),
        "{e}"
    );
    // cam1 without its T_cn_cnm1 block (the key and its four rows).
    let lines: Vec<&str> = base.lines().collect();
    let at = lines.iter().position(|l| *l == "cam1:").unwrap();
    let no_link: String = lines
        .iter()
        .enumerate()
        .filter(|(i, _)| !(at + 1..=at + 5).contains(i))
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    let e = kalibr_err(&no_link);
    assert!(
        e.contains("'cam1'") && e.contains("T_cn_cnm1") && e.contains("missing"),
        "{e}"
    );
    let e = kalibr_err(&base.replacen("cam2:", "cam7:", 1));
    assert!(e.contains("gap"), "{e}");
    // A chain link that is not a rotation.
    let e = kalibr_err(&base.replacen("[0.9399715008686393,", "[1.9399715008686393,", 1));
    assert!(
        e.contains("'cam1'") && e.contains("T_cn_cnm1") && e.contains("not a rotation"),
        "{e}"
    );
    // Not YAML at all.
    let e = kalibr_err("cam0: [");
    assert!(e.contains("malformed Kalibr camchain YAML"), "{e}");
    // One camera is not a rig.
    let one = &base[..base.find("cam1:").unwrap()];
    let e = kalibr_err(one);
    assert!(e.contains("at least 2"), "{e}");
}

#[test]
fn basalt_bad_input_is_a_clear_error() {
    let base = std::fs::read_to_string(fixture("basalt_calibration.json")).unwrap();
    let err = |text: &str| {
        let dir = tempfile::tempdir().unwrap();
        let p = write(&dir, "calibration.json", text);
        rig_from_basalt_json(&p, &ImportOptions::default())
            .unwrap_err()
            .to_string()
    };
    let e = err(&base.replacen("\"camera_type\": \"kb4\"", "\"camera_type\": \"kb8\"", 1));
    assert!(
        e.contains("'cam1'") && e.contains("unknown camera model 'kb8'"),
        "{e}"
    );
    let e = err(&base.replacen("\"camera_type\": \"kb4\"", "\"camera_type\": \"fov\"", 1));
    assert!(
        e.contains("'cam1'") && e.contains("'fov' cannot be represented exactly"),
        "{e}"
    );
    let e = err(&base.replacen("\"alpha\": 0.593", "\"alpah\": 0.593", 1));
    assert!(
        e.contains("'cam0'") && e.contains("intrinsics.alpha") && e.contains("missing"),
        "{e}"
    );
    let e = err(&base.replacen("\"cx\": 255.5", "\"cx\": -40.0", 1));
    assert!(
        e.contains("'cam2'") && e.contains("cx") && e.contains("outside the image"),
        "{e}"
    );
    let e = err(&base.replacen("\"qw\": 0.9999500004166653", "\"qw\": 0.5", 1));
    assert!(
        e.contains("'cam0'") && e.contains("T_imu_cam") && e.contains("norm"),
        "{e}"
    );
    let e = err("{\"value0\": {}}");
    assert!(e.contains("malformed Basalt calibration JSON"), "{e}");
}
