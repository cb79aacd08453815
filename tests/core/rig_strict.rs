//! Rig YAML and `Rig::new` are strict (issue 22): topics and frame ids follow ROS 2's naming
//! rules on every path to a rig, implausible values are refused with the bound, a camera with
//! fisheye fields but no projection says the projection is missing, and huge or deeply nested
//! files are refused before parsing; every rig the project ships or trains on still loads.

use mode360::geometry::rig::{validate_frame_id, validate_topic_name};
use mode360::geometry::rig_yaml::MAX_CALIBRATION_FILE_BYTES;
use mode360::geometry::{Projection, Rig, RigCamera, RigError};
use mode360::train::fisheye_rigs::random_fisheye_rig;
use mode360::train::rack::random_rig;
use nalgebra::Isometry3;
use std::time::{Duration, Instant};

const RIG: &str = r#"
rig_frame: base_link
output: {frame_id: rig_centre, rig_from_output: {translation: [0, 0, 1.5], rotation_xyzw: [0, 0, 0, 1]}}
cameras:
  - name: front
    topic: /front/image_raw
    frame_id: front_optical
    projection: kannala_brandt
    image_size: [1280, 1024]
    intrinsics: {fx: 400.0, fy: 401.0, cx: 640.0, cy: 512.0, k1: 0.02, k2: -0.005, k3: 0.001, k4: -0.0002}
    rig_from_cam: {translation: [0.5, 0, 1.5], rotation_rpy: [-1.5707963267948966, 0, -1.5707963267948966]}
  - name: back
    topic: /back/image_raw
    frame_id: back_optical
    projection: eucm
    image_size: [1280, 1024]
    intrinsics: {fx: 400.0, fy: 401.0, cx: 640.0, cy: 512.0, alpha: 0.62, beta: 1.1}
    rig_from_cam: {translation: [-0.5, 0, 1.5], rotation_rpy: [-1.5707963267948966, 0, 1.5707963267948966]}
  - name: pano
    topic: pano/image_raw
    frame_id: pano_link
    rig_from_cam: {translation: [0, 0, 2.2], rotation_xyzw: [0, 0, 0, 1]}
"#;

/// The error of `RIG` with `from` replaced by `to`, checked to name the file and every needle,
/// on one line.
fn err(from: &str, to: &str, needles: &[&str]) -> String {
    assert!(RIG.contains(from), "test setup: {from}");
    let e = Rig::from_yaml_str(&RIG.replacen(from, to, 1), "strict_rig.yaml")
        .expect_err(to)
        .to_string();
    for n in std::iter::once(&"strict_rig.yaml").chain(needles) {
        assert!(e.contains(n), "error '{e}' should mention '{n}'");
    }
    assert!(!e.contains('\n'), "one line: {e}");
    e
}

#[test]
fn the_base_rig_loads_and_a_missing_projection_means_equirectangular() {
    let rig = Rig::from_yaml_str(RIG, "strict_rig.yaml").unwrap();
    assert!(rig.cameras[2].projection.is_equirectangular());
    assert_eq!(rig.cameras[2].topic, "pano/image_raw");
}

#[test]
fn topics_must_be_ros2_topic_names() {
    // Issue 22: a topic with a space, a newline and quotes rendered a bag.
    for (topic, shown) in [
        ("\"/front/image raw\"", "' '"),
        ("\"/front/image\\n\\\"raw\\\"\"", "'\\n'"),
        ("/front//image_raw", "'//'"),
        ("/front/image_raw/", "ends with '/'"),
        ("/front/2image", "'2image' starts with a digit"),
        ("/front/image__raw", "'__'"),
        ("~/image_raw", "'~'"),
        ("\"/{ns}/image_raw\"", "'{'"),
        ("/front/image-raw", "'-'"),
    ] {
        err(
            "topic: /front/image_raw",
            &format!("topic: {topic}"),
            &[
                "camera 'front'",
                "field 'topic'",
                "not a valid ROS 2 topic name",
                shown,
            ],
        );
    }
}

