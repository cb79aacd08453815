//! PSMODE (issue 41): the fusion network's training (fits, resumes exactly), the estimator with
//! and without it, and the stages' weights files refused where the other is expected.

use crate::common::{deep360_rig, TestResult};
use mode360::estimator::psmode::{
    PairChoice, PsmodeEstimator, DEFAULT_PAIR_WIDTH, TRAINED_PAIR_WIDTH,
};
use mode360::estimator::ssmode::{default_weights_path, SsmodeEstimator};
use mode360::estimator::{DepthEstimator, EstimatorKind, EstimatorSpec};
use mode360::geometry::ErpGrid;
use mode360::model::{ComputeDevice, FusionConfig};
use mode360::synth::{SynthConfig, SynthRenderer};
use mode360::train::data::{DataConfig, SceneMix, StreamOptions};
use mode360::train::fusion::{run_fusion_training, FusionTrainOptions, FUSION_WEIGHTS_FILE};
use std::path::{Path, PathBuf};

/// The test network: 32 wide.
fn tiny() -> FusionConfig {
    FusionConfig::tiny()
}

fn options(out: &Path, steps: usize, until: Option<usize>) -> FusionTrainOptions {
    let config = tiny();
    FusionTrainOptions {
        out_dir: out.to_path_buf(),
        stage1_weights: default_weights_path(),
        pair_width: 0,
        samples: 2,
        steps,
        until_step: until,
        lr: 3e-3,
        warmup_steps: 1,
        val_samples: 1,
        val_every: steps,
        checkpoint_every: 10,
        resume: true,
        data: DataConfig {
            stream: StreamOptions {
                seed: 3,
                soiled_fraction: 0.0,
                deep360_fraction: 0.0,
                camera_effects: false,
                mix: SceneMix::default(),
            },
            width: config.width,
            max_depth_m: config.max_depth_m,
            deep360_disk: None,
        },
        config,
        loss: Default::default(),
        show_progress: false,
    }
}

fn losses(csv: &Path) -> Vec<f64> {
    std::fs::read_to_string(csv)
        .unwrap_or_default()
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').nth(1)?.parse().ok())
        .collect()
}

/// Trained on two samples, the fusion network fits them (its loss falls from the most
/// confident pair's), and a run stopped at step 10 and resumed ends with the same weights as a
/// straight one. Bit-exact needs a fixed reduction order, so it runs in a one-thread pool (as
/// SSMODE's resume test does).
#[test]
fn fusion_training_fits_its_samples_and_resumes_exactly() -> TestResult {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()?
        .install(|| fits_and_resumes().map_err(|e| e.to_string()))?;
    Ok(())
}

fn fits_and_resumes() -> TestResult {
    const STEPS: usize = 30;
    let dir = tempfile::tempdir()?;
    let (straight, resumed) = (dir.path().join("straight"), dir.path().join("resumed"));
    let a = run_fusion_training(&options(&straight, STEPS, None))?;
    assert_eq!((a.start_step, a.final_step), (0, STEPS));
    let (fused, pair) = a.last_val_delta1_pct.ok_or("no validation")?;
    println!("held-out δ1: fused {fused:.2} %, most confident pair {pair:.2} %");
    let l = losses(&straight.join("train.csv"));
    assert_eq!(l.len(), STEPS);
    // steps 1-2 see both samples with the untrained (most-confident-pair) network
    let (first, last) = ((l[0] + l[1]) / 2.0, (l[STEPS - 2] + l[STEPS - 1]) / 2.0);
    println!("loss: first epoch {first:.4}, last epoch {last:.4}");
    assert!(last < 0.8 * first, "loss {first} -> {last}");

    // stage 1's cache is the straight run's (the same samples), so the resumed run renders none
    std::fs::create_dir_all(&resumed)?;
    let cache = straight.join("stage1_cache");
    std::fs::create_dir_all(resumed.join("stage1_cache"))?;
    for entry in std::fs::read_dir(&cache)? {
        let entry = entry?;
        std::fs::copy(
            entry.path(),
            resumed.join("stage1_cache").join(entry.file_name()),
        )?;
    }
    let b1 = run_fusion_training(&options(&resumed, STEPS, Some(10)))?;
    assert_eq!(b1.final_step, 10);
    let b2 = run_fusion_training(&options(&resumed, STEPS, None))?;
    assert_eq!((b2.start_step, b2.final_step), (10, STEPS));
    let load = |p: &Path| candle_core::safetensors::load(p, &candle_core::Device::Cpu);
    let (wa, wb) = (
        load(&straight.join(FUSION_WEIGHTS_FILE))?,
        load(&resumed.join(FUSION_WEIGHTS_FILE))?,
    );
    assert_eq!(wa.len(), wb.len());
    for (name, t) in &wa {
        let u = &wb[name];
        let diff = (t - u)?.abs()?.max_all()?.to_scalar::<f32>()?;
        assert!(diff == 0.0, "{name}: resumed differs by {diff}");
    }
    // a run with other data options refuses the checkpoint, naming it
    let mut other = options(&resumed, STEPS + 5, None);
    other.samples = 3;
    let e = run_fusion_training(&other)
        .err()
        .ok_or("mismatched resume accepted")?;
    assert!(e.to_string().contains("another run"), "{e}");
    Ok(())
}

