//! Deep360 to rig bag: a converted fixture reads back with the Deep360 rig, its stamps,
//! images and ground truth; `eval` on converted bags (an oracle scores perfectly, a constant
//! estimate as the metrics give); conversion errors name the frame and file; and the
//! `mode360` binary converts, evaluates and replays.

use crate::deep360_writer::{convert, write_split, BAG_WIDTH, TEST_FRAMES};
use mode360::bag::RigBagReader;
use mode360::bag::{MAX_DEPTH_KEY, SOILED_KEY};
use mode360::cli::deep360_bag::{convert_deep360_to_bag, Deep360BagOptions};
use mode360::cli::eval::{evaluate, EvalOptions, ViewMode};
use mode360::deep360::{
    deep360_rig, Deep360Dataset, Deep360FrameId, Deep360Split, DEEP360_MAX_DEPTH_M,
};
use mode360::estimator::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360::frame::{FloatImage, RgbImage, RigFrame};
use mode360::geometry::{ErpGrid, Rig};
use mode360::metrics::{depth_metrics, FrameAverage};
use std::collections::VecDeque;

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
        lens_masks: true,
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
