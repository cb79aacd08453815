//! Tests of the pipeline: REP 117, point clouds, sizes, missing cameras.

use super::*;
use mode360_core::geometry::PixelCoord;
use mode360_estimator::DepthEstimate;
use mode360_io::msgs::image::float_from_image_msg;

const RIG_YAML: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../launch_configs/rig_deep360.yaml"
);

/// A fake estimator: range grows with the row, the top rows are sky, one pixel NaN.
struct FakeEstimator {
    max_depth_m: f32,
}

impl DepthEstimator for FakeEstimator {
    fn name(&self) -> &str {
        "fake"
    }
    fn estimate(
        &mut self,
        _rig: &Rig,
        _images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        let (w, h) = (output.width(), output.height());
        let mut range = FloatImage::filled(w, h, 0.0);
        for v in 0..h {
            for u in 0..w {
                range.data[v * w + u] = if v < 2 {
                    self.max_depth_m
                } else {
                    1.0 + v as f32 + 0.01 * u as f32
                };
            }
        }
        range.data[3 * w + 5] = f32::NAN;
        Ok(DepthEstimate {
            confidence: FloatImage::filled(w, h, 0.5),
            range_m: range,
        })
    }
}

fn test_image(w: u32) -> RgbImage {
    RgbImage::from_fn(w, w / 2, |u, v| image::Rgb([u as u8, v as u8, 7]))
}

fn pipeline(width: usize) -> Pipeline {
    let rig = Rig::from_file(RIG_YAML).unwrap();
    let max_depth_m = 100.0;
    Pipeline::new(
        rig,
        Box::new(FakeEstimator { max_depth_m }),
        PipelineParams {
            output_width: width,
            max_depth_m,
            ..Default::default()
        },
    )
    .unwrap()
}

#[test]
fn points_are_valid_pixels_at_range_times_direction() {
    let width = 32;
    let mut p = pipeline(width);
    let n = p.rig().cameras.len();
    let group = (0..n).map(|_| Some(test_image(width as u32))).collect();
    let out = p.process(group, 1_234_567_890).unwrap();
    let range = float_from_image_msg(&out.depth).unwrap();
    let valid = range
        .data
        .iter()
        .filter(|&&r| is_point_range(r, p.params().max_depth_m))
        .count();
    // 16 rows, 2 of sky, one NaN pixel.
    assert_eq!(valid, width * (width / 2 - 2) - 1);
    let points = out.points.as_ref().unwrap();
    assert_eq!(points.width as usize, valid);
    assert_eq!(points.data.len(), valid * POINT_STEP_BYTES as usize);
    assert_eq!(out.depth.header.stamp.to_nanos(), 1_234_567_890);
    assert_eq!(points.header.frame_id, p.rig().output_frame_id);
    let pts = decode_points(out.points.as_ref().unwrap()).unwrap();
    // First point: pixel (0, 2).
    let grid = ErpGrid::new(width).unwrap();
    let dir = grid.dir_from_pixel(PixelCoord { u: 0.0, v: 2.0 });
    let rho = range.get(0, 2) as f64;
    assert!((pts[0].x_m as f64 - rho * dir.x).abs() < 1e-4);
    assert!((pts[0].y_m as f64 - rho * dir.y).abs() < 1e-4);
    assert!((pts[0].z_m as f64 - rho * dir.z).abs() < 1e-4);
    let conf = float_from_image_msg(&out.confidence).unwrap();
    assert!(conf.data.iter().all(|&c| c == 0.5));
}

