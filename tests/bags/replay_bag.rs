//! Offline replay: a small rendered bag through the node's pipeline into an output bag.

use crate::common::{TestResult, RIG_PATH};
use mode360::bag::{BagReader, RigBagReader, GROUND_TRUTH_TOPIC, TF_STATIC_TOPIC};
use mode360::cli::replay::{replay_bag, ReplayOptions};
use mode360::estimator::{EstimatorKind, EstimatorSpec};
use mode360::geometry::Rig;
use mode360::msgs::image::float_from_image_msg;
use mode360::msgs::{DiagnosticArray, Image, PointCloud2, TFMessage};
use mode360::node::diagnostics::diagnostic_value;
use mode360::node::pipeline::{decode_points, is_point_range};
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::SynthConfig;

const WIDTH: usize = 128;
const FRAMES: usize = 2;
const MAX_DEPTH_M: f64 = 1000.0;
/// Mean delta1 (%) of the photometric estimator on these 128x64 street frames: measured
/// 67.06% (seed 3, frames 0-1); the bound leaves a margin.
const MIN_DELTA1_PCT: f64 = 60.0;

#[test]
fn replay_writes_decodable_outputs_matching_inputs() -> TestResult {
    let dir = tempfile::tempdir()?;
    let input = dir.path().join("in.mcap");
    let output = dir.path().join("out.mcap");
    let rig = Rig::from_file(RIG_PATH)?;
    record_synthetic_bag(&RecordOptions {
        rig: rig.clone(),
        config: SynthConfig {
            seed: 3,
            width: WIDTH,
            max_depth_m: MAX_DEPTH_M,
            ..Default::default()
        },
        frames: FRAMES,
        first_frame: 0,
        out: input.clone(),
        show_progress: false,
    })?;
    let summary = replay_bag(&ReplayOptions {
        input: input.clone(),
        output: output.clone(),
        estimator: EstimatorSpec::new(EstimatorKind::Photometric),
        output_width: None,
        max_depth_m: None,
        max_frames: None,
        rig: None,
    })?;
    assert_eq!(summary.frames, FRAMES);
    let metrics = summary.metrics.ok_or("no metrics")?;
    println!(
        "replay {WIDTH}x{}: delta1 {:.2}% AbsRel {:.3}, mean latency {:.1} ms",
        WIDTH / 2,
        metrics.delta1_pct,
        metrics.abs_rel,
        summary.mean_latency_ms()
    );
    assert!(metrics.delta1_pct >= MIN_DELTA1_PCT, "{metrics:?}");

    // The output bag decodes; inputs are carried over.
    let inputs = RigBagReader::open(&input)?;
    let in_frames: Vec<_> = inputs.frames().collect::<Result<_, _>>()?;
    let out = BagReader::open(&output)?;
    out.check_complete()?;
    for cam in &rig.cameras {
        assert_eq!(out.decode_topic::<Image>(&cam.topic)?.len(), FRAMES);
    }
    assert_eq!(out.decode_topic::<Image>(GROUND_TRUTH_TOPIC)?.len(), FRAMES);
    let tf = out.decode_topic::<TFMessage>(TF_STATIC_TOPIC)?;
    assert_eq!(tf.len(), 1);
    assert!(tf[0].transforms.len() >= rig.cameras.len());
    let depth = out.decode_topic::<Image>("/depth")?;
    let points = out.decode_topic::<PointCloud2>("/points")?;
    let confidence = out.decode_topic::<Image>("/confidence")?;
    let diagnostics = out.decode_topic::<DiagnosticArray>("/diagnostics")?;
    assert_eq!(depth.len(), FRAMES);
    assert_eq!(points.len(), FRAMES);
    assert_eq!(confidence.len(), FRAMES);
    assert_eq!(diagnostics.len(), FRAMES);
    for (k, frame) in in_frames.iter().enumerate() {
        for msg in [&depth[k].header, &points[k].header, &confidence[k].header] {
            assert_eq!(msg.stamp.to_nanos(), frame.stamp_ns);
            assert_eq!(msg.frame_id, rig.output_frame_id);
        }
        let range = float_from_image_msg(&depth[k])?;
        assert_eq!((range.width, range.height), (WIDTH, WIDTH / 2));
        let valid = range
            .data
            .iter()
            .filter(|&&r| is_point_range(r, MAX_DEPTH_M as f32))
            .count();
        assert!(valid > 0);
        assert_eq!(points[k].width as usize, valid);
        assert_eq!(summary.point_counts[k], valid);
        let pts = decode_points(&points[k]).ok_or("unexpected point layout")?;
        assert_eq!(pts.len(), valid);
        // Every point's distance from the origin is a valid range of the depth image.
        let first_valid = range
            .data
            .iter()
            .copied()
            .find(|&r| is_point_range(r, MAX_DEPTH_M as f32))
            .ok_or("no valid pixel")?;
        let p = pts[0];
        let norm = (p.x_m * p.x_m + p.y_m * p.y_m + p.z_m * p.z_m).sqrt();
        assert!((norm - first_valid).abs() < 1e-3 * first_valid.max(1.0));
        let conf = float_from_image_msg(&confidence[k])?;
        assert!(conf
            .data
            .iter()
            .all(|c| (0.0..=1.0).contains(c) || c.is_nan()));
        assert_eq!(
            diagnostic_value(&diagnostics[k], "mode360: pipeline", "groups_processed"),
            Some((k + 1).to_string().as_str())
        );
    }
    // Deterministic: a second replay gives the same depth bytes.
    let output2 = dir.path().join("out2.mcap");
    replay_bag(&ReplayOptions {
        input,
        output: output2.clone(),
        estimator: EstimatorSpec::new(EstimatorKind::Photometric),
        output_width: None,
        max_depth_m: None,
        max_frames: Some(1),
        rig: None,
    })?;
    let depth2 = BagReader::open(&output2)?.decode_topic::<Image>("/depth")?;
    assert_eq!(depth2.len(), 1);
    assert_eq!(depth2[0].data, depth[0].data);
    check_compressed_depth(&output, FRAMES)?;
    Ok(())
}

