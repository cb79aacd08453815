//! Fisheye and dual-fisheye cameras in the rig YAML: each model loads and writes back, bad
//! intrinsics are errors naming the file, the camera and the field, and the parts that handle
//! only panoramas refuse such a rig by name.

use mode360_core::geometry::camera::CameraModel;
use mode360_core::geometry::erp::PixelCoord;
use mode360_core::geometry::{GeometryError, Projection, Rig};
use nalgebra::Vector3;

const RIG: &str = r#"
rig_frame: base_link
cameras:
  - name: front
    topic: /front/image_raw
    frame_id: front_optical
    projection: double_sphere
    image_size: [1280, 1024]
    intrinsics: {fx: 380.0, fy: 378.0, cx: 640.0, cy: 512.0, xi: -0.2, alpha: 0.6}
    rig_from_cam: {translation: [0.5, 0, 1.5], rotation_rpy: [-1.5707963267948966, 0, -1.5707963267948966]}
  - name: left
    topic: /left/image_raw
    frame_id: left_optical
    projection: kannala_brandt
    image_size: [1920, 1910]
    intrinsics: {fx: 600.0, fy: 602.0, cx: 960.0, cy: 955.0, k1: 0.02, k2: -0.005, k3: 0.001, k4: -0.0002}
    rig_from_cam: {translation: [0, 0.5, 1.5], rotation_rpy: [-1.5707963267948966, 0, 0]}
  - name: right
    topic: /right/image_raw
    frame_id: right_optical
    projection: eucm
    image_size: [1280, 1024]
    intrinsics: {fx: 400.0, fy: 401.0, cx: 640.0, cy: 512.0, alpha: 0.62, beta: 1.1}
    rig_from_cam: {translation: [0, -0.5, 1.5], rotation_rpy: [-1.5707963267948966, 0, 3.141592653589793]}
  - name: roof
    topic: /roof/image_raw
    frame_id: roof_link
    projection: dual_fisheye
    image_size: [3840, 1920]
    lenses:
      - projection: kannala_brandt
        intrinsics: {fx: 580, fy: 580, cx: 960, cy: 960, k1: 0.01, k2: 0, k3: 0, k4: 0}
        cam_from_lens: {translation: [0.02, 0, 0], rotation_rpy: [-1.5707963267948966, 0, -1.5707963267948966]}
      - projection: double_sphere
        intrinsics: {fx: 380, fy: 380, cx: 2880, cy: 960, xi: -0.1, alpha: 0.55}
        cam_from_lens: {translation: [-0.02, 0, 0], rotation_rpy: [-1.5707963267948966, 0, 1.5707963267948966]}
    rig_from_cam: {translation: [0, 0, 2.0], rotation_xyzw: [0, 0, 0, 1]}
  - name: pano
    topic: /pano/image_raw
    frame_id: pano_link
    projection: equirectangular
    rig_from_cam: {translation: [0, 0, 2.2], rotation_xyzw: [0, 0, 0, 1]}
"#;

fn load(text: &str) -> Result<Rig, String> {
    Rig::from_yaml_str(text, "fisheye_rig.yaml").map_err(|e| e.to_string())
}