#[test]
fn depth_follows_rep117_and_only_measurements_become_points() {
    let width = 32;
    let (w, h) = (width, width / 2);
    let mut p = pipeline(width);
    let n = p.rig().cameras.len();
    let group = || (0..n).map(|_| Some(test_image(width as u32))).collect();
    // Default: the two sky rows are +Inf, the invalid pixel NaN, the rest finite.
    let out = p.process(group(), 1).unwrap();
    let range = float_from_image_msg(&out.depth).unwrap();
    assert!(range.data[..2 * w].iter().all(|&r| r == f32::INFINITY));
    assert!(range.data[3 * w + 5].is_nan());
    let finite = range.data.iter().filter(|r| r.is_finite()).count();
    assert_eq!(finite, w * (h - 2) - 1);
    assert_eq!(out.points.as_ref().unwrap().width as usize, finite);
    // The older convention on request: the sky holds max_depth_m, still no point.
    p.params.far_value = FarValue::MaxDepth;
    let out = p.process(group(), 2).unwrap();
    let range = float_from_image_msg(&out.depth).unwrap();
    assert!(range.data[..2 * w].iter().all(|&r| r == 100.0));
    assert_eq!(out.points.as_ref().unwrap().width as usize, finite);
    // Confidence 0.5 everywhere: a threshold above it leaves no measurement and no point.
    p.params.min_confidence = 0.6;
    let out = p.process(group(), 3).unwrap();
    let range = float_from_image_msg(&out.depth).unwrap();
    assert!(range.data.iter().all(|r| r.is_nan()));
    assert_eq!(out.points.as_ref().unwrap().width, 0);
    // Not asked for, not built.
    let none = OutputRequest {
        points: false,
        compressed_depth: false,
    };
    let out = p.process_with(group(), 4, none).unwrap();
    assert!(out.points.is_none() && out.compressed_depth.is_none());
}

#[test]
fn colour_comes_from_reference_camera_pixel() {
    let width = 32;
    let mut p = pipeline(width);
    let n = p.rig().cameras.len();
    let group = (0..n).map(|_| Some(test_image(width as u32))).collect();
    let out = p.process(group, 0).unwrap();
    let pts = decode_points(out.points.as_ref().unwrap()).unwrap();
    let rig = p.rig().clone();
    let cam_from_output = rig.cam_from_output(rig.reference);
    let grid = ErpGrid::new(width).unwrap();
    for pt in pts.iter().step_by(37) {
        let p_cam = cam_from_output.transform_point(&nalgebra::Point3::new(
            pt.x_m as f64,
            pt.y_m as f64,
            pt.z_m as f64,
        ));
        let px = grid.pixel_from_dir(&p_cam.coords);
        let u = (px.u.round() as u32).min(width as u32 - 1);
        let v = (px.v.round() as u32).min(width as u32 / 2 - 1);
        assert_eq!(pt.rgb, [u as u8, v as u8, 7]);
    }
}

#[test]
fn rgb_packing_round_trips() {
    for (r, g, b) in [
        (0, 0, 0),
        (255, 0, 0),
        (1, 2, 3),
        (255, 255, 255),
        (12, 200, 99),
    ] {
        let packed = pack_rgb(r, g, b);
        assert_eq!(
            packed.to_bits(),
            (r as u32) << 16 | (g as u32) << 8 | b as u32
        );
        assert_eq!(unpack_rgb(packed), [r, g, b]);
    }
}

#[test]
fn missing_cameras_are_reported_and_too_few_rejected() {
    let width = 16;
    let mut p = pipeline(width);
    let n = p.rig().cameras.len();
    let mut group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
    group[1] = None;
    let out = p.process(group, 5).unwrap();
    assert_eq!(out.missing_cameras, vec![p.rig().cameras[1].name.clone()]);
    let mut few: Vec<Option<RgbImage>> = vec![None; n];
    few[0] = Some(test_image(width as u32));
    assert!(matches!(
        p.process(few, 5),
        Err(PipelineError::TooFewCameras { present: 1 })
    ));
    assert!(matches!(
        p.process(vec![None], 5),
        Err(PipelineError::GroupSize { got: 1, .. })
    ));
}

#[test]
fn mixed_image_sizes_name_every_camera() {
    let width = 16;
    let mut p = pipeline(width);
    let n = p.rig().cameras.len();
    let names: Vec<String> = p.rig().cameras.iter().map(|c| c.name.clone()).collect();
    // Two sizes, two cameras each: which is wrong is not knowable, the error names all.
    let mut group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
    group[0] = Some(test_image(8));
    group[1] = Some(test_image(8));
    let err = p.process(group, 5).err().map(|e| e.to_string());
    let expected = format!(
        "the cameras' images do not fit their cameras ({} 8x4, {} 8x4, {} 16x8, {} 16x8): \
         panoramas must share one 2:1 size, fisheye images must be their image_size",
        names[0], names[1], names[2], names[3]
    );
    assert_eq!(err, Some(expected));
}

