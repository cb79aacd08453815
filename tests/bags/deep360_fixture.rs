//! Deep360 reader: a fixture written in the dataset's layout (Cassini PNGs + npz) from a
//! synthetic frame reads back as the original ERP frame within interpolation tolerance; and
//! ground truth written by numpy from the format's description alone (not by this crate's
//! writer) reads as the known scene along every ERP ray.

use mode360::deep360::{
    deep360_rig, erp_to_cassini_range, erp_to_cassini_rgb, write_npz, Deep360Dataset, Deep360Error,
    Deep360FrameId, Deep360Split, CASSINI_HEIGHT, CASSINI_WIDTH, DEPTH_NPZ_KEY,
};
use mode360::frame::RigFrame;
use mode360::synth::{SynthConfig, SynthRenderer};
use std::path::Path;

const ERP_WIDTH: usize = 256;
const FRAME: u32 = 42;

/// Writes `frame` in the dataset's layout: its four cameras as RGBA Cassini PNGs under
/// `ep{episode}_500frames/{split}/{image_dir}/` and, with `with_depth`, its range as the
/// depth `.npz`.
fn write_frame_files(
    root: &Path,
    episode: u32,
    split: &str,
    frame_number: u32,
    frame: &RigFrame,
    image_dir: &str,
    with_depth: bool,
) {
    let split = root.join(format!("ep{episode}_500frames")).join(split);
    std::fs::create_dir_all(split.join(image_dir)).unwrap();
    std::fs::create_dir_all(split.join("depth")).unwrap();
    for (k, img) in frame.images.iter().enumerate() {
        let cam = k + 1;
        let pair = if cam <= 2 { "12" } else { "34" };
        let cassini = erp_to_cassini_rgb(img, CASSINI_WIDTH, CASSINI_HEIGHT);
        // RGBA like the dataset.
        let rgba = image::DynamicImage::ImageRgb8(cassini).to_rgba8();
        rgba.save(
            split
                .join(image_dir)
                .join(format!("{frame_number:06}_{pair}_rgb{cam}.png")),
        )
        .unwrap();
    }
    if with_depth {
        let gt = frame.ground_truth.as_ref().unwrap();
        let cassini_range = erp_to_cassini_range(gt, CASSINI_WIDTH, CASSINI_HEIGHT);
        write_npz(
            &split
                .join("depth")
                .join(format!("{frame_number:06}_depth.npz")),
            DEPTH_NPZ_KEY,
            &[CASSINI_HEIGHT, CASSINI_WIDTH],
            &cassini_range.data,
        )
        .unwrap();
    }
}

/// A synthetic frame on the Deep360 rig at `ERP_WIDTH`, clean or soiled.
fn render(index: usize, soiled: bool) -> RigFrame {
    let renderer = SynthRenderer::new(SynthConfig {
        seed: 11,
        width: ERP_WIDTH,
        soiled,
        ..SynthConfig::default()
    })
    .unwrap();
    renderer.render_frame(&deep360_rig().unwrap(), index)
}

fn write_fixture(root: &Path) -> RigFrame {
    let frame = render(3, false);
    write_frame_files(root, 2, "validation", FRAME, &frame, "rgb", true);
    frame
}

#[test]
fn fixture_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let original = write_fixture(dir.path());
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let ids = ds.frame_ids(Deep360Split::Validation).unwrap();
    assert_eq!(
        ids,
        vec![Deep360FrameId {
            episode: 2,
            frame: FRAME
        }]
    );
    assert!(ds.frame_ids(Deep360Split::Training).unwrap().is_empty());
    let frame = ds
        .load_frame(ids[0], Deep360Split::Validation, false, ERP_WIDTH)
        .unwrap();
    assert_eq!(frame.images.len(), 4);
    // Colour: ERP -> Cassini (2x finer) -> ERP, bilinear both ways.
    for (k, (a, b)) in original.images.iter().zip(&frame.images).enumerate() {
        assert_eq!(a.dimensions(), b.dimensions());
        let diffs: Vec<f64> = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(&x, &y)| (f64::from(x) - f64::from(y)).abs())
            .collect();
        let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
        let within = diffs.iter().filter(|d| **d <= 12.0).count() as f64 / diffs.len() as f64;
        assert!(mean < 4.0, "camera {}: mean abs diff {mean}", k + 1);
        assert!(within > 0.93, "camera {}: {within} within 12 levels", k + 1);
    }
    // Range: nearest neighbour both ways, exact except at depth edges.
    let gt_a = original.ground_truth.as_ref().unwrap();
    let gt_b = frame.ground_truth.as_ref().unwrap();
    let close = gt_a
        .data
        .iter()
        .zip(&gt_b.data)
        .filter(|(a, b)| ((*a - *b) / *a).abs() < 0.01)
        .count() as f64
        / gt_a.data.len() as f64;
    assert!(close > 0.97, "only {close} of range pixels within 1%");
}

