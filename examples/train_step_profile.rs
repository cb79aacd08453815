//! Where a training step's time goes, for one preset at its own width with 4 cameras: sweep
//! tables, the forward stages, backward, and the optimizer step.
//!
//! `cargo run --release --example train_step_profile -- [PRESET] [STEPS]`

use candle_core::{DType, Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarBuilder, VarMap};
use mode360::geometry::Rig;
use mode360::model::{Ssmode, SsmodeConfig, StageProfiler, SweepSampling};
use std::time::Instant;

#[global_allocator]
static GLOBAL: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let preset = args.next().unwrap_or_else(|| "parallax".into());
    let steps: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(3);
    let cfg = SsmodeConfig::preset(&preset)?;
    let rig = Rig::from_file("launch_configs/rig_deep360.yaml")?;
    let t = Instant::now();
    let sampling = SweepSampling::new(&rig, &cfg)?;
    println!("sweep tables: {:.3} s", t.elapsed().as_secs_f64());
    let varmap = VarMap::new();
    let net = Ssmode::new(
        &cfg,
        VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu),
    )?;
    let images: Vec<Tensor> = (0..rig.cameras.len())
        .map(|_| Tensor::rand(0f32, 1f32, (1, cfg.height(), cfg.width, 3), &Device::Cpu))
        .collect::<Result<_, _>>()?;
    let mut opt = AdamW::new(varmap.all_vars(), ParamsAdamW::default())?;
    for step in 0..steps {
        let t0 = Instant::now();
        let mut prof = StageProfiler::new();
        let out = net.forward_profiled(&images, &sampling, true, Some(&mut prof))?;
        let mut loss = Tensor::new(0f32, &Device::Cpu)?;
        for s in &out.inverse_depth_stages {
            loss = (loss + (s - 0.4)?.abs()?.mean_all()?)?;
        }
        let t1 = Instant::now();
        let grads = loss.backward()?;
        let t2 = Instant::now();
        opt.step(&grads)?;
        let t3 = Instant::now();
        let stages: Vec<String> = prof
            .stages()
            .iter()
            .map(|s| format!("{} {:.3}", s.stage, s.elapsed.as_secs_f64()))
            .collect();
        println!(
            "step {step}: forward {:.3} s ({}), backward {:.3} s, optimizer {:.3} s",
            (t1 - t0).as_secs_f64(),
            stages.join(", "),
            (t2 - t1).as_secs_f64(),
            (t3 - t2).as_secs_f64()
        );
    }
    Ok(())
}
