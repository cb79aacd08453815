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
        if std::env::var("PHOTO_DUMP").is_ok() {
            let (w, h) = (width as u32, width as u32 / 2);
            let mut img = RgbImage::new(w, h * 2);
            let mut sky_bad = 0;
            let mut bad = 0;
            for (k, (&p, &g)) in out
                .range_m
                .data
                .iter()
                .zip(&frame.ground_truth.data)
                .enumerate()
            {
                let (u, v) = (k as u32 % w, k as u32 / w);
                let ok = (p / g).max(g / p) < 1.25;
                if !ok {
                    bad += 1;
                    if g >= 999.0 {
                        sky_bad += 1;
                    }
                }
                let enc = |d: f32| (255.0 * (1.0 / d).min(1.0).sqrt()) as u8;
                img.put_pixel(
                    u,
                    v,
                    image::Rgb([enc(g), enc(g), if ok { enc(g) } else { 255 }]),
                );
                img.put_pixel(u, v + h, image::Rgb([enc(p), enc(p), enc(p)]));
            }
            println!("bad {bad} of which sky {sky_bad}");
            img.save(format!("/tmp/photo_{name}.png"))?;
            frame.images[0].save("/tmp/photo_cam1.png")?;
        }
    }
    Ok(())
}