/// A bag with malformed and mismatched camera messages among good frames, written message by
/// message: `replay` and `eval` drop what is bad, as the node does, process every good frame,
/// and report each drop with its file, topic, count and reason.
#[test]
fn malformed_messages_are_dropped_counted_and_every_good_frame_is_kept() -> TestResult {
    use mode360::bag::RigBagWriter;
    use mode360::cli::eval::{evaluate, EvalOptions, ViewMode};
    use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
    use mode360::msgs::image::image_msg_from_rgb;
    use mode360::msgs::Header;
    use mode360::synth::SynthRenderer;
    const GOOD_FRAMES: usize = 4;
    const SMALL_WIDTH: usize = 64;
    let dir = tempfile::tempdir()?;
    let input = dir.path().join("bad_messages.mcap");
    let rig = Rig::from_file(RIG_PATH)?;
    let renderer = SynthRenderer::new(SynthConfig {
        seed: 4,
        width: SMALL_WIDTH,
        max_depth_m: MAX_DEPTH_M,
        ..Default::default()
    })?;
    let frames: Vec<_> = (0..GOOD_FRAMES)
        .map(|k| renderer.render_frame(&rig, k))
        .collect();
    let mut writer = RigBagWriter::create(&input, &rig, &Default::default())?;
    for f in &frames {
        writer.write_frame(f)?;
    }
    let period_ns = frames[1].stamp_ns - frames[0].stamp_ns;
    let image = |frame: &mode360::frame::RigFrame, cam: usize, stamp_ns: u64| {
        image_msg_from_rgb(
            Header::new(stamp_ns, &rig.cameras[cam].frame_id),
            &frame.images[cam],
        )
    };
    let bag = writer.bag_mut();
    // 1. A frame whose camera 2 image is truncated (rgb8 with half its bytes).
    let truncated_ns = frames[GOOD_FRAMES - 1].stamp_ns + period_ns;
    for cam in 0..rig.cameras.len() {
        let mut msg = image(&frames[0], cam, truncated_ns);
        if cam == 2 {
            msg.data.truncate(msg.data.len() / 2);
        }
        bag.write(&rig.cameras[cam].topic, truncated_ns, &msg)?;
    }
    // 2. A stamp where camera 4 never sent its image.
    let incomplete_ns = truncated_ns + period_ns;
    for cam in 0..rig.cameras.len() - 1 {
        bag.write(
            &rig.cameras[cam].topic,
            incomplete_ns,
            &image(&frames[1], cam, incomplete_ns),
        )?;
    }
    // 3. Camera 1 sends a second image at the first good frame's stamp.
    bag.write(
        &rig.cameras[0].topic,
        frames[0].stamp_ns,
        &image(&frames[2], 0, frames[0].stamp_ns),
    )?;
    writer.finish()?;

    let summary = replay_bag(&ReplayOptions {
        input: input.clone(),
        output: dir.path().join("out.mcap"),
        estimator: EstimatorSpec::new(EstimatorKind::Photometric),
        output_width: None,
        max_depth_m: None,
        max_frames: None,
        rig: None,
    })?;
    assert_eq!(summary.frames, GOOD_FRAMES);
    let drops = summary.drops.counts();
    println!("{}", summary.drops.summary());
    assert_eq!(summary.drops.total(), 3, "{drops:?}");
    let on = |topic: &str, needle: &str| {
        drops
            .iter()
            .any(|d| d.topic == topic && d.reason.contains(needle) && d.count == 1)
    };
    assert!(on(&rig.cameras[2].topic, "bytes"), "{drops:?}");
    assert!(
        on(&rig.cameras[3].topic, "no image from camera"),
        "{drops:?}"
    );
    assert!(on(&rig.cameras[0].topic, "same stamp"), "{drops:?}");
    assert!(drops.iter().all(|d| d.file.ends_with("bad_messages.mcap")));
    // The kept image at the repeated stamp is the first one: replay's input copy has it.
    let replayed = RigBagReader::open(dir.path().join("out.mcap"))?;
    let first = replayed.frames().next().ok_or("no frames")??;
    assert_eq!(first.images[0], frames[0].images[0]);

    let mut sweep = PhotometricSweep::new(PhotometricConfig::default())?;
    let report = evaluate(
        &EvalOptions {
            bags: vec![input],
            cameras: None,
            max_frames: None,
            show_progress: false,
            png_dir: None,
            views: ViewMode::True,
            lens_masks: true,
        },
        &mut sweep,
    )?;
    assert_eq!(
        report.rows.iter().map(|r| r.frames).sum::<usize>(),
        GOOD_FRAMES
    );
    assert_eq!(report.drops, drops);
    assert!(
        report.to_table().contains("dropped 3"),
        "{}",
        report.to_table()
    );
    Ok(())
}

