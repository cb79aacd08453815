//! Ground-truth labels and the obstacle metrics end to end: the renderer's classes and
//! instances agree with its range, survive a bag (as documented bytes) and replay, and
//! `eval` scores obstacles with labels and reports n/a without them.

use crate::common::{TestResult, RIG_PATH};
use mode360::bag::{
    BagReader, RigBagReader, GROUND_TRUTH_CLASSES_TOPIC, GROUND_TRUTH_INSTANCES_TOPIC,
};
use mode360::cli::eval::{evaluate, EvalOptions};
use mode360::cli::replay::{replay_bag, ReplayOptions};
use mode360::estimator::{EstimatorKind, EstimatorSpec};
use mode360::frame::{SurfaceClass, NO_INSTANCE};
use mode360::geometry::Rig;
use mode360::msgs::Image;
use mode360::obstacles::{frame_obstacles, ObstacleCounts};
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::{StreetStyle, SynthConfig, SynthRenderer};
use std::collections::BTreeSet;
use std::path::Path;

const MAX_DEPTH_M: f64 = 1000.0;

fn cluttered(width: usize) -> SynthConfig {
    SynthConfig {
        seed: 11,
        width,
        max_depth_m: MAX_DEPTH_M,
        street: StreetStyle::Cluttered,
        ..Default::default()
    }
}

#[test]
fn cluttered_street_labels_agree_with_the_range() -> TestResult {
    let rig = Rig::from_file(RIG_PATH)?;
    let renderer = SynthRenderer::new(cluttered(256))?;
    let frame = renderer.render_frame(&rig, 3);
    let gt = frame.ground_truth.as_ref().ok_or("no ground truth")?;
    let labels = frame.labels.as_ref().ok_or("no labels")?;
    assert!(labels.is_consistent());
    assert_eq!((labels.width, labels.height), (gt.width, gt.height));
    let mut instances = BTreeSet::new();
    for ((&class, &id), &g) in labels.class.iter().zip(&labels.instance).zip(&gt.data) {
        // Sky exactly where nothing is within range.
        assert_eq!(
            class == SurfaceClass::Sky,
            f64::from(g) >= MAX_DEPTH_M,
            "{class:?} at {g} m"
        );
        // Instances exactly on objects.
        assert_eq!(class == SurfaceClass::Object, id != NO_INSTANCE);
        if id != NO_INSTANCE {
            instances.insert(id);
        }
    }
    let count = |c| labels.class.iter().filter(|&&x| x == c).count();
    assert!(count(SurfaceClass::Ground) > gt.data.len() / 5);
    assert!(count(SurfaceClass::Structure) > 0);
    assert!(instances.len() >= 10, "{} instances", instances.len());
    // A perfect estimate recovers every counted obstacle, with clutter near the rig.
    let perfect = frame_obstacles(&gt.data, &gt.data, labels, MAX_DEPTH_M)?;
    let c = ObstacleCounts::of_frame(&perfect);
    assert!(c.within_5m().total >= 2, "{c:?}");
    assert_eq!(c.within_10m().hits, c.within_10m().total);
    assert_eq!(c.phantom.hits, 0);
    assert_eq!(c.near_object_delta1.pct(), Some(100.0));
    // Melting every object into the sky loses them all and makes their pixels phantoms.
    let melted: Vec<f32> = gt
        .data
        .iter()
        .zip(&labels.class)
        .map(|(&g, &class)| match class {
            SurfaceClass::Object => f32::INFINITY,
            _ => g,
        })
        .collect();
    let m = ObstacleCounts::of_frame(&frame_obstacles(&melted, &gt.data, labels, MAX_DEPTH_M)?);
    assert_eq!(m.within_10m().hits, 0);
    assert_eq!(m.within_10m().total, c.within_10m().total);
    let objects_within_50m = labels
        .class
        .iter()
        .zip(&gt.data)
        .filter(|(&class, &g)| class == SurfaceClass::Object && f64::from(g) <= 50.0)
        .count() as u64;
    assert_eq!(m.phantom.hits, objects_within_50m);
    assert_eq!(m.phantom_out_of_range.hits, objects_within_50m);
    Ok(())
}

fn record(path: &Path, config: SynthConfig) -> TestResult {
    record_synthetic_bag(&RecordOptions {
        rig: Rig::from_file(RIG_PATH)?,
        config,
        frames: 2,
        first_frame: 0,
        out: path.to_path_buf(),
        show_progress: false,
    })?;
    Ok(())
}

