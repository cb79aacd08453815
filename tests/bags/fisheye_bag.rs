//! Rig bags of fisheye and dual-fisheye rigs (issue 12): rendered frames written by `synth`
//! read back byte for byte; an image that is not its camera's `image_size` is refused by the
//! writer and dropped by the reader with an error naming the camera, the size expected and
//! the size found.

use crate::common::{repo_path, TestResult};
use mode360::bag::{BagError, RigBagReader, RigBagWriter};
use mode360::frame::{RgbImage, RigFrame};
use mode360::geometry::Rig;
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::{SceneKind, SynthConfig, SynthRenderer};
use std::collections::BTreeMap;

const OMNIMVS_RIG: &str = "launch_configs/rig_omnimvs.yaml";
const DUAL_RIG: &str = "launch_configs/rig_dual_fisheye.yaml";
/// Ground-truth (ERP) width of these tests.
const GT_WIDTH: usize = 64;
const FRAMES: usize = 2;

fn config(soiled: bool) -> SynthConfig {
    SynthConfig {
        seed: 21,
        width: GT_WIDTH,
        soiled,
        scene: SceneKind::Objects,
        ..SynthConfig::default()
    }
}

/// A rig with an ERP panorama camera and a fisheye camera: images of different sizes.
fn mixed_rig() -> Result<Rig, Box<dyn std::error::Error>> {
    let omni = Rig::from_file(repo_path(OMNIMVS_RIG))?.scaled(0.25)?;
    let mut rig = omni.subset(&[0, 3])?;
    let mut erp = rig.cameras[1].clone();
    erp.name = "pano".into();
    erp.topic = "/pano/image_raw".into();
    erp.frame_id = "pano_link".into();
    erp.projection = mode360::geometry::Projection::Equirectangular;
    erp.rig_from_cam = nalgebra::Isometry3::translation(0.0, 0.0, 1.9);
    rig.cameras.push(erp);
    Ok(rig)
}

#[test]
fn rendered_fisheye_frames_read_back_byte_for_byte() -> TestResult {
    let dir = tempfile::tempdir()?;
    let rigs = [
        Rig::from_file(repo_path(OMNIMVS_RIG))?.scaled(0.25)?,
        Rig::from_file(repo_path(DUAL_RIG))?.scaled(0.25)?,
        mixed_rig()?,
    ];
    for (k, rig) in rigs.iter().enumerate() {
        let out = dir.path().join(format!("rig{k}.mcap"));
        record_synthetic_bag(&RecordOptions {
            rig: rig.clone(),
            config: config(true),
            frames: FRAMES,
            first_frame: 3,
            out: out.clone(),
            show_progress: false,
        })?;
        let renderer = SynthRenderer::new(config(true))?;
        let reader = RigBagReader::open(&out)?;
        assert_eq!(reader.rig().cameras.len(), rig.cameras.len());
        for (a, b) in reader.rig().cameras.iter().zip(&rig.cameras) {
            assert_eq!(a.projection, b.projection, "rig {k} camera {}", a.name);
        }
        let frames: Vec<RigFrame> = reader.frames().collect::<Result<_, _>>()?;
        assert_eq!(frames.len(), FRAMES, "rig {k}");
        for (i, got) in frames.iter().enumerate() {
            let want = renderer.render_frame(rig, 3 + i);
            assert_eq!(got.stamp_ns, want.stamp_ns);
            for (c, (g, w)) in got.images.iter().zip(&want.images).enumerate() {
                assert_eq!(g.dimensions(), w.dimensions(), "rig {k} camera {c}");
                assert!(
                    g.as_raw() == w.as_raw(),
                    "rig {k} frame {i} camera {c} bytes"
                );
            }
            let (g, w) = (
                got.ground_truth.as_ref().ok_or("no ground truth")?,
                want.ground_truth.as_ref().ok_or("no ground truth")?,
            );
            assert_eq!((g.width, g.height), (GT_WIDTH, GT_WIDTH / 2));
            assert!(g
                .data
                .iter()
                .zip(&w.data)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }
    Ok(())
}

/// A frame of one flat image per camera of `rig`, at `sizes`.
fn frame_with(rig: &Rig, sizes: &[(u32, u32)]) -> RigFrame {
    assert_eq!(sizes.len(), rig.cameras.len(), "one size per camera");
    RigFrame {
        stamp_ns: 1_700_000_000_000_000_000,
        images: sizes
            .iter()
            .map(|&(w, h)| RgbImage::from_pixel(w, h, image::Rgb([1, 2, 3])))
            .collect(),
        ground_truth: None,
        labels: None,
    }
}

#[test]
fn wrong_fisheye_size_is_refused_by_the_writer_and_dropped_by_the_reader() -> TestResult {
    let dir = tempfile::tempdir()?;
    let rig = mixed_rig()?; // two 96 x 96 fisheyes and a panorama
    let path = dir.path().join("w.mcap");
    let mut writer = RigBagWriter::create(&path, &rig, &BTreeMap::new())?;
    // A panorama on a fisheye topic.
    let err = writer
        .write_frame(&frame_with(&rig, &[(96, 96), (128, 64), (128, 64)]))
        .expect_err("wrong size");
    let text = err.to_string();
    for part in [
        "/rear_right/image_raw",
        "camera 'rear_right'",
        "expected 96x96 (its double_sphere image_size), got 128x64",
    ] {
        assert!(text.contains(part), "{text}");
    }
    // A square image on the panorama camera.
    let err = writer
        .write_frame(&frame_with(&rig, &[(96, 96), (96, 96), (96, 96)]))
        .expect_err("not 2:1");
    assert!(
        err.to_string()
            .contains("camera 'pano': expected a 2:1 equirectangular panorama"),
        "{err}"
    );
    writer.write_frame(&frame_with(&rig, &[(96, 96), (96, 96), (128, 64)]))?;
    writer.finish()?;

    // Read with the full-resolution rig: every fisheye image is now the wrong size.
    let full = Rig::from_file(repo_path(OMNIMVS_RIG))?.subset(&[0, 3])?;
    let mut full_mixed = full.clone();
    full_mixed.cameras.push(rig.cameras[2].clone());
    let reader = RigBagReader::open_with_rig(&path, full_mixed)?;
    let results: Vec<Result<RigFrame, BagError>> = reader.frames().collect();
    assert_eq!(results.len(), 1);
    let err = results[0].as_ref().expect_err("dropped").to_string();
    assert!(
        err.contains(
            "camera 'front_left': expected 384x384 (its double_sphere image_size), got 96x96"
        ),
        "{err}"
    );
    // And with the rig stored in the bag, it reads.
    let reader = RigBagReader::open(&path)?;
    let frame = reader.frames().next().ok_or("no frame")??;
    let sizes: Vec<_> = frame.images.iter().map(RgbImage::dimensions).collect();
    assert_eq!(sizes, [(96, 96), (96, 96), (128, 64)]);
    Ok(())
}
