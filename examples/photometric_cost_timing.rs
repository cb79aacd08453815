//! Time of SSMODE's photometric cost channel (the sweep's ZNCC per sphere, on the CPU) for one
//! frame of the Deep360 rig at a preset's width, best of a few runs, with a checksum of its
//! output so that a faster version can be checked against a slower one:
//! `cargo run --release --example photometric_cost_timing -- [PRESET] [WIDTH] [RUNS] [SAVE|CHECK FILE]`
//! (SAVE writes the output as little-endian f32 to FILE, CHECK compares with such a file).

use std::time::Instant;

use candle_core::{Device, Tensor};
use mode360::geometry::Rig;
use mode360::model::photometric_cost::photometric_cost;
use mode360::model::{SsmodeConfig, SweepSampling};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let preset = args.next().unwrap_or_else(|| "parallax_zncc_log".into());
    let mut cfg = SsmodeConfig::preset(&preset)?;
    if let Some(width) = args.next() {
        cfg.width = width.parse()?;
    }
    let runs: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(3);
    let mode = args.next();
    let file = args.next();
    let rig = Rig::from_file("launch_configs/rig_deep360.yaml")?;
    let sampling = SweepSampling::new(&rig, &cfg)?;
    let grid = sampling.geometry().output();
    // smooth random images: a sum of a few sinusoids per camera, so that ZNCC has structure
    let images: Vec<Tensor> = (0..rig.cameras.len())
        .map(|cam| {
            let (w, h) = (grid.width(), grid.height());
            let data: Vec<f32> = (0..h * w * 3)
                .map(|i| {
                    let (p, c) = (i / 3, i % 3);
                    let (u, v) = ((p % w) as f32, (p / w) as f32);
                    let k = (cam * 3 + c) as f32;
                    0.5 + 0.2 * (0.31 * u + 0.17 * v + k).sin()
                        + 0.2 * (0.07 * u * (1.0 + 0.1 * k) - 0.23 * v).cos()
                })
                .collect();
            Tensor::from_vec(data, (1, h, w, 3), &Device::Cpu)
        })
        .collect::<Result<_, _>>()?;
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let cost = photometric_cost(&images, &sampling)?;
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(cost);
    }
    let values: Vec<f32> = out.expect("one run").flatten_all()?.to_vec1()?;
    let sum: f64 = values.iter().map(|&x| f64::from(x)).sum();
    println!(
        "photometric_cost {preset} at {}x{} ({} values): best of {runs} {best:.3} s, sum {sum:.4}",
        grid.width(),
        grid.height(),
        values.len()
    );
    match (mode.as_deref(), file) {
        (Some("SAVE"), Some(f)) => {
            std::fs::write(
                &f,
                values
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect::<Vec<u8>>(),
            )?;
        }
        (Some("CHECK"), Some(f)) => {
            let bytes = std::fs::read(&f)?;
            let reference: Vec<f32> = bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            anyhow::ensure!(
                reference.len() == values.len(),
                "{} values in {f}",
                reference.len()
            );
            let max = values
                .iter()
                .zip(&reference)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            println!("max |difference| against {f}: {max:.3e}");
        }
        _ => {}
    }
    Ok(())
}