#[test]
fn missing_and_corrupt_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    write_fixture(dir.path());
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let id = Deep360FrameId {
        episode: 2,
        frame: FRAME,
    };
    // Soiled images were not written.
    let err = ds
        .load_frame(id, Deep360Split::Validation, true, ERP_WIDTH)
        .unwrap_err();
    assert!(matches!(err, Deep360Error::Io { .. }));
    assert!(err.to_string().contains("rgb_soiled"), "{err}");
    assert!(err.to_string().contains("000042_12_rgb1.png"), "{err}");
    // Corrupt depth archive.
    let depth = ds.depth_path(id, Deep360Split::Validation);
    std::fs::write(&depth, b"not a zip").unwrap();
    let err = ds
        .load_frame(id, Deep360Split::Validation, false, ERP_WIDTH)
        .unwrap_err();
    assert!(matches!(err, Deep360Error::Npz { .. }));
    assert!(err.to_string().contains("000042_depth.npz"), "{err}");
    assert!(Deep360Dataset::open(dir.path().join("nope")).is_err());
}

// ---- Conversion to a rig bag, evaluation, fine-tuning ----------------------------------

use mode360::bag::RigBagReader;
use mode360::bag::{MAX_DEPTH_KEY, SOILED_KEY};
use mode360::cli::deep360_bag::{convert_deep360_to_bag, Deep360BagOptions};
use mode360::cli::eval::{evaluate, EvalOptions, ViewMode};
use mode360::deep360::{Deep360FrameVariant, DEEP360_MAX_DEPTH_M};
use mode360::estimator::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360::frame::{FloatImage, RgbImage};
use mode360::geometry::{ErpGrid, Rig};
use mode360::metrics::{depth_metrics, FrameAverage};
use mode360::train::data::{
    image_tensor, sample_fingerprint, training_sample, training_spec, DataConfig, Deep360Mix,
    RigChoice, SampleStream,
};
use std::collections::VecDeque;

/// ERP width of the converted bags (half the fixture's rendering width).
const BAG_WIDTH: usize = 128;

/// Frames of the fixture's testing split: (episode, frame, render index).
const TEST_FRAMES: [(u32, u32, usize); 3] = [(1, 7, 20), (1, 8, 21), (3, 7, 40)];

/// One fixture frame: its id and the clean and soiled renderings it was written from.
struct Written {
    id: Deep360FrameId,
    clean: RigFrame,
    soiled: RigFrame,
}

/// Writes `frames` (clean in `rgb/`, soiled in `rgb_soiled/`) into `split`.
fn write_split(root: &Path, split: &str, frames: &[(u32, u32, usize)]) -> Vec<Written> {
    frames
        .iter()
        .map(|&(episode, frame, index)| {
            let clean = render(index, false);
            let soiled = render(index, true);
            write_frame_files(root, episode, split, frame, &clean, "rgb", true);
            write_frame_files(root, episode, split, frame, &soiled, "rgb_soiled", false);
            Written {
                id: Deep360FrameId { episode, frame },
                clean,
                soiled,
            }
        })
        .collect()
}

fn convert(root: &Path, soiled: bool, out: &Path) -> anyhow::Result<usize> {
    convert_deep360_to_bag(&Deep360BagOptions {
        root: root.to_path_buf(),
        split: Deep360Split::Testing,
        soiled,
        width: BAG_WIDTH,
        max_frames: None,
        episode: None,
        out: out.to_path_buf(),
        show_progress: false,
    })
    .map(|s| s.frames)
}

/// 2x2 box average (the fixture renders at twice the bag's width).
fn half(img: &RgbImage) -> RgbImage {
    RgbImage::from_fn(img.width() / 2, img.height() / 2, |x, y| {
        let mut acc = [0u32; 3];
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let p = img.get_pixel(2 * x + dx, 2 * y + dy).0;
            for c in 0..3 {
                acc[c] += u32::from(p[c]);
            }
        }
        image::Rgb(acc.map(|a| ((a + 2) / 4) as u8))
    })
}

fn mean_abs_diff(a: &RgbImage, b: &RgbImage) -> f64 {
    let n = a.as_raw().len() as f64;
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (f64::from(x) - f64::from(y)).abs())
        .sum::<f64>()
        / n
}