#[test]
fn labels_survive_the_bag_and_replay_scores_obstacles() -> TestResult {
    let dir = tempfile::tempdir()?;
    let input = dir.path().join("in.mcap");
    record(&input, cluttered(128))?;
    // The documented bytes: classes one byte a pixel, instances little-endian u16.
    let rig = Rig::from_file(RIG_PATH)?;
    let rendered = SynthRenderer::new(cluttered(128))?.render_frame(&rig, 0);
    let labels = rendered.labels.ok_or("no labels")?;
    let raw = BagReader::open(&input)?;
    let classes: Vec<Image> = raw.decode_topic(GROUND_TRUTH_CLASSES_TOPIC)?;
    let instances: Vec<Image> = raw.decode_topic(GROUND_TRUTH_INSTANCES_TOPIC)?;
    assert_eq!((classes.len(), instances.len()), (2, 2));
    assert_eq!(
        (classes[0].encoding.as_str(), instances[0].encoding.as_str()),
        ("8UC1", "16UC1")
    );
    let class_bytes: Vec<u8> = labels.class.iter().map(|c| *c as u8).collect();
    assert_eq!(classes[0].data, class_bytes);
    let ids: Vec<u16> = instances[0]
        .data
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    assert_eq!(ids, labels.instance);
    // The reader gives them back with the frame.
    let reader = RigBagReader::open(&input)?;
    let first = reader.frames().next().ok_or("no frame")??;
    assert_eq!(first.labels.as_ref(), Some(&labels));
    // Replay carries them into its output and scores obstacles.
    let output = dir.path().join("out.mcap");
    let summary = replay_bag(&ReplayOptions {
        input: input.clone(),
        output: output.clone(),
        estimator: EstimatorSpec::new(EstimatorKind::Photometric),
        output_width: None,
        max_depth_m: None,
        max_frames: None,
        rig: None,
    })?;
    let report = summary.obstacles.ok_or("replay reported no obstacles")?;
    assert_eq!(report.frames, 2);
    let counted: u64 = report.bands.iter().map(|b| b.instances).sum();
    assert!(counted >= 2, "{report:?}");
    let replayed = RigBagReader::open(&output)?;
    let out_first = replayed.frames().next().ok_or("no frame")??;
    assert_eq!(out_first.labels.as_ref(), Some(&labels));
    Ok(())
}

#[test]
fn eval_reports_obstacles_with_labels_and_na_without() -> TestResult {
    let dir = tempfile::tempdir()?;
    let labelled = dir.path().join("labelled.mcap");
    record(&labelled, cluttered(128))?;
    // The same frames without label topics (an older or recorded bag).
    let unlabelled = dir.path().join("unlabelled.mcap");
    {
        let reader = RigBagReader::open(&labelled)?;
        let mut writer =
            mode360::bag::RigBagWriter::create(&unlabelled, reader.rig(), &reader.info())?;
        for frame in reader.frames() {
            let mut frame = frame?;
            frame.labels = None;
            writer.write_frame(&frame)?;
        }
        writer.finish()?;
    }
    let mut sweep = EstimatorSpec::new(EstimatorKind::Photometric).build()?;
    let opts = |bag: &Path| EvalOptions {
        bags: vec![bag.to_path_buf()],
        show_progress: false,
        ..Default::default()
    };
    let with = evaluate(&opts(&labelled), sweep.as_mut())?;
    let o = with.rows[0].obstacles.as_ref().ok_or("no obstacles row")?;
    assert_eq!(o.frames, 2);
    assert!(o.bands.iter().map(|b| b.instances).sum::<u64>() >= 2);
    let table = with.to_table();
    assert!(
        table.contains("| clean | ") && table.contains("recall 0-2 m"),
        "{table}"
    );
    let without = evaluate(&opts(&unlabelled), sweep.as_mut())?;
    assert!(without.rows[0].obstacles.is_none());
    // Same depth, and the obstacle cells say n/a rather than zero.
    assert_eq!(
        without.rows[0].depth.delta1_pct,
        with.rows[0].depth.delta1_pct
    );
    let table = without.to_table();
    assert!(table.contains("| clean | n/a | n/a |"), "{table}");
    let json = serde_json::to_value(&without)?;
    assert!(json["rows"][0]["obstacles"].is_null());
    Ok(())
}