#[test]
fn every_model_loads_and_writes_back() {
    let rig = load(RIG).unwrap();
    let names: Vec<&str> = rig.cameras.iter().map(|c| c.projection.name()).collect();
    assert_eq!(
        names,
        [
            "double_sphere",
            "kannala_brandt",
            "eucm",
            "dual_fisheye",
            "equirectangular"
        ]
    );
    let Projection::Fisheye(front) = &rig.cameras[0].projection else {
        panic!("front is not a fisheye");
    };
    // Same numbers as tests/core/camera_models.rs (Python from the published formula).
    let px = front.project(&Vector3::new(0.3, -0.2, 1.0)).unwrap();
    assert!((px.u - 776.596953220170).abs() < 1e-9 && (px.v - 421.414652075045).abs() < 1e-9);
    assert_eq!(front.image_size().width, 1280);
    // The front lens's optical axis (z) is the rig's forward (x); image right (x) is the rig's -y.
    let r = rig.cameras[0].rig_from_cam.rotation;
    assert!((r * Vector3::z() - Vector3::x()).norm() < 1e-12);
    assert!((r * Vector3::x() + Vector3::y()).norm() < 1e-12);
    assert!((r * Vector3::y() + Vector3::z()).norm() < 1e-12);

    let back = load(&rig.to_yaml()).unwrap();
    assert_eq!(back.cameras.len(), rig.cameras.len());
    for (a, b) in rig.cameras.iter().zip(&back.cameras) {
        assert_eq!(a.projection.name(), b.projection.name());
        let (Some(ma), Some(mb)) = (a.projection.fisheye_model(), b.projection.fisheye_model())
        else {
            assert!(a.projection.is_equirectangular() && b.projection.is_equirectangular());
            continue;
        };
        assert_eq!(ma.image_size(), mb.image_size());
        for p in [
            Vector3::new(0.3, -0.2, 1.0),
            Vector3::new(1.0, 0.1, 0.1),
            Vector3::new(-1.0, 0.4, 0.2),
        ] {
            match (ma.project(&p), mb.project(&p)) {
                (None, None) => {}
                (Some(x), Some(y)) => {
                    assert!(
                        (x.u - y.u).abs() < 1e-9 && (x.v - y.v).abs() < 1e-9,
                        "{}",
                        a.name
                    )
                }
                other => panic!("{}: {other:?}", a.name),
            }
        }
    }
    // The dual fisheye's right half is its second lens (double sphere), looking backwards.
    let dual = rig.cameras[3].projection.fisheye_model().unwrap();
    let px = dual.project(&Vector3::new(-1.0, 0.0, 0.0)).unwrap();
    assert!(
        (px.u - 2880.0).abs() < 1e-9 && (px.v - 960.0).abs() < 1e-9,
        "{px:?}"
    );
    let d = dual.unproject(PixelCoord { u: 960.0, v: 960.0 }).unwrap();
    assert!((d.into_inner() - Vector3::x()).norm() < 1e-12);
}

fn expect_err(from: &str, to: &str, needles: &[&str]) {
    assert!(RIG.contains(from), "test setup: {from}");
    let e = load(&RIG.replacen(from, to, 1)).expect_err(to);
    for n in ["fisheye_rig.yaml"].iter().chain(needles) {
        assert!(e.contains(n), "error '{e}' should mention '{n}'");
    }
}

