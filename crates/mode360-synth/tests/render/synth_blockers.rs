//! Blocked lenses (issues 19 and 21): a blocker covers its target fraction of a panorama's
//! solid angle or of a fisheye's seen pixels, reports that fraction exactly, leaves every other
//! pixel's bytes alone, is opaque, and stays the same across frames.

use crate::common::{deep360_rig, repo_path};
use mode360_core::frame::RgbImage;
use mode360_core::geometry::{Projection, Rig};
use mode360_synth::blockers::{
    block_image, lens_mask, parse_blocked_lens, BlockerError, MAX_BLOCKED_FRACTION,
};
use mode360_synth::camera_view::PixelRays;
use mode360_synth::noise::hash_words;
use mode360_synth::{BlockedLens, BlockerKind, SynthConfig, SynthRenderer};
use std::f64::consts::{FRAC_PI_2, PI};

const THIRD: f64 = 1.0 / 3.0;
const TOLERANCE: f64 = 0.03;

/// A noisy image (every pixel its own colour) to paint over.
fn noise_image(w: u32, h: u32, salt: u64) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let v = hash_words(&[u64::from(x), u64::from(y), salt]);
        image::Rgb([v as u8, (v >> 8) as u8, (v >> 16) as u8])
    })
}

/// The image with the pixels the lens does not see black, as the renderer leaves them.
fn with_unseen_black(mut img: RgbImage, seen: &[bool]) -> RgbImage {
    for (i, p) in img.pixels_mut().enumerate() {
        if !seen[i] {
            p.0 = [0, 0, 0];
        }
    }
    img
}

/// Paints `lens` over two different images and checks: the painted pixels are exactly the
/// mask's, their weighted share is within `TOLERANCE` of the target and equals the reported
/// fraction, every other byte is unchanged, and the paint does not depend on the image.
/// `weight(i)` is pixel `i`'s weight (0 where the lens sees nothing).
fn check_blocker(projection: &Projection, w: u32, h: u32, lens: &BlockedLens, weight: &[f64]) {
    let seen: Vec<bool> = weight.iter().map(|&x| x > 0.0).collect();
    let mask = lens_mask(lens, projection, w as usize, 42);
    assert_eq!(mask.mask.len(), (w * h) as usize);
    let mut painted = Vec::new();
    for salt in [1, 2] {
        let before = with_unseen_black(noise_image(w, h, salt), &seen);
        let mut img = before.clone();
        let reported = block_image(&mut img, projection, lens, 42);
        let (mut covered, mut total, mut changed_in_mask, mut in_mask) = (0.0, 0.0, 0, 0);
        for (i, (a, b)) in img.pixels().zip(before.pixels()).enumerate() {
            total += weight[i];
            if mask.mask[i] {
                assert!(
                    seen[i],
                    "{lens:?}: blocked pixel {i} is one the lens does not see"
                );
                covered += weight[i];
                in_mask += 1;
                changed_in_mask += usize::from(a != b);
            } else {
                assert_eq!(a.0, b.0, "{lens:?}: pixel {i} outside the blocker changed");
            }
        }
        let measured = covered / total;
        assert!(
            (measured - lens.fraction).abs() <= TOLERANCE,
            "{lens:?}: {measured} of the view blocked"
        );
        assert!(
            (reported - measured).abs() < 1e-12,
            "{reported} vs {measured}"
        );
        assert!((mask.fraction - measured).abs() < 1e-12);
        // Painted over (a noise pixel may rarely match the paint by chance).
        assert!(
            changed_in_mask as f64 >= 0.98 * in_mask as f64,
            "{changed_in_mask}/{in_mask}"
        );
        painted.push(
            img.pixels()
                .zip(&mask.mask)
                .filter(|(_, m)| **m)
                .map(|(p, _)| p.0)
                .collect::<Vec<_>>(),
        );
    }
    assert_eq!(
        painted[0], painted[1],
        "{lens:?}: the blocker is not opaque"
    );
}

#[test]
fn blockers_cover_a_third_of_a_panorama() {
    let (w, h) = (256u32, 128u32);
    let weight: Vec<f64> = (0..w * h)
        .map(|i| (FRAC_PI_2 - PI * ((i / w) as f64 + 0.5) / h as f64).cos())
        .collect();
    for kind in BlockerKind::ALL {
        for camera in 0..4 {
            let lens = BlockedLens {
                camera,
                fraction: THIRD,
                kind,
            };
            check_blocker(&Projection::Equirectangular, w, h, &lens, &weight);
        }
        // Small and large targets are met too.
        for fraction in [0.05, MAX_BLOCKED_FRACTION] {
            let lens = BlockedLens {
                camera: 1,
                fraction,
                kind,
            };
            let m = lens_mask(&lens, &Projection::Equirectangular, w as usize, 7);
            assert!(
                (m.fraction - fraction).abs() <= TOLERANCE,
                "{lens:?}: {}",
                m.fraction
            );
        }
    }
}