#[test]
fn a_camera_of_another_size_is_left_out_and_the_rest_go_on() {
    let width = 16;
    let mut p = pipeline(width);
    let n = p.rig().cameras.len();
    let names: Vec<String> = p.rig().cameras.iter().map(|c| c.name.clone()).collect();
    // The odd one is the first camera: it alone is left out.
    let mut group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
    group[0] = Some(test_image(8));
    let out = p.process(group, 5).unwrap();
    assert_eq!(out.missing_cameras, vec![names[0].clone()]);
    assert_eq!(out.depth.width as usize, width);
    // A panorama that is not 2:1 is left out too; with it back to size, nobody is missing.
    let mut group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
    group[2] = Some(RgbImage::new(width as u32, width as u32));
    assert_eq!(
        p.process(group, 6).unwrap().missing_cameras,
        vec![names[2].clone()]
    );
    let group: Vec<_> = (0..n).map(|_| Some(test_image(width as u32))).collect();
    assert!(p.process(group, 7).unwrap().missing_cameras.is_empty());
    // Too few left: the error names every camera's size.
    let mut group: Vec<_> = (0..n).map(|_| Some(test_image(8))).collect();
    group[0] = Some(test_image(width as u32));
    group[1] = None;
    group[2] = None;
    assert!(p.process(group, 8).is_err());
}

#[test]
fn fisheye_points_take_colour_from_a_camera_that_sees_them() {
    let rig = Rig::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_omnimvs.yaml"
    ))
    .and_then(|r| r.scaled(0.125))
    .unwrap();
    let max_depth_m = 100.0;
    let params = PipelineParams {
        output_width: 32,
        max_depth_m,
        ..PipelineParams::default()
    };
    let estimator = Box::new(FakeEstimator { max_depth_m });
    let mut p = Pipeline::new(rig.clone(), estimator, params).unwrap();
    // Camera k's image is one flat colour; corners outside the lens stay black.
    let colour = |k: usize| [40 + 50 * k as u8, 7, 9];
    let group = || {
        (0..4)
            .map(|k| Some(RgbImage::from_pixel(48, 48, image::Rgb(colour(k)))))
            .collect::<Vec<_>>()
    };
    let out = p.process(group(), 0).unwrap();
    let pts = decode_points(out.points.as_ref().unwrap()).unwrap();
    assert_eq!(pts.len(), 32 * 14 - 1);
    let mut by_camera = [0usize; 4];
    for pt in &pts {
        let k = (0..4)
            .find(|&k| colour(k) == pt.rgb)
            .expect("a camera's colour");
        by_camera[k] += 1;
        // The reference (front-left, yaw +45°) colours all it sees.
        let p_out = nalgebra::Vector3::new(pt.x_m as f64, pt.y_m as f64, pt.z_m as f64);
        let p_cam = rig.cam_from_output(0).transform_point(&p_out.into()).coords;
        let seen = rig.cameras[0]
            .projection
            .fisheye_model()
            .unwrap()
            .project(&p_cam);
        assert_eq!(seen.is_some(), k == 0, "{p_out:?} coloured by camera {k}");
    }
    assert!(by_camera[0] > pts.len() / 3, "{by_camera:?}");
    // Then the next cameras in rig order: front-right and rear-left cover the rest.
    assert!(by_camera[1] > 0 && by_camera[2] > 0, "{by_camera:?}");
    // A fisheye image at the wrong size leaves that camera out; three such, and the error
    // names them.
    let mut bad = group();
    bad[2] = Some(RgbImage::new(64, 32));
    let out = p.process(bad, 1).unwrap();
    assert_eq!(out.missing_cameras, vec!["rear_left".to_string()]);
    let mut bad = group();
    for slot in bad.iter_mut().skip(1) {
        *slot = Some(RgbImage::new(64, 32));
    }
    let err = p.process(bad, 2).err().map(|e| e.to_string());
    assert!(
        err.as_deref()
            .is_some_and(|e| e.contains("rear_left 64x32")),
        "{err:?}"
    );
}