/// `/depth/compressedDepth` of a replayed bag: one message per frame, and an independent
/// Python decoder (tests/interop/check_compressed_depth.py: PNG and header from the format's
/// description) reads back every measurable `/depth` pixel within half a quantization step.
fn check_compressed_depth(output: &std::path::Path, frames: usize) -> TestResult {
    use mode360::msgs::compressed_depth::{quantization_params, DEFAULT_DEPTH_QUANTIZATION};
    use mode360::msgs::CompressedImage;
    let compressed =
        BagReader::open(output)?.decode_topic::<CompressedImage>("/depth/compressedDepth")?;
    assert_eq!(compressed.len(), frames);
    let Some(python) = crate::common::tool_from_env(
        crate::common::PYTHON_ENV,
        "the Python compressedDepth decoder",
        "set MODE360_PYTHON to a Python with mcap and mcap-ros2-support (tests/interop/setup.sh)",
    ) else {
        return Ok(());
    };
    let script = crate::common::repo_path("tests/interop/check_compressed_depth.py");
    let out = std::process::Command::new(python)
        .arg(script)
        .arg(output)
        .output()?;
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    println!("Python compressedDepth decoder: {report}");
    let (a, _) = quantization_params(DEFAULT_DEPTH_QUANTIZATION, MAX_DEPTH_M as f32);
    // Half a code: |dd| <= d^2 / (2 A), i.e. a relative error of at most max_depth / (2 A).
    let bound = MAX_DEPTH_M / (2.0 * f64::from(a)) * 1.01;
    assert_eq!(report["frames"], frames);
    assert_eq!(report["pixels"], frames * WIDTH * WIDTH / 2);
    assert_eq!(report["nan_where_invalid"], true);
    assert_eq!(report["format"], "32FC1; compressedDepth png");
    let max_rel = report["max_rel_err"].as_f64().ok_or("max_rel_err")?;
    assert!(max_rel <= bound, "relative error {max_rel} > {bound}");
    Ok(())
}