#[test]
fn frame_ids_must_be_usable_tf2_frames() {
    for (frame, shown) in [
        ("\"back optical\"", "' '"),
        ("\"back\\toptical\"", "'\\t'"),
        ("\"back\\\"optical\"", "'\"'"),
        ("/back_optical", "starts with '/'"),
    ] {
        err(
            "frame_id: back_optical",
            &format!("frame_id: {frame}"),
            &["camera 'back'", "field 'frame_id'", shown],
        );
    }
    err(
        "rig_frame: base_link",
        "rig_frame: \"base link\"",
        &["field 'rig_frame'", "' '"],
    );
    err(
        "frame_id: rig_centre",
        "frame_id: /rig_centre",
        &["field 'output.frame_id'", "starts with '/'"],
    );
}

#[test]
fn rig_new_checks_names_on_every_path() {
    let cam = |name: &str, topic: &str, frame: &str| RigCamera {
        name: name.into(),
        topic: topic.into(),
        frame_id: frame.into(),
        projection: Projection::Equirectangular,
        rig_from_cam: Isometry3::translation(0.0, 0.0, 1.0),
    };
    let ok = || {
        vec![
            cam("a", "/a/image_raw", "a_link"),
            cam("b", "b/image", "b_link"),
        ]
    };
    Rig::new("base_link", ok(), 0, None).unwrap();
    let mut bad = ok();
    bad[1].topic = "/b image".into();
    let e = Rig::new("base_link", bad, 0, None).unwrap_err();
    assert!(
        matches!(&e, RigError::Camera { camera, field, .. } if camera == "b" && field == "topic"),
        "{e}"
    );
    let mut bad = ok();
    bad[0].frame_id = "a link".into();
    let e = Rig::new("base_link", bad, 0, None).unwrap_err();
    assert!(
        matches!(&e, RigError::Camera { camera, field, .. } if camera == "a" && field == "frame_id"),
        "{e}"
    );
    let mut far = ok();
    far[0].rig_from_cam = Isometry3::translation(1e308, 0.0, 0.0);
    let e = Rig::new("base_link", far, 0, None).unwrap_err().to_string();
    assert!(
        e.contains("field 'rig_from_cam'") && e.contains("1000 m"),
        "{e}"
    );
}

#[test]
fn shipped_and_training_rigs_pass_the_rules() {
    let root = env!("CARGO_MANIFEST_DIR");
    let mut files = Vec::new();
    for (dir, prefix) in [("launch_configs", "rig_"), ("models/eval_rigs", "")] {
        for entry in std::fs::read_dir(format!("{root}/{dir}")).unwrap() {
            let p = entry.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            if name.starts_with(prefix) && name.ends_with(".yaml") {
                files.push(p);
            }
        }
    }
    assert!(files.len() >= 6, "{files:?}");
    let mut rigs: Vec<Rig> = files
        .iter()
        .map(|p| Rig::from_file(p).unwrap_or_else(|e| panic!("{e}")))
        .collect();
    for seed in 0..16 {
        rigs.push(random_rig(seed).unwrap());
        rigs.push(random_fisheye_rig(seed, 512).unwrap());
    }
    for rig in &rigs {
        for c in &rig.cameras {
            assert_eq!(validate_topic_name(&c.topic), Ok(()));
            assert_eq!(validate_frame_id(&c.frame_id), Ok(()));
        }
        assert_eq!(validate_frame_id(&rig.output_frame_id), Ok(()));
        // And they write and read back.
        Rig::from_yaml_str(&rig.to_yaml(), "back.yaml").unwrap();
    }
}

#[test]
fn a_missing_projection_is_named() {
    // Issue 22: said "field 'image_size': not used by projection equirectangular".
    let e = err(
        "    projection: kannala_brandt\n",
        "",
        &[
            "camera 'front'",
            "field 'projection': missing",
            "image_size",
            "double_sphere, kannala_brandt, eucm, dual_fisheye",
        ],
    );
    assert!(!e.contains("not used by projection"), "{e}");
    // An explicit equirectangular projection with fisheye fields is still that error.
    err(
        "projection: eucm",
        "projection: equirectangular",
        &[
            "field 'image_size'",
            "not used by projection equirectangular",
        ],
    );
}