/// The untrained fusion network returns the most confident pair, so PSMODE with it equals
/// PSMODE without it on the same frame (the wiring from stage 1 to the fusion's tensors and
/// back to ranges is exact); its output is a real estimate (δ1 against the ground truth).
#[test]
fn psmode_with_an_untrained_fusion_equals_the_most_confident_pair() -> TestResult {
    let dir = tempfile::tempdir()?;
    let out = dir.path().join("run");
    run_fusion_training(&FusionTrainOptions {
        lr: 0.0,
        val_samples: 0,
        samples: 1,
        ..options(&out, 1, None)
    })?;
    let rig = deep360_rig();
    let frame = SynthRenderer::new(SynthConfig {
        seed: 21,
        width: 256,
        ..SynthConfig::default()
    })?
    .render_frame(&rig, 0);
    let grid = ErpGrid::new(tiny().width)?;
    let with = PsmodeEstimator::load_on(
        default_weights_path(),
        Some(&out.join(FUSION_WEIGHTS_FILE)),
        ComputeDevice::Cpu,
        PairChoice::All,
        DEFAULT_PAIR_WIDTH,
    )?
    .estimate(&rig, &frame.images, grid)?;
    let without = PsmodeEstimator::load_on(
        default_weights_path(),
        None,
        ComputeDevice::Cpu,
        PairChoice::All,
        DEFAULT_PAIR_WIDTH,
    )?
    .estimate(&rig, &frame.images, grid)?;
    let mut worst = 0.0f32;
    for (a, b) in with.range_m.data.iter().zip(&without.range_m.data) {
        worst = worst.max((a - b).abs() / b.max(0.5));
    }
    assert!(worst < 2e-3, "relative difference {worst}");
    Ok(())
}

