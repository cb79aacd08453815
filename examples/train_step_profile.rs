//! Where a training step's time goes, for one preset with 4 cameras: sweep tables, the forward
//! stages, backward, and the optimizer step. On a GPU (a `cuda` build), it first checks the
//! CUDA table kernels against the CPU's (forward and gradient; exits 1 past a tolerance), and
//! times each part to the device's end (synchronized).
//!
//! `cargo run --release --example train_step_profile -- [PRESET] [STEPS] [DEVICE] [WIDTH]`
//! (DEVICE: cpu or cuda:N; WIDTH: the preset's own when absent)

use candle_core::{DType, Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarBuilder, VarMap};
use mode360::geometry::Rig;
use mode360::model::ops::{table_sample, SampleTable};
use mode360::model::{ComputeDevice, Ssmode, SsmodeConfig, StageProfiler, SweepSampling};
use mode360_core::geometry::BilinearTaps;
use std::time::Instant;

#[global_allocator]
static GLOBAL: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let preset = args.next().unwrap_or_else(|| "parallax".into());
    let steps: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(3);
    let device: ComputeDevice = args.next().unwrap_or_else(|| "cpu".into()).parse()?;
    let device = device.open()?;
    let mut cfg = SsmodeConfig::preset(&preset)?;
    if let Some(width) = args.next() {
        cfg.width = width.parse()?;
    }
    if device.is_cuda() {
        check_table_kernels(&device)?;
    }
    let rig = Rig::from_file("launch_configs/rig_deep360.yaml")?;
    let t = Instant::now();
    let sampling = SweepSampling::new(&rig, &cfg)?;
    println!("sweep tables: {:.3} s", t.elapsed().as_secs_f64());
    let varmap = VarMap::new();
    let net = Ssmode::new(&cfg, VarBuilder::from_varmap(&varmap, DType::F32, &device))?;
    let images: Vec<Tensor> = (0..rig.cameras.len())
        .map(|_| Tensor::rand(0f32, 1f32, (1, cfg.height(), cfg.width, 3), &device))
        .collect::<Result<_, _>>()?;
    let mut opt = AdamW::new(varmap.all_vars(), ParamsAdamW::default())?;
    for step in 0..steps {
        let t0 = Instant::now();
        let mut prof = StageProfiler::new();
        let out = net.forward_profiled(&images, &sampling, true, Some(&mut prof))?;
        let mut loss = Tensor::new(0f32, &device)?;
        for s in &out.inverse_depth_stages {
            loss = (loss + (s - 0.4)?.abs()?.mean_all()?)?;
        }
        device.synchronize()?;
        let t1 = Instant::now();
        let grads = loss.backward()?;
        device.synchronize()?;
        let t2 = Instant::now();
        opt.step(&grads)?;
        device.synchronize()?;
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

/// The CUDA table gather and its adjoint against the CPU kernels on a random table: prints the
/// largest differences and fails past `TOLERANCE`.
fn check_table_kernels(device: &Device) -> anyhow::Result<()> {
    const TOLERANCE: f32 = 1e-3;
    let (h, w, c, samples) = (64usize, 128usize, 8usize, 200_000usize);
    let pixels = (h * w) as u32;
    // a fixed pseudo-random table (an LCG: reproducible, no extra dependency)
    let mut state = 12345u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 33) as u32
    };
    let taps: Vec<BilinearTaps> = (0..samples)
        .map(|_| BilinearTaps {
            index: std::array::from_fn(|_| next() % pixels),
            weight: std::array::from_fn(|_| (next() % 1000) as f32 / 1000.0),
        })
        .collect();
    let table = SampleTable::new(&taps);
    let features = Tensor::rand(-1f32, 1f32, (2, h, w, c), &Device::Cpu)?;
    let upstream = Tensor::rand(-1f32, 1f32, (2, samples, c), &Device::Cpu)?;
    let run = |dev: &Device| -> anyhow::Result<(Vec<f32>, Vec<f32>)> {
        let f = candle_core::Var::from_tensor(&features.to_device(dev)?)?;
        let out = table_sample(f.as_tensor(), &table)?;
        let loss = (&out * upstream.to_device(dev)?)?.sum_all()?;
        let grads = loss.backward()?;
        let grad = grads
            .get(f.as_tensor())
            .ok_or_else(|| anyhow::anyhow!("no gradient to the features"))?;
        Ok((
            out.flatten_all()?.to_vec1()?,
            grad.flatten_all()?.to_vec1()?,
        ))
    };
    let t = Instant::now();
    let (gpu_out, gpu_grad) = run(device)?;
    let gpu_s = t.elapsed().as_secs_f64();
    let (cpu_out, cpu_grad) = run(&Device::Cpu)?;
    let max_diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max)
    };
    let (d_out, d_grad) = (max_diff(&gpu_out, &cpu_out), max_diff(&gpu_grad, &cpu_grad));
    println!(
        "table kernels on {device:?} against the CPU ({samples} samples, {h}x{w}x{c}): \
         max |out diff| {d_out:.2e}, max |grad diff| {d_grad:.2e} ({gpu_s:.3} s with the first load)"
    );
    if !(d_out <= TOLERANCE && d_grad <= TOLERANCE) {
        anyhow::bail!("the CUDA table kernels disagree with the CPU's beyond {TOLERANCE}");
    }
    Ok(())
}