#[test]
fn rig_health_checks_off_skip_the_lens_and_drift_checks() {
    // Wide enough for the drift check (it skips images narrower than 256).
    let width = 256;
    let group = |p: &Pipeline| -> Vec<Option<RgbImage>> {
        (0..p.rig().cameras.len())
            .map(|_| Some(test_image(width as u32)))
            .collect()
    };
    let mut on = pipeline(width);
    let n = on.rig().cameras.len();
    let checked = on.process(group(&on), 5).unwrap();
    assert_eq!(checked.lens.len(), n, "one lens health per camera");
    assert_eq!(checked.calibration.len(), n, "one drift figure per camera");

    let mut off = pipeline(width);
    off.set_params(PipelineParams {
        rig_health_checks: false,
        ..off.params().clone()
    });
    let unchecked = off.process(group(&off), 5).unwrap();
    assert!(unchecked.lens.is_empty() && unchecked.calibration.is_empty());
    assert_eq!(unchecked.missing_cameras, Vec::<String>::new());
    assert_eq!(
        float_from_image_msg(&unchecked.depth).unwrap().data.len(),
        width * width / 2
    );
}

/// The live node's deferred checks (after publishing) give the same messages as checking at
/// once, and the same lens health and drift once they have run; before that the output
/// carries the previous group's.
#[test]
fn deferred_checks_match_checks_at_once() {
    let width = 256;
    // Camera k: a texture of its own that changes per group; camera 3's lower half flat grey.
    let group = |p: &Pipeline, g: u32| -> Vec<Option<RgbImage>> {
        (0..p.rig().cameras.len() as u32)
            .map(|k| {
                Some(RgbImage::from_fn(width as u32, width as u32 / 2, |u, v| {
                    if k == 2 && v > width as u32 / 4 {
                        return image::Rgb([128, 128, 128]);
                    }
                    let t = (u * 7 + v * 13 + k * 31 + g * 17) % 251;
                    image::Rgb([t as u8, (t * 3 % 256) as u8, (u ^ v) as u8])
                }))
            })
            .collect()
    };
    let mut at_once = pipeline(width);
    let mut deferred = pipeline(width);
    let mut previous: Option<(Vec<LensHealth>, Vec<CalibrationDrift>)> = None;
    for g in 0..4 {
        let a = at_once
            .process(group(&at_once, g), 10 + u64::from(g))
            .unwrap();
        let d = deferred
            .process_deferred(group(&deferred, g), 10 + u64::from(g), OutputRequest::ALL)
            .unwrap();
        assert_eq!(a.depth.data, d.depth.data, "group {g}: depth");
        assert_eq!(
            a.points.as_ref().map(|p| &p.data),
            d.points.as_ref().map(|p| &p.data),
            "group {g}: points"
        );
        match &previous {
            // the first group is checked at once in both
            None => assert_eq!((&a.lens, &a.calibration), (&d.lens, &d.calibration)),
            Some((lens, calibration)) => {
                assert_eq!((&d.lens, &d.calibration), (lens, calibration), "group {g}")
            }
        }
        deferred.run_deferred_checks().unwrap();
        assert_eq!(deferred.lens_health(), a.lens, "group {g}: lens health");
        assert_eq!(
            deferred.calibration_drift(),
            a.calibration,
            "group {g}: drift"
        );
        assert_eq!(a.lens.len(), at_once.rig().cameras.len());
        if let Some((lens, _)) = &previous {
            // each group's votes move the health, so a stale figure would show
            assert_ne!(&a.lens, lens, "group {g}: the health moved");
        }
        previous = Some((a.lens.clone(), a.calibration.clone()));
    }
    // nothing pending: a second run is a no-op
    deferred.run_deferred_checks().unwrap();
    assert_eq!(deferred.lens_health(), previous.unwrap().0);
}