/// An untrained select head is a soft consensus: each pixel a blend of the pairs' aligned ranges
/// (never outside them), weighted by how close each pair is to the pairs' consensus, so PSMODE
/// with it reads what the consensus reads on nearly every pixel (the wiring from stage 1
/// through the pair weights back to ranges holds). Trained on a stream rendered twice as wide
/// as its grid (stage 1's `pair_width`), its loss falls on its two samples.
#[test]
fn psmode_with_a_select_fusion_blends_the_pairs() -> TestResult {
    use mode360::model::FusionHead;
    let dir = tempfile::tempdir()?;
    let select = |out: &Path, steps: usize, lr: f64| {
        let mut o = options(out, steps, None);
        o.config = FusionConfig {
            head: FusionHead::Select,
            ..tiny()
        };
        o.pair_width = 2 * o.config.width;
        o.data.width = o.render_width();
        o.lr = lr;
        o.val_samples = 0;
        o
    };
    let fixed = dir.path().join("fixed");
    run_fusion_training(&select(&fixed, 1, 0.0))?;
    let rig = deep360_rig();
    let frame = SynthRenderer::new(SynthConfig {
        seed: 21,
        width: 256,
        ..SynthConfig::default()
    })?
    .render_frame(&rig, 0);
    let grid = ErpGrid::new(tiny().width)?;
    let load = |fusion: Option<&Path>| {
        PsmodeEstimator::load_on(
            default_weights_path(),
            fusion,
            ComputeDevice::Cpu,
            PairChoice::All,
            DEFAULT_PAIR_WIDTH,
        )
    };
    let with = load(Some(&fixed.join(FUSION_WEIGHTS_FILE)))?.estimate(&rig, &frame.images, grid)?;
    let consensus = load(Some(Path::new(
        mode360::estimator::psmode::CONSENSUS_FUSION,
    )))?
    .estimate(&rig, &frame.images, grid)?;
    let pairs = load(None)?.pairwise(&rig, &frame.images, grid)?;
    assert_eq!(pairs.aligned.len(), 6);
    let cap = |r: f32| r.min(1000.0);
    let (mut agree, mut outside) = (0usize, 0usize);
    for (k, (&r, &c)) in with
        .range_m
        .data
        .iter()
        .zip(&consensus.range_m.data)
        .enumerate()
    {
        let ranges: Vec<f32> = pairs
            .aligned
            .iter()
            .map(|a| a.range_m[k])
            .filter(|r| !r.is_nan() && *r > 0.0)
            .map(cap)
            .collect();
        if ranges.is_empty() {
            assert!(r.is_nan(), "pixel {k}: {r} where no pair has a range");
            continue;
        }
        let lo = ranges.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = ranges.iter().copied().fold(0.0f32, f32::max);
        if cap(r) < lo * 0.999 || cap(r) > hi * 1.001 {
            outside += 1;
        }
        if (cap(r) / cap(c)).max(cap(c) / cap(r)) < 1.25 {
            agree += 1;
        }
    }
    assert_eq!(outside, 0, "pixels outside the pairs' ranges");
    let share = agree as f64 / grid.len() as f64;
    println!(
        "untrained select head: within δ1 of the consensus on {:.1} %",
        100.0 * share
    );
    assert!(share > 0.9, "{share}");

    let trained = dir.path().join("trained");
    run_fusion_training(&select(&trained, 30, 3e-3))?;
    let l = losses(&trained.join("train.csv"));
    let (first, last) = ((l[0] + l[1]) / 2.0, (l[28] + l[29]) / 2.0);
    println!("select head loss: first epoch {first:.4}, last epoch {last:.4}");
    // it can only choose among the pairs (no correction), so it falls less than the
    // correction head's on the same samples
    assert!(last < 0.98 * first, "loss {first} -> {last}");
    // a cache written for one head is refused by the other, naming what is missing
    let mut other = options(&trained, 31, None);
    other.resume = false;
    other.pair_width = 2 * other.config.width;
    other.data.width = other.render_width();
    let e = run_fusion_training(&other)
        .err()
        .ok_or("cache of the other head")?;
    assert!(e.to_string().contains("'base'"), "{e}");
    Ok(())
}