/// `replay --rig`: a bag replayed with a camera turned by 5° in the calibration (two pixels at this width) scores worse
/// than with its own calibration written to a file (which reproduces the bag's replay to the
/// byte), the output bag records the calibration used, and a file whose cameras differ from
/// the bag's is refused naming the camera.
#[test]
fn replay_with_another_rig_file() -> TestResult {
    let dir = tempfile::tempdir()?;
    let input = dir.path().join("in.mcap");
    let rig = Rig::from_file(RIG_PATH)?;
    record_synthetic_bag(&RecordOptions {
        rig: rig.clone(),
        config: SynthConfig {
            seed: 3,
            width: WIDTH,
            max_depth_m: MAX_DEPTH_M,
            ..Default::default()
        },
        frames: 1,
        first_frame: 0,
        out: input.clone(),
        show_progress: false,
    })?;
    let replay = |name: &str, rig_file: Option<std::path::PathBuf>| {
        let output = dir.path().join(name);
        let summary = replay_bag(&ReplayOptions {
            input: input.clone(),
            output: output.clone(),
            estimator: EstimatorSpec::new(EstimatorKind::Photometric),
            output_width: None,
            max_depth_m: None,
            max_frames: None,
            rig: rig_file,
        });
        (summary, output)
    };
    let (own, own_out) = replay("own.mcap", None);
    let own = own?;
    let same_file = dir.path().join("same.yaml");
    std::fs::write(&same_file, rig.to_yaml())?;
    let (same, same_out) = replay("same.mcap", Some(same_file));
    same?;
    let depth = |path: &std::path::Path| -> Result<Vec<u8>, Box<dyn std::error::Error>> {
        Ok(BagReader::open(path)?.decode_topic::<Image>("/depth")?[0]
            .data
            .clone())
    };
    assert_eq!(depth(&own_out)?, depth(&same_out)?);

    let mut knocked = rig.clone();
    let knock = nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 5f64.to_radians());
    knocked.cameras[1].rig_from_cam.rotation = knock * knocked.cameras[1].rig_from_cam.rotation;
    let knocked_file = dir.path().join("knocked.yaml");
    std::fs::write(&knocked_file, knocked.to_yaml())?;
    let (worse, worse_out) = replay("knocked.mcap", Some(knocked_file));
    let (own_d1, worse_d1) = (
        own.metrics.ok_or("no metrics")?.delta1_pct,
        worse?.metrics.ok_or("no metrics")?.delta1_pct,
    );
    assert!(
        worse_d1 < own_d1 - 1.0,
        "knocked {worse_d1:.2} % vs own {own_d1:.2} %"
    );
    let recorded = RigBagReader::open(&worse_out)?.rig().clone();
    let angle = recorded.cameras[1]
        .rig_from_cam
        .rotation
        .angle_to(&knocked.cameras[1].rig_from_cam.rotation);
    assert!(
        angle < 1e-9,
        "output bag's camera 2 is {angle} rad off the file's"
    );

    let renamed = dir.path().join("renamed.yaml");
    std::fs::write(&renamed, rig.to_yaml().replace("name: cam3", "name: cam9"))?;
    let (refused, _) = replay("renamed.mcap", Some(renamed.clone()));
    let e = format!(
        "{:#}",
        refused.err().ok_or("a renamed camera was accepted")?
    );
    assert!(
        e.contains("renamed.yaml") && e.contains("'cam9'") && e.contains("'cam3'"),
        "{e}"
    );
    Ok(())
}
