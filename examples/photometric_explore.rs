//! Exploration of the photometric sphere sweep: prints accuracy and timing on the analytic
//! scene (4, 3 and 2 cameras) and on rendered street frames, for tuning its configuration.
//!
//! `cargo run --release --example photometric_explore -- analytic|synth`; environment:
//! `PHOTO_WIDTH` (frame width), `PHOTO_CFG` (a PhotometricConfig as JSON), and the variables
//! read below. Nothing here is asserted: the tests in tests/model/photometric_sweep.rs are.

#[path = "../tests/common/mod.rs"]
mod common;
#[path = "../tests/model/photometric_scene.rs"]
mod photometric_scene;

use common::{TestResult, RIG_PATH};
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::DepthEstimator;
use mode360::frame::RgbImage;
use mode360::geometry::{ErpGrid, Rig};
use photometric_scene::{render, scores};
use std::time::Instant;

fn main() -> TestResult {
    match std::env::args().nth(1).as_deref() {
        Some("analytic") => explore_analytic_scene(),
        Some("synth") => explore_synth(),
        _ => Err("usage: photometric_explore analytic|synth".into()),
    }
}

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

fn explore_synth() -> TestResult {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .try_init();
    use mode360::synth::{SynthConfig, SynthRenderer};
    let rig = Rig::from_file(RIG_PATH)?;
    let env_num = |k: &str, d: usize| {
        std::env::var(k)
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(d)
    };
    let width = env_num("PHOTO_WIDTH", 512);
    let seeds = env_num("PHOTO_SEEDS", 2);
    let frames = env_num("PHOTO_FRAMES", 1);
    let soiled = std::env::var("PHOTO_SOILED").is_ok();
    let max_depth_m = 1000.0;
    let cfg: PhotometricConfig = match std::env::var("PHOTO_CFG") {
        Ok(json) => serde_json::from_str(&json)?,
        Err(_) => PhotometricConfig::default(),
    };
    let sets: Vec<(&str, Vec<usize>)> = match std::env::var("PHOTO_SETS") {
        Ok(s) if s == "4" => vec![("4cam", vec![0, 1, 2, 3])],
        _ => vec![
            ("4cam", vec![0, 1, 2, 3]),
            ("3cam", vec![0, 1, 2]),
            ("2cam", vec![0, 1]),
        ],
    };
    for (name, idx) in sets {
        let sub = rig.subset(&idx)?;
        let mut est = PhotometricSweep::new(cfg.clone())?;
        let (mut d1, mut ar, mut mae, mut rmse, mut secs, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut cpu = 0.0;
        for seed in 0..seeds as u64 {
            let renderer = SynthRenderer::new(SynthConfig {
                seed,
                width,
                soiled,
                ..Default::default()
            })?;
            for f in 0..frames {
                let frame = renderer.render_frame(&rig, f * 5);
                let Some(gt) = frame.ground_truth.as_ref() else {
                    continue;
                };
                let imgs: Vec<RgbImage> = idx.iter().map(|&i| frame.images[i].clone()).collect();
                let t0 = Instant::now();
                let cpu0 = process_cpu_s();
                let out = est.estimate(&sub, &imgs, ErpGrid::new(width)?)?;
                secs += t0.elapsed().as_secs_f64();
                cpu += process_cpu_s() - cpu0;
                let s = scores(&out.range_m, gt, max_depth_m);
                println!("  {name} seed {seed} frame {}: {s:?}", f * 5);
                d1 += s.delta1;
                ar += s.abs_rel;
                mae += s.mae_m;
                rmse += s.rmse_m;
                n += 1.0;
                if std::env::var("PHOTO_DUMP").is_ok() && seed == 0 && f == 0 {
                    let (w, h) = (width as u32, width as u32 / 2);
                    let mut img = RgbImage::new(w, h * 2);
                    for (k, (&p, &g)) in out.range_m.data.iter().zip(&gt.data).enumerate() {
                        let (u, v) = (k as u32 % w, k as u32 / w);
                        let ok = (p / g).max(g / p) < 1.25;
                        let enc = |d: f32| (255.0 * (1.0 / d).min(1.0).sqrt()) as u8;
                        img.put_pixel(
                            u,
                            v,
                            image::Rgb([enc(g), enc(g), if ok { enc(g) } else { 255 }]),
                        );
                        img.put_pixel(u, v + h, image::Rgb([enc(p), enc(p), enc(p)]));
                    }
                    img.save(format!("/tmp/photo_synth_{name}.png"))?;
                    frame.images[0].save("/tmp/photo_synth_cam1.png")?;
                }
            }
        }
        println!("{name} {width} soiled={soiled}: delta1 {:.4} absrel {:.4} mae {:.2} rmse {:.2} s/frame {:.2} cpu-s/frame {:.2}",
            d1 / n, ar / n, mae / n, rmse / n, secs / n, cpu / n);
    }
    Ok(())
}

/// User + system CPU seconds of this process so far (Linux `/proc/self/stat`, 100 ticks/s).
fn process_cpu_s() -> f64 {
    const TICKS_PER_S: f64 = 100.0;
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after_name = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name.
    let tick = |i: usize| {
        fields
            .get(i)
            .and_then(|s| s.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    (tick(11) + tick(12)) / TICKS_PER_S
}
