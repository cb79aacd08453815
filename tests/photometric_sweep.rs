//! Accuracy of the photometric sphere sweep against exact ground truth.

mod photometric_scene;

use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::{DepthEstimator, EstimatorError};
use mode360::frame::RgbImage;
use mode360::geometry::{ErpGrid, Rig};
use photometric_scene::{render, scores};
use std::time::Instant;

const RIG_PATH: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/launch_configs/rig_deep360.yaml"
);

type TestResult = Result<(), Box<dyn std::error::Error>>;

#[test]
#[ignore = "exploration: prints metrics"]
fn explore_analytic_scene() -> TestResult {
    let rig = Rig::from_file(RIG_PATH)?;
    let width: usize = std::env::var("PHOTO_WIDTH")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(256);
    let max_depth_m = 1000.0;
    let frame = render(&rig, width, max_depth_m)?;
    for (name, idx) in [
        ("4cam", vec![0, 1, 2, 3]),
        ("3cam", vec![0, 1, 2]),
        ("2cam", vec![0, 1]),
    ] {
        let sub = rig.subset(&idx)?;
        let imgs: Vec<RgbImage> = idx.iter().map(|&i| frame.images[i].clone()).collect();
        let cfg: PhotometricConfig = match std::env::var("PHOTO_CFG") {
            Ok(json) => serde_json::from_str(&json)?,
            Err(_) => PhotometricConfig::default(),
        };
        let mut est = PhotometricSweep::new(cfg)?;
        let t0 = Instant::now();
        let out = est.estimate(&sub, &imgs, ErpGrid::new(width)?)?;
        let secs = t0.elapsed().as_secs_f64();
        let s = scores(&out.range_m, &frame.ground_truth, max_depth_m);
        println!("{name} {width}: {s:?} {secs:.2}s");
    }
    Ok(())
}