#[test]
fn converted_bag_reads_back_with_rig_stamps_images_and_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let written = write_split(dir.path(), "testing", &TEST_FRAMES);
    let out = dir.path().join("deep360_test_soiled.mcap");
    assert_eq!(convert(dir.path(), true, &out).unwrap(), 3);

    let reader = RigBagReader::open(&out).unwrap();
    assert_eq!(reader.rig(), &deep360_rig().unwrap());
    let info = reader.info();
    assert_eq!(info[SOILED_KEY], "true");
    assert_eq!(
        info[MAX_DEPTH_KEY].parse::<f64>().unwrap(),
        DEEP360_MAX_DEPTH_M
    );
    assert_eq!(info["split"], "testing");
    let frames: Vec<RigFrame> = reader.frames().collect::<Result<_, _>>().unwrap();
    // Stamps: (episode * 1000 + frame) * 100 ms, unique across episodes, in (episode, frame)
    // order.
    let stamps: Vec<u64> = frames.iter().map(|f| f.stamp_ns).collect();
    assert_eq!(
        stamps,
        vec![100_700_000_000, 100_800_000_000, 300_700_000_000]
    );

    let ds = Deep360Dataset::open(dir.path()).unwrap();
    for (w, f) in written.iter().zip(&frames) {
        assert_eq!(f.stamp_ns, w.id.stamp_ns());
        assert_eq!(f.images.len(), 4);
        // Images: exactly what the reader gives for the soiled set, and closer to the soiled
        // rendering than to the clean one.
        let direct = ds
            .load_frame(w.id, Deep360Split::Testing, true, BAG_WIDTH)
            .unwrap();
        let (mut to_soiled, mut to_clean) = (0.0, 0.0);
        for (k, img) in f.images.iter().enumerate() {
            assert_eq!(img.dimensions(), (BAG_WIDTH as u32, BAG_WIDTH as u32 / 2));
            assert_eq!(img, &direct.images[k], "camera {}", k + 1);
            to_soiled += mean_abs_diff(img, &half(&w.soiled.images[k]));
            to_clean += mean_abs_diff(img, &half(&w.clean.images[k]));
        }
        assert!(
            to_soiled < to_clean,
            "{}: images differ from the soiled rendering by {to_soiled}, from the clean by {to_clean}",
            w.id
        );
        // Ground truth: nearest neighbour twice (ERP 256 -> Cassini -> ERP 128), so every
        // pixel away from the poles holds the fixture's range of a pixel at most one
        // rendering pixel from its ray's corner of the 2x2 block it covers.
        let gt = f.ground_truth.as_ref().unwrap();
        let orig = w.clean.ground_truth.as_ref().unwrap();
        assert_eq!((gt.width, gt.height), (BAG_WIDTH, BAG_WIDTH / 2));
        let near_original = |u: usize, v: usize| {
            let g = gt.get(u, v);
            (-1i64..=2).any(|dv| {
                (-1i64..=2).any(|du| {
                    let ou = (2 * u as i64 + du).rem_euclid(orig.width as i64) as usize;
                    let ov = (2 * v as i64 + dv).clamp(0, orig.height as i64 - 1) as usize;
                    (orig.get(ou, ov) - g).abs() <= 1e-4 * g
                })
            })
        };
        let margin = BAG_WIDTH / 16;
        for v in margin..gt.height - margin {
            for u in 0..gt.width {
                assert!(near_original(u, v), "{}: pixel ({u}, {v})", w.id);
            }
        }
        // A few pixels by hand: straight ahead, left, behind, below the horizon.
        for (u, v) in [(64, 31), (32, 31), (0, 31), (64, 48), (100, 40)] {
            assert!(near_original(u, v), "{}: pixel ({u}, {v})", w.id);
        }
        assert!(gt.data.iter().all(|r| *r > 0.0 && *r <= 1000.0));
    }
}

/// Returns the queued ground truths in order: a perfect estimator.
struct Oracle(VecDeque<FloatImage>);

impl DepthEstimator for Oracle {
    fn name(&self) -> &str {
        "oracle"
    }

    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        assert_eq!(images.len(), rig.cameras.len());
        let range = self.0.pop_front().expect("one ground truth per frame");
        assert_eq!(
            (range.width, range.height),
            (output.width(), output.height())
        );
        let n = range.data.len();
        Ok(DepthEstimate::on_grid(output, range.data, vec![1.0; n]))
    }
}

/// The same range everywhere.
struct Constant(f32);

impl DepthEstimator for Constant {
    fn name(&self) -> &str {
        "constant"
    }

    fn estimate(
        &mut self,
        _rig: &Rig,
        _images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        let n = output.width() * output.height();
        Ok(DepthEstimate::on_grid(
            output,
            vec![self.0; n],
            vec![1.0; n],
        ))
    }
}