#[test]
fn blockers_cover_a_third_of_a_fisheye() {
    for file in [
        "launch_configs/rig_omnimvs.yaml",
        "launch_configs/rig_dual_fisheye.yaml",
    ] {
        let rig = Rig::from_file(repo_path(file)).unwrap();
        let rig = rig.scaled(0.5).unwrap();
        for camera in 0..2 {
            let projection = &rig.cameras[camera].projection;
            let rays = PixelRays::of_projection(projection).unwrap();
            let weight: Vec<f64> = rays
                .valid_mask()
                .iter()
                .map(|&s| f64::from(u8::from(s)))
                .collect();
            for kind in BlockerKind::ALL {
                let lens = BlockedLens {
                    camera,
                    fraction: THIRD,
                    kind,
                };
                check_blocker(
                    projection,
                    rays.width as u32,
                    rays.height as u32,
                    &lens,
                    &weight,
                );
            }
        }
    }
}

#[test]
fn renderer_blocks_one_camera_in_every_frame_and_reports_it() {
    let rig = deep360_rig();
    let lens = BlockedLens {
        camera: 2,
        fraction: THIRD,
        kind: BlockerKind::Mud,
    };
    let render = |blockers: Vec<BlockedLens>| {
        SynthRenderer::new(SynthConfig {
            seed: 11,
            width: 128,
            blockers,
            ..SynthConfig::default()
        })
        .unwrap()
    };
    let (clean, blocked) = (render(Vec::new()), render(vec![lens]));
    let expected = blocked.blocked_fractions(&rig);
    assert_eq!(expected[0], 0.0);
    assert!((expected[2] - THIRD).abs() <= TOLERANCE, "{expected:?}");
    let mask = lens_mask(&lens, &rig.cameras[2].projection, 128, 11);
    for index in [0, 5] {
        let (c, _) = clean.render_frame_with_report(&rig, index);
        let (b, report) = blocked.render_frame_with_report(&rig, index);
        assert_eq!(report.blocked, expected);
        assert_eq!(c.ground_truth.unwrap().data, b.ground_truth.unwrap().data);
        for cam in [0, 1, 3] {
            assert_eq!(c.images[cam], b.images[cam], "camera {cam}");
        }
        // Only the masked pixels change, and the same ones in every frame.
        for (i, (p, q)) in c.images[2].pixels().zip(b.images[2].pixels()).enumerate() {
            if !mask.mask[i] {
                assert_eq!(p, q, "frame {index}: pixel {i}");
            }
        }
    }
    let info = blocked.config().to_info();
    assert_eq!(
        info.get("blocked_lenses").map(String::as_str),
        Some(&*format!("3:{THIRD}:mud"))
    );
}

#[test]
fn blocked_lens_specs_parse_and_name_what_is_wrong() {
    let names = ["cam1", "cam2", "cam3", "cam4"];
    let ok = parse_blocked_lens("cam3:0.33:mount", &names).unwrap();
    assert_eq!(
        (ok.camera, ok.fraction, ok.kind),
        (2, 0.33, BlockerKind::Mount)
    );
    let ok = parse_blocked_lens("2:0.25", &names).unwrap();
    assert_eq!((ok.camera, ok.kind), (1, BlockerKind::Mud));
    let err = |spec: &str| parse_blocked_lens(spec, &names).unwrap_err().to_string();
    assert!(
        err("cam9:0.3").contains("camera 'cam9'"),
        "{}",
        err("cam9:0.3")
    );
    assert!(err("0:0.3").contains("camera '0'"));
    assert!(err("5:0.3").contains("1..=4"));
    assert!(err("3:abc").contains("fraction 'abc'"));
    assert!(err("3:0.9").contains("fraction 0.9"));
    assert!(err("3:0").contains("fraction 0"));
    assert!(err("3:0.3:dirt").contains("kind 'dirt'"));
    assert!(err("3").contains("CAM:FRACTION[:KIND]"));
    // A camera blocked twice is refused by the renderer's configuration.
    let twice = SynthRenderer::new(SynthConfig {
        blockers: vec![ok, ok],
        ..SynthConfig::default()
    });
    let msg = twice.err().map(|e| e.to_string()).unwrap_or_default();
    assert!(
        msg.contains("blockers") && msg.contains("camera 2"),
        "{msg}"
    );
    assert!(matches!(
        mode360_synth::blockers::validate_blockers(&[BlockedLens {
            fraction: 1.5,
            ..ok
        }]),
        Err(BlockerError::Fraction { .. })
    ));
}