/// Each stage's weights file is refused where the other stage's is expected, naming the file
/// and what it holds; fusion weights given to another estimator are an error.
#[test]
fn a_stages_weights_are_refused_where_the_other_is_expected() -> TestResult {
    let dir = tempfile::tempdir()?;
    let out = dir.path().join("run");
    run_fusion_training(&FusionTrainOptions {
        lr: 0.0,
        val_samples: 0,
        samples: 1,
        ..options(&out, 1, None)
    })?;
    let fusion = out.join(FUSION_WEIGHTS_FILE);
    let e = SsmodeEstimator::load(&fusion)
        .err()
        .ok_or("fusion as SSMODE")?
        .to_string();
    assert!(
        e.contains("fusion network (stage 2)") && e.contains(&fusion.display().to_string()),
        "{e}"
    );
    let shipped = default_weights_path();
    let e = PsmodeEstimator::load_on(
        &shipped,
        Some(&shipped),
        ComputeDevice::Cpu,
        PairChoice::All,
        DEFAULT_PAIR_WIDTH,
    )
    .err()
    .ok_or("stage 1 as fusion")?
    .to_string();
    assert!(
        e.contains("stage-1") && e.contains("not PSMODE's fusion"),
        "{e}"
    );
    let e = EstimatorSpec {
        fusion_weights: Some(fusion.clone()),
        ..EstimatorSpec::new(EstimatorKind::Ssmode)
    }
    .build()
    .err()
    .ok_or("fusion weights for SSMODE")?
    .to_string();
    assert!(e.contains("only PSMODE"), "{e}");
    // the shipped fusion network is found (or unpacked from the binary); `none` is no network
    // (the most confident pair), unset the pairs' consensus
    use mode360::estimator::psmode::{
        fusion_weights_path, CONSENSUS_FUSION, DEFAULT_FUSION_WEIGHTS_PATH, NO_FUSION,
    };
    let shipped = fusion_weights_path(Some(Path::new(DEFAULT_FUSION_WEIGHTS_PATH)))
        .ok_or("no shipped fusion")?;
    let (cfg, _) = mode360::model::load_fusion_weights(&shipped, &candle_core::Device::Cpu)?;
    // either head: the shipped file is the `small` network or its `select` variant
    let preset = match cfg.head {
        mode360::model::FusionHead::Correction => FusionConfig::small(),
        mode360::model::FusionHead::Select => FusionConfig::select(),
    };
    assert_eq!(cfg, preset);
    assert_eq!(fusion_weights_path(Some(Path::new(NO_FUSION))), None);
    let consensus = Some(PathBuf::from(CONSENSUS_FUSION));
    assert_eq!(fusion_weights_path(None), consensus);
    assert_eq!(
        fusion_weights_path(Some(Path::new(CONSENSUS_FUSION))),
        consensus
    );
    Ok(())
}

/// Pairs that name a camera the rig does not have are refused, naming it and the rig's cameras.
#[test]
fn pairs_naming_an_unknown_camera_are_refused() -> TestResult {
    let rig = deep360_rig();
    let images = SynthRenderer::new(SynthConfig {
        seed: 1,
        width: 64,
        ..SynthConfig::default()
    })?
    .render_frame(&rig, 0)
    .images;
    let mut est = PsmodeEstimator::load_on(
        default_weights_path(),
        None,
        ComputeDevice::Cpu,
        PairChoice::parse("cam1-bumper")?,
        DEFAULT_PAIR_WIDTH,
    )?;
    let e = est
        .estimate(&rig, &images, ErpGrid::new(64)?)
        .err()
        .ok_or("unknown camera accepted")?
        .to_string();
    assert!(e.contains("'bumper'") && e.contains("cam1, cam2"), "{e}");
    Ok(())
}

/// `rig pair` writes a pair as stage 1 sees it: two 360° cameras in the pair's GEER frame, the
/// depth frame the left camera's, so that `synth` and `eval` score stage 1 on its own.
#[test]
fn rig_pair_writes_the_pair_in_its_geer_frame() -> TestResult {
    use mode360::cli::rig::{run_pair, RigPairArgs};
    use mode360::geometry::{CameraPair, PairView, Rig};
    let dir = tempfile::tempdir()?;
    let out = dir.path().join("pair.yaml");
    run_pair(RigPairArgs {
        rig: crate::common::repo_path(crate::common::DEEP360_RIG),
        pair: "cam2-cam4".into(),
        out: out.clone(),
    })?;
    let pair = Rig::from_file(&out)?;
    let rig = deep360_rig();
    let view = PairView::new(&rig, CameraPair { left: 1, right: 3 })?;
    assert_eq!(pair.cameras.len(), 2);
    assert_eq!(
        (pair.cameras[0].name.as_str(), pair.cameras[1].name.as_str()),
        ("cam2", "cam4")
    );
    for (a, b) in pair.cameras.iter().zip(&view.pair_rig().cameras) {
        let d = a.rig_from_cam.inverse() * b.rig_from_cam;
        assert!(d.translation.vector.norm() < 1e-6 && d.rotation.angle() < 1e-6);
    }
    let d = pair.rig_from_output.inverse() * pair.cameras[0].rig_from_cam;
    assert!(d.translation.vector.norm() < 1e-6 && d.rotation.angle() < 1e-6);
    let e = run_pair(RigPairArgs {
        rig: crate::common::repo_path(crate::common::DEEP360_RIG),
        pair: "cam2-roof".into(),
        out: dir.path().join("bad.yaml"),
    })
    .err()
    .ok_or("unknown camera accepted")?;
    assert!(format!("{e:#}").contains("no camera 'roof'"), "{e:#}");
    Ok(())
}