#[test]
fn duplicate_keys_are_errors() {
    err(
        "k1: 0.02,",
        "k1: 0.02, k1: 0.5,",
        &["malformed YAML", "duplicate", "k1"],
    );
    err(
        "    frame_id: back_optical\n",
        "    frame_id: back_optical\n    frame_id: back_link\n",
        &["malformed YAML", "duplicate", "frame_id"],
    );
}

#[test]
fn implausible_values_are_refused_with_the_bound() {
    let focal = "[0.001, 1000000] px";
    err(
        "fx: 400.0, fy: 401.0, cx: 640.0, cy: 512.0, k1",
        "fx: 1.0e-300, fy: 401.0, cx: 640.0, cy: 512.0, k1",
        &["camera 'front'", "field 'intrinsics.fx'", "1e-300", focal],
    );
    err(
        "fy: 401.0, cx: 640.0, cy: 512.0, alpha",
        "fy: 1.0e+308, cx: 640.0, cy: 512.0, alpha",
        &["camera 'back'", "field 'intrinsics.fy'", "1e308", focal],
    );
    for k in ["1.0e+10", "-1.0e+10"] {
        err(
            "k2: -0.005",
            &format!("k2: {k}"),
            &["camera 'front'", "field 'intrinsics.k2'", "[-1000, 1000]"],
        );
    }
    err(
        "beta: 1.1",
        "beta: 1.0e+10",
        &["camera 'back'", "field 'intrinsics.beta'", "[-1000, 1000]"],
    );
    err(
        "translation: [0.5, 0, 1.5]",
        "translation: [1.0e+308, 0, 1.5]",
        &[
            "camera 'front'",
            "field 'rig_from_cam.translation'",
            "plausible 1000 m",
        ],
    );
    err(
        "translation: [0, 0, 1.5]",
        "translation: [0, 0, 2000]",
        &["field 'output.rig_from_output.translation'", "1000 m"],
    );
    // Issue 22: roll = 1e300 rendered a bag.
    err(
        "rotation_rpy: [-1.5707963267948966, 0, 1.5707963267948966]",
        "rotation_rpy: [1.0e+300, 0, 1.5707963267948966]",
        &[
            "camera 'back'",
            "field 'rig_from_cam.rotation_rpy'",
            "1e300",
            "[-6.283185, 6.283185]",
        ],
    );
    err(
        "[0, 0, 2.2], rotation_xyzw: [0, 0, 0, 1]",
        "[0, 0, 2.2], rotation_xyzw: [0, 0, 0, .nan]",
        &["camera 'pano'", "rotation_xyzw", "not finite"],
    );
}

#[test]
fn rig_files_are_guarded_before_parsing() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    // A byte-order mark is dropped.
    let plain = Rig::from_yaml_str(RIG, "a.yaml").unwrap();
    let p = write("bom.yaml", &format!("\u{feff}{RIG}"));
    assert_eq!(Rig::from_file(&p).unwrap(), plain);
    let t0 = Instant::now();
    let p = write("deep.yaml", &format!("cameras: {}", "[".repeat(400_000)));
    let e = Rig::from_file(&p).unwrap_err().to_string();
    assert!(
        e.contains("deep.yaml") && e.contains("deeper than 64") && e.contains("line 1 column 74"),
        "{e}"
    );
    let e = Rig::from_yaml_str(&"{a: ".repeat(100_000), "inline")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("inline: nesting deeper than 64"), "{e}");
    let sneaky = format!("cameras: {}", "[ \"]\", ".repeat(50_000));
    let e = Rig::from_yaml_str(&sneaky, "sneaky")
        .unwrap_err()
        .to_string();
    assert!(e.contains("more than 8192"), "{e}");
    let big = format!("{RIG}{}", "#".repeat(MAX_CALIBRATION_FILE_BYTES as usize));
    let p = write("big.yaml", &big);
    let e = Rig::from_file(&p).unwrap_err().to_string();
    assert!(e.contains("big.yaml") && e.contains("1 MiB"), "{e}");
    let e = Rig::from_yaml_str(&big, "big text")
        .unwrap_err()
        .to_string();
    assert!(e.contains("big text") && e.contains("1 MiB"), "{e}");
    let elapsed = t0.elapsed();
    assert!(elapsed < Duration::from_secs(5), "took {elapsed:?}");
}