#[test]
fn evaluating_converted_bags() {
    let dir = tempfile::tempdir().unwrap();
    write_split(dir.path(), "testing", &TEST_FRAMES);
    let clean = dir.path().join("clean.mcap");
    let soiled = dir.path().join("soiled.mcap");
    convert(dir.path(), false, &clean).unwrap();
    convert(dir.path(), true, &soiled).unwrap();
    let ground_truths: Vec<FloatImage> = [&clean, &soiled]
        .iter()
        .flat_map(|p| {
            RigBagReader::open(p)
                .unwrap()
                .frames()
                .map(|f| f.unwrap().ground_truth.unwrap())
                .collect::<Vec<_>>()
        })
        .collect();
    assert_eq!(ground_truths.len(), 6);
    let opts = EvalOptions {
        bags: vec![clean.clone(), soiled.clone()],
        cameras: None,
        max_frames: None,
        show_progress: false,
        png_dir: None,
        views: ViewMode::True,
    };

    // The ground truth against itself is perfect, through metrics directly ...
    for gt in &ground_truths {
        let m = depth_metrics(&gt.data, &gt.data, DEEP360_MAX_DEPTH_M).unwrap();
        assert_eq!(
            (m.mae_m, m.rmse_m, m.abs_rel, m.silog),
            (0.0, 0.0, 0.0, 0.0)
        );
        assert_eq!((m.delta1_pct, m.coverage_pct), (100.0, 100.0));
    }
    // ... and through `eval` on the bags, one row per condition from the `soiled` metadata.
    let report = evaluate(&opts, &mut Oracle(ground_truths.iter().cloned().collect())).unwrap();
    let conditions: Vec<&str> = report.rows.iter().map(|r| r.condition.as_str()).collect();
    assert_eq!(conditions, vec!["clean", "soiled"]);
    for row in &report.rows {
        assert_eq!(row.frames, 3);
        assert_eq!(row.cameras, vec!["cam1", "cam2", "cam3", "cam4"]);
        assert_eq!(row.depth.mae_m, 0.0);
        assert_eq!(row.depth.abs_rel, 0.0);
        assert_eq!(row.depth.delta1_pct, 100.0);
        let disp = row.disparity.unwrap();
        assert_eq!((disp.mae_px, disp.px1_pct, disp.d1_pct), (0.0, 0.0, 0.0));
    }

    // A constant 20 m scores exactly what the metrics give on the bags' ground truth, with
    // max_depth_m = 1000 from the metadata.
    let report = evaluate(&opts, &mut Constant(20.0)).unwrap();
    for (row, gts) in report.rows.iter().zip(ground_truths.chunks(3)) {
        let mut avg = FrameAverage::default();
        for gt in gts {
            let pred = vec![20.0; gt.data.len()];
            avg.push(depth_metrics(&pred, &gt.data, 1000.0).unwrap(), None);
        }
        let (a, b) = (row.depth, avg.depth());
        for (x, y) in [
            (a.mae_m, b.mae_m),
            (a.rmse_m, b.rmse_m),
            (a.abs_rel, b.abs_rel),
            (a.delta1_pct, b.delta1_pct),
        ] {
            assert!((x - y).abs() <= 1e-9 * y.abs().max(1.0), "{x} vs {y}");
        }
        assert!(a.mae_m > 1.0 && a.delta1_pct < 100.0);
    }
}

#[test]
fn conversion_errors_name_the_frame_and_file() {
    let dir = tempfile::tempdir().unwrap();
    write_split(dir.path(), "testing", &TEST_FRAMES);
    let out = dir.path().join("out.mcap");
    let opts = Deep360BagOptions {
        root: dir.path().to_path_buf(),
        split: Deep360Split::Testing,
        soiled: true,
        width: BAG_WIDTH,
        max_frames: None,
        episode: None,
        out: out.clone(),
        show_progress: false,
    };
    // --episode and --max-frames select frames; stamps keep the episode.
    let s = convert_deep360_to_bag(&Deep360BagOptions {
        episode: Some(3),
        max_frames: Some(1),
        ..opts.clone()
    })
    .unwrap();
    assert_eq!(
        (s.frames, s.first),
        (
            1,
            Deep360FrameId {
                episode: 3,
                frame: 7
            }
        )
    );
    let f: Vec<_> = RigBagReader::open(&out)
        .unwrap()
        .frames()
        .map(|f| f.unwrap().stamp_ns)
        .collect();
    assert_eq!(f, vec![300_700_000_000]);
    std::fs::remove_file(&out).unwrap();

    let err = |o: &Deep360BagOptions| format!("{:#}", convert_deep360_to_bag(o).unwrap_err());
    let e = err(&Deep360BagOptions {
        split: Deep360Split::Validation,
        ..opts.clone()
    });
    assert!(
        e.contains("no Deep360 frames") && e.contains("validation"),
        "{e}"
    );
    let e = err(&Deep360BagOptions {
        episode: Some(2),
        ..opts.clone()
    });
    assert!(e.contains("episode 2"), "{e}");
    let e = err(&Deep360BagOptions {
        episode: Some(9),
        ..opts.clone()
    });
    assert!(e.contains("episode must be 1 to 6"), "{e}");
    let e = err(&Deep360BagOptions {
        width: 99,
        ..opts.clone()
    });
    assert!(e.contains("99"), "{e}");
    let e = err(&Deep360BagOptions {
        root: dir.path().join("nowhere"),
        ..opts.clone()
    });
    assert!(e.contains("nowhere"), "{e}");

    // A missing image is found before anything is written.
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let id = Deep360FrameId {
        episode: 3,
        frame: 7,
    };
    let png = ds.image_path(id, Deep360Split::Testing, 3, true);
    std::fs::remove_file(&png).unwrap();
    let e = err(&opts);
    assert!(e.contains("episode 3 frame 000007"), "{e}");
    assert!(e.contains("rgb_soiled/000007_34_rgb3.png"), "{e}");
    assert!(!out.exists());
    // The clean set of that frame is complete.
    convert_deep360_to_bag(&Deep360BagOptions {
        soiled: false,
        ..opts.clone()
    })
    .unwrap();
    std::fs::remove_file(&out).unwrap();
    // A corrupt image fails during conversion; the half-written bag is removed.
    std::fs::write(&png, b"not a png").unwrap();
    let e = err(&opts);
    assert!(e.contains("episode 3 frame 000007"), "{e}");
    assert!(
        e.contains("000007_34_rgb3.png") && e.contains("decode"),
        "{e}"
    );
    assert!(!out.exists());
}