/// `bench-model --presets psmode,psmode_fusion`: the whole estimator per frame, with both
/// stages' parameters counted and every pair of the Deep360 rig matched.
#[test]
fn bench_model_times_psmode_with_and_without_fusion() -> TestResult {
    use mode360::cli::bench_model::psmode::{
        bench_psmode_case, case_fusion_weights, PsmodeBenchOptions, PSMODE, PSMODE_FUSION,
    };
    let case = |name: &str| {
        bench_psmode_case(&PsmodeBenchOptions {
            stage1_weights: None,
            fusion_weights: case_fusion_weights(name),
            width: 64,
            pair_width: DEFAULT_PAIR_WIDTH,
            rig: deep360_rig(),
            runs: 1,
            seed: 3,
            device: ComputeDevice::Cpu,
        })
    };
    let (plain, fused) = (case(PSMODE)?, case(PSMODE_FUSION)?);
    // the shipped files: SSMODE 152,736 parameters, the fusion network (select head) 92,522
    assert_eq!(plain.parameters, 152_736);
    assert_eq!(fused.parameters, 152_736 + 92_522);
    for c in [&plain, &fused] {
        assert!(c.preset.contains("6 pairs"), "{}", c.preset);
        assert_eq!((c.width, c.height, c.cameras, c.runs), (64, 32, 4, 1));
        assert_eq!(c.stages.len(), 1);
        assert!(c.end_to_end_median_s > 0.0 && c.peak_rss_mib > 0.0);
    }
    assert!(plain.preset.starts_with("psmode (") && fused.preset.starts_with("psmode_fusion ("));
    Ok(())
}

/// Stage 1 runs at the pair width where the output is at least that wide and at the width its
/// network was trained at otherwise; a width the network cannot run at is refused naming the
/// setting, and a pair width given to another estimator is an error.
#[test]
fn stage_one_runs_at_the_pair_width_where_the_output_is_that_wide() -> TestResult {
    let load = |width| {
        PsmodeEstimator::load_on(
            default_weights_path(),
            None,
            ComputeDevice::Cpu,
            PairChoice::All,
            width,
        )
    };
    let est = load(DEFAULT_PAIR_WIDTH)?;
    // the shipped stage 1 was trained at 256
    assert_eq!(
        [128, 256, 511, 512, 1024].map(|w| est.stage1_width(w)),
        [256, 256, 256, 512, 512]
    );
    for width in [TRAINED_PAIR_WIDTH, 256, 128] {
        assert_eq!(load(width)?.stage1_width(1024), 256, "pair width {width}");
    }
    let e = load(500).err().ok_or("a width the network cannot run at")?;
    let e = e.to_string();
    assert!(e.contains("pair_width") && e.contains("500"), "{e}");
    let spec = EstimatorSpec {
        pair_width: Some(512),
        ..EstimatorSpec::new(EstimatorKind::Ssmode)
    };
    let e = spec.build().err().ok_or("a pair width for SSMODE")?;
    assert!(e.to_string().contains("pair_width"), "{e}");
    Ok(())
}