#[test]
fn bad_intrinsics_name_file_camera_and_field() {
    // A principal point outside the image.
    expect_err(
        "cx: 640.0, cy: 512.0, xi",
        "cx: 1400.0, cy: 512.0, xi",
        &["'front'", "intrinsics.cx", "outside the image"],
    );
    expect_err(
        "cy: 955.0",
        "cy: 2000.0",
        &["'left'", "intrinsics.cy", "outside the image"],
    );
    // Each lens of a dual fisheye must stay in its half.
    expect_err(
        "cx: 2880",
        "cx: 1500",
        &["'roof'", "lenses[1].intrinsics.cx", "outside"],
    );
    // A negative focal length.
    expect_err(
        "fx: 400.0",
        "fx: -400.0",
        &["'right'", "intrinsics.fx", "positive"],
    );
    // A missing parameter, and one the model does not take.
    expect_err(
        ", alpha: 0.62, beta: 1.1",
        ", alpha: 0.62",
        &["'right'", "intrinsics.beta", "missing"],
    );
    expect_err(
        "k4: -0.0002",
        "k4: -0.0002, xi: 0.1",
        &[
            "'left'",
            "intrinsics.xi",
            "not a parameter of kannala_brandt",
        ],
    );
    // Out of the model's valid range.
    expect_err(
        "alpha: 0.6}",
        "alpha: 1.6}",
        &["'front'", "intrinsics.alpha", "valid range"],
    );
    expect_err(
        "xi: -0.2",
        "xi: -3",
        &["'front'", "intrinsics.xi", "valid range"],
    );
    expect_err(
        "beta: 1.1",
        "beta: 0",
        &["'right'", "intrinsics.beta", "positive"],
    );
    expect_err(
        "k2: -0.005",
        "k2: .nan",
        &["'left'", "intrinsics.k2", "not finite"],
    );
    // Image size.
    expect_err(
        "    image_size: [1280, 1024]\n    intrinsics: {fx: 400.0",
        "    intrinsics: {fx: 400.0",
        &["'right'", "image_size", "missing"],
    );
    expect_err(
        "image_size: [1920, 1910]",
        "image_size: [1920.5, 1910]",
        &["'left'", "image_size", "whole number"],
    );
    expect_err(
        "image_size: [3840, 1920]",
        "image_size: [3841, 1920]",
        &["'roof'", "image_size", "even"],
    );
    // A dual fisheye with one lens, or a lens without its pose or with an unknown model.
    let one_lens = RIG.replacen(
        "      - projection: double_sphere\n        intrinsics: {fx: 380, fy: 380, cx: 2880, cy: 960, xi: -0.1, alpha: 0.55}\n        cam_from_lens: {translation: [-0.02, 0, 0], rotation_rpy: [-1.5707963267948966, 0, 1.5707963267948966]}\n",
        "",
        1,
    );
    let e = load(&one_lens).unwrap_err();
    assert!(
        e.contains("'roof'")
            && e.contains("lenses")
            && e.contains("exactly 2")
            && e.contains("found 1"),
        "{e}"
    );
    expect_err(
        "        cam_from_lens: {translation: [0.02, 0, 0], rotation_rpy: [-1.5707963267948966, 0, -1.5707963267948966]}\n",
        "",
        &["'roof'", "lenses[0].cam_from_lens", "missing"],
    );
    expect_err(
        "      - projection: kannala_brandt",
        "      - projection: fisheye62",
        &["'roof'", "lenses[0].projection", "not a lens model"],
    );
    // Fields that do not belong to the projection, and unknown projections.
    expect_err(
        "    projection: equirectangular\n",
        "    projection: equirectangular\n    image_size: [100, 50]\n",
        &[
            "'pano'",
            "image_size",
            "not used by projection equirectangular",
        ],
    );
    expect_err(
        "projection: eucm",
        "projection: omni",
        &[
            "'right'",
            "projection",
            "unsupported projection 'omni'",
            "double_sphere",
        ],
    );
    // A typo in a parameter name is a YAML error naming the field.
    let e = load(&RIG.replacen("alpha: 0.62", "alpah: 0.62", 1)).unwrap_err();
    assert!(e.contains("alpah") && e.contains("fisheye_rig.yaml"), "{e}");
}

/// `Rig::require_equirectangular`: the check a part that handles panoramas only uses to refuse
/// a fisheye rig by name.
#[test]
fn panorama_only_parts_refuse_a_fisheye_rig_by_name() {
    let rig = load(RIG).unwrap();
    let e = rig
        .require_equirectangular("the photometric sweep")
        .unwrap_err();
    assert_eq!(
        e,
        GeometryError::UnsupportedProjection {
            camera: "front".into(),
            projection: "double_sphere",
            consumer: "the photometric sweep",
        }
    );
    assert!(
        e.to_string().contains(
            "camera front: projection double_sphere is not supported by the photometric sweep"
        ),
        "{e}"
    );
    // A subset keeps the refusal: it names the first camera that is not a panorama.
    let with_pano = rig.subset(&[4, 1]).unwrap();
    let e = with_pano.require_equirectangular("x").unwrap_err();
    assert!(
        e.to_string()
            .contains("camera left: projection kannala_brandt"),
        "{e}"
    );
    // A rig of panoramas only passes.
    let deep360 = Rig::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    ));
    assert_eq!(deep360.unwrap().require_equirectangular("x"), Ok(()));
}