fn mode360_cli(args: &[&std::ffi::OsStr]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_mode360"))
        .args(args)
        .output()
        .expect("the mode360 binary runs")
}

#[test]
fn cli_converts_then_evaluates_and_replays() {
    let dir = tempfile::tempdir().unwrap();
    write_split(dir.path(), "testing", &TEST_FRAMES[..2]);
    let bag = dir.path().join("d.mcap");
    let json = dir.path().join("eval.json");
    let replayed = dir.path().join("replay.mcap");
    let os = |s: &str| std::ffi::OsString::from(s);
    let o = mode360_cli(&[
        &os("deep360-bag"),
        dir.path().as_os_str(),
        &os("--split"),
        &os("test"),
        &os("--width"),
        &os("64"),
        &os("--out"),
        bag.as_os_str(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("wrote 2 Deep360 frames"), "{stdout}");

    let o = mode360_cli(&[
        &os("eval"),
        &os("--bag"),
        bag.as_os_str(),
        &os("--json"),
        json.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["rows"][0]["condition"], "clean");
    assert_eq!(report["rows"][0]["frames"], 2);

    let o = mode360_cli(&[
        &os("replay"),
        bag.as_os_str(),
        &os("--out"),
        replayed.as_os_str(),
        &os("--max-frames"),
        &os("1"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(replayed.is_file());

    // Errors: unknown split, missing root (named), no exit through a panic.
    let o = mode360_cli(&[
        &os("deep360-bag"),
        dir.path().as_os_str(),
        &os("--split"),
        &os("bogus"),
        &os("--out"),
        bag.as_os_str(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("expected train, val or test"));
    let missing = dir.path().join("no_such_root");
    let o = mode360_cli(&[
        &os("deep360-bag"),
        missing.as_os_str(),
        &os("--split"),
        &os("val"),
        &os("--out"),
        bag.as_os_str(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("no_such_root"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Training split of the fine-tuning fixture: two frames of episode 1 with both image sets,
/// and a frame of episode 2 with clean images only.
fn write_training_split(root: &Path) {
    write_split(root, "training", &[(1, 0, 5), (1, 1, 6)]);
    write_frame_files(root, 2, "training", 5, &render(9, false), "rgb", true);
}

fn data_cfg(mix: Option<Deep360Mix>) -> DataConfig {
    DataConfig {
        seed: 3,
        width: 64,
        max_depth_m: DEEP360_MAX_DEPTH_M,
        soiled_fraction: 0.5,
        deep360_fraction: 0.25,
        deep360_disk: mix,
        objects_fraction: 0.0,
        street: mode360::synth::StreetStyle::Regular,
        fisheye_fraction: 0.0,
        rig_layouts: mode360::train::rig_layouts::RigLayouts::Roof,
        blocked_fraction: 0.0,
        rig_pool: 0,
    }
}

#[test]
fn deep360_training_samples_come_from_the_fixture() {
    let dir = tempfile::tempdir().unwrap();
    write_training_split(dir.path());
    let mix = Deep360Mix::open(dir.path(), 1.0).unwrap();
    let variant = |episode, frame, soiled| Deep360FrameVariant {
        id: Deep360FrameId { episode, frame },
        soiled,
    };
    assert_eq!(
        mix.frames,
        vec![
            variant(1, 0, false),
            variant(1, 0, true),
            variant(1, 1, false),
            variant(1, 1, true),
            variant(2, 5, false),
        ]
    );
    let cfg = data_cfg(Some(mix.clone()));

    // Fraction 1: every sample is a fixture frame, all five get picked.
    let specs: Vec<_> = (0..60).map(|k| training_spec(&cfg, k)).collect();
    let mut picked = std::collections::BTreeSet::new();
    for s in &specs {
        let id = s.deep360_frame.expect("a Deep360 frame");
        assert_eq!(s.rig, RigChoice::Deep360);
        assert!(mix.frames.contains(&Deep360FrameVariant {
            id,
            soiled: s.soiled
        }));
        picked.insert((id, s.soiled));
    }
    assert_eq!(picked.len(), 5);

    // A sample holds the frame as the reader gives it at the training width.
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    for k in [0, 1] {
        let sample = training_sample(&cfg, k).unwrap();
        let id = sample.spec.deep360_frame.unwrap();
        let direct = ds
            .load_frame(id, Deep360Split::Training, sample.spec.soiled, 64)
            .unwrap();
        assert_eq!(sample.rig, deep360_rig().unwrap());
        assert_eq!(sample.images.len(), 4);
        for (t, img) in sample.images.iter().zip(&direct.images) {
            assert_eq!(t.dims(), &[1, 32, 64, 3]);
            let a: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
            let b: Vec<f32> = image_tensor(img)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap();
            assert_eq!(a, b);
        }
        assert_eq!((sample.range_m.width, sample.range_m.height), (64, 32));
        assert_eq!(sample.range_m, direct.ground_truth.unwrap());
    }
    // The background stream yields the same samples (resume reads the same frames).
    let mut stream = SampleStream::start(cfg.clone(), 1, 1).unwrap();
    let s = stream.next_sample().unwrap();
    assert_eq!(s.index, 1);
    assert_eq!(
        sample_fingerprint(&s.sample.unwrap()).unwrap(),
        sample_fingerprint(&training_sample(&cfg, 1).unwrap()).unwrap()
    );

    // Fraction 0.5: about half; the rendered ones are exactly the stream without a dataset.
    let half_cfg = data_cfg(Some(Deep360Mix {
        fraction: 0.5,
        ..mix.clone()
    }));
    let plain = data_cfg(None);
    let mut from_disk = 0;
    for k in 0..400 {
        let s = training_spec(&half_cfg, k);
        match s.deep360_frame {
            Some(_) => from_disk += 1,
            None => assert_eq!(s, training_spec(&plain, k)),
        }
    }
    assert!(
        (150..=250).contains(&from_disk),
        "{from_disk}/400 from disk"
    );
    // Fraction 0: none.
    let none_cfg = data_cfg(Some(Deep360Mix {
        fraction: 0.0,
        ..mix
    }));
    assert!((0..100).all(|k| training_spec(&none_cfg, k).deep360_frame.is_none()));

    // A root without training frames is an error naming it.
    let empty = tempfile::tempdir().unwrap();
    let e = Deep360Mix::open(empty.path(), 1.0).unwrap_err().to_string();
    assert!(e.contains("no Deep360 training frames"), "{e}");
    assert!(Deep360Mix::open(dir.path(), 1.5).is_err());
}

#[test]
fn fine_tune_runs_on_the_fixture_and_resume_checks_the_dataset() {
    use mode360::train::{run_training, CheckpointState, TrainOptions, CHECKPOINT_DIR, STATE_FILE};
    let dir = tempfile::tempdir().unwrap();
    write_training_split(dir.path());
    let out = tempfile::tempdir().unwrap();
    let opts = TrainOptions {
        preset: mode360::model::Preset::Tiny,
        steps: 2,
        out_dir: out.path().to_path_buf(),
        warmup_steps: 1,
        val_every: 0,
        checkpoint_every_steps: 1,
        seed: 3,
        deep360_disk: Some(dir.path().to_path_buf()),
        deep360_disk_fraction: 1.0,
        show_progress: false,
        ..TrainOptions::default()
    };
    let s = run_training(&opts).unwrap();
    assert_eq!(s.final_step, 2);
    assert!(s.last_loss.is_finite() && s.last_loss > 0.0);
    let state: CheckpointState = serde_json::from_str(
        &std::fs::read_to_string(out.path().join(CHECKPOINT_DIR).join(STATE_FILE)).unwrap(),
    )
    .unwrap();
    let disk = state.deep360_disk.unwrap();
    assert_eq!((disk.frames, disk.fraction), (5, 1.0));
    assert_eq!(state.next_sample_index, 2);
    // The two samples trained on were fixture frames.
    let cfg = data_cfg(Some(Deep360Mix::open(dir.path(), 1.0).unwrap()));
    for k in 0..2 {
        assert!(training_spec(&cfg, k).deep360_frame.is_some());
    }
    // Resuming without the dataset would change the stream: refused, naming the option.
    let e = run_training(&TrainOptions {
        steps: 3,
        resume: true,
        deep360_disk: None,
        ..opts
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("deep360_disk"), "{e}");
}

/// Python (numpy) writes Deep360 ground truth from the format's description alone: the range
/// from camera 1 to the walls of a box room around it, off centre so that a mirrored or
/// rotated convention would not match (dataset frame `D`: x left, y up, z forward; walls at
/// x -2 and 4 m, y -1.5 and 3 m, z -3 and 7 m) as a Cassini image (row i, column j look along
/// `(sin phi, cos phi sin theta, cos phi cos theta)`, `theta = pi - (i + 0.5) 2 pi / H`,
/// `phi = pi/2 - (j + 0.5) pi / W`), saved by `numpy.savez` and `numpy.savez_compressed` with
/// numpy's own `.npy` writer. The crate reads the archives and resamples them to ERP; every
/// ERP pixel must hold the room's range along its own REP 103 direction (x forward = z_D,
/// y left = x_D, z up = y_D), computed here independently of the Cassini formulas.
#[test]
fn numpy_written_cassini_range_reads_as_the_room_along_every_erp_ray() {
    use mode360::deep360::{cassini_to_erp_range, read_npz_array};
    use mode360::frame::FloatImage;
    use mode360::geometry::{ErpGrid, PixelCoord};
    /// The room's walls along x_D, y_D, z_D (below and above camera 1), metres.
    const LOW_M: [f64; 3] = [-2.0, -1.5, -3.0];
    const HIGH_M: [f64; 3] = [4.0, 3.0, 7.0];
    const CASSINI_W: usize = 128;
    const CASSINI_H: usize = 256;
    let Some(python) = crate::common::python_with_numpy("the numpy-written fixture") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let script = format!(
        r#"
import sys, numpy as np
W, H = {CASSINI_W}, {CASSINI_H}
low = np.array([{}, {}, {}])[:, None, None]
high = np.array([{}, {}, {}])[:, None, None]
i = np.arange(H)[:, None] + 0.5
j = np.arange(W)[None, :] + 0.5
theta = np.pi - i * 2 * np.pi / H
phi = np.pi / 2 - j * np.pi / W
d = np.stack(np.broadcast_arrays(np.sin(phi), np.cos(phi) * np.sin(theta), np.cos(phi) * np.cos(theta)))
with np.errstate(divide="ignore", invalid="ignore"):
    t = np.where(d > 0, high / d, np.where(d < 0, low / d, np.inf))
r = np.min(t, axis=0)
np.savez(sys.argv[1], r.astype(np.float32))
np.savez_compressed(sys.argv[2], r.astype(np.float32))
"#,
        LOW_M[0], LOW_M[1], LOW_M[2], HIGH_M[0], HIGH_M[1], HIGH_M[2]
    );
    let (plain, compressed) = (
        dir.path().join("plain.npz"),
        dir.path().join("compressed.npz"),
    );
    let out = std::process::Command::new(&python)
        .args(["-c", &script])
        .arg(&plain)
        .arg(&compressed)
        .output()
        .expect("running python");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let grid = ErpGrid::new(128).unwrap();
    for path in [&plain, &compressed] {
        let arr = read_npz_array(path, DEPTH_NPZ_KEY).unwrap();
        assert_eq!(arr.shape, vec![CASSINI_H, CASSINI_W], "{}", path.display());
        let cassini = FloatImage {
            width: CASSINI_W,
            height: CASSINI_H,
            data: arr.data,
        };
        let erp = cassini_to_erp_range(&cassini, grid);
        let (mut worst, mut compared) = (0f64, 0usize);
        for v in 0..grid.height() {
            for u in 0..grid.width() {
                let rep = grid.dir_from_pixel(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                });
                // REP 103 -> dataset axes: x_D = y_rep (left), y_D = z_rep (up), z_D = x_rep
                let d = [rep.y, rep.z, rep.x];
                let expected = (0..3)
                    .map(|k| match d[k] {
                        x if x > 0.0 => HIGH_M[k] / x,
                        x if x < 0.0 => LOW_M[k] / x,
                        _ => f64::INFINITY,
                    })
                    .fold(f64::INFINITY, f64::min);
                let got = f64::from(erp.data[v * grid.width() + u]);
                // nearest-neighbour resampling: compare in relative terms away from the room's
                // edges, where a neighbouring Cassini pixel may see the other wall
                let rel = (got - expected).abs() / expected;
                worst = worst.max(rel.min(1.0));
                if rel < 0.05 {
                    compared += 1;
                }
            }
        }
        let share = compared as f64 / grid.len() as f64;
        assert!(
            share > 0.97,
            "{}: only {:.1} % of ERP pixels within 5 % of the room's range (worst {worst:.3})",
            path.display(),
            100.0 * share
        );
    }
}

/// Python writes a Deep360 frame from the format's description alone: each camera's RGBA PNG
/// (written with zlib and the PNG chunk layout, not an image library) is a Cassini image whose
/// pixel colour encodes the direction that pixel looks along in the dataset frame `D`
/// (`colour = round(127.5 (1 + d_D))` per axis, with row i, column j looking along
/// `(sin phi, cos phi sin theta, cos phi cos theta)`, `theta = pi - (i + 0.5) 2 pi / H`,
/// `phi = pi/2 - (j + 0.5) pi / W`); the depth archive is numpy's. Read through the crate's
/// dataset loader, every ERP pixel must show the colour of its own REP 103 direction
/// (x forward = z_D, y left = x_D, z up = y_D), computed here independently.
#[test]
fn python_written_cassini_images_look_along_their_erp_directions() {
    use mode360::geometry::{ErpGrid, PixelCoord};
    /// Largest angle between an ERP pixel's direction and the one its colour encodes.
    const MAX_ANGLE_DEG: f64 = 2.0;
    const ERP_W: usize = 256;
    let Some(python) = crate::common::python_with_numpy("the numpy-written fixture") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let split = dir.path().join("ep1_500frames").join("testing");
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(split.join(sub)).unwrap();
    }
    let script = format!(
        r#"
import sys, struct, zlib, numpy as np
W, H = {CASSINI_WIDTH}, {CASSINI_HEIGHT}
i = np.arange(H)[:, None] + 0.5
j = np.arange(W)[None, :] + 0.5
theta = np.pi - i * 2 * np.pi / H
phi = np.pi / 2 - j * np.pi / W
d = np.stack(np.broadcast_arrays(np.sin(phi), np.cos(phi) * np.sin(theta), np.cos(phi) * np.cos(theta)), axis=-1)
rgb = np.round(127.5 * (1.0 + d)).astype(np.uint8)
rgba = np.concatenate([rgb, np.full((H, W, 1), 255, np.uint8)], axis=-1)
# PNG: signature, IHDR (8-bit RGBA), IDAT (filter byte 0 per row, zlib), IEND
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
raw = b"".join(b"\x00" + rgba[r].tobytes() for r in range(H))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 6, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
split = sys.argv[1]
for name in ["12_rgb1", "12_rgb2", "34_rgb3", "34_rgb4"]:
    open(f"{{split}}/rgb/000000_{{name}}.png", "wb").write(png)
np.savez(f"{{split}}/depth/000000_depth.npz", np.full((H, W), 10.0, np.float32))
"#
    );
    let out = std::process::Command::new(&python)
        .args(["-c", &script])
        .arg(&split)
        .output()
        .expect("running python");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let ids = ds.frame_ids(Deep360Split::Testing).unwrap();
    assert_eq!(ids.len(), 1);
    let frame = ds
        .load_frame(ids[0], Deep360Split::Testing, false, ERP_W)
        .unwrap();
    assert_eq!(frame.images.len(), 4);
    let grid = ErpGrid::new(ERP_W).unwrap();
    let max_cos = MAX_ANGLE_DEG.to_radians().cos();
    for (cam, img) in frame.images.iter().enumerate() {
        assert_eq!(
            (img.width() as usize, img.height() as usize),
            (ERP_W, ERP_W / 2)
        );
        let (mut within, mut worst_deg) = (0usize, 0f64);
        for v in 0..grid.height() {
            for u in 0..grid.width() {
                let rep = grid.dir_from_pixel(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                });
                let p = img.get_pixel(u as u32, v as u32).0;
                let decode = |c: u8| f64::from(c) / 127.5 - 1.0;
                let (xd, yd, zd) = (decode(p[0]), decode(p[1]), decode(p[2]));
                // dataset axes -> REP 103: x = z_D, y = x_D, z = y_D
                let seen = nalgebra::Vector3::new(zd, xd, yd);
                let cos = seen.dot(&rep) / seen.norm().max(1e-12);
                worst_deg = worst_deg.max(cos.clamp(-1.0, 1.0).acos().to_degrees());
                if cos >= max_cos {
                    within += 1;
                }
            }
        }
        let share = within as f64 / grid.len() as f64;
        // Bilinear blending across the wrap seam and at the poles blurs a few pixels' colours.
        assert!(
            share > 0.98,
            "camera {}: only {:.2} % of ERP pixels look within {MAX_ANGLE_DEG} deg of their colour's direction (worst {worst_deg:.1} deg)",
            cam + 1,
            100.0 * share
        );
    }
}
