//! Seconds per frame of the photometric sphere sweep on a rendered 512x256 street frame,
//! 4 cameras of the Deep360 rig, default config (the rig cache is warm after the first call),
//! and of SSMODE's photometric cost channel (`model::photometric_cost`, the shipped preset's
//! 96 spheres at 256x128 cost cells) on the same rig.

use criterion::{criterion_group, criterion_main, Criterion};
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::DepthEstimator;
use mode360::geometry::{ErpGrid, Rig};
use mode360::model::photometric_cost::photometric_cost;
use mode360::model::{input_tensor, SsmodeConfig, SweepSampling};
use mode360::synth::{SynthConfig, SynthRenderer};
use std::time::Duration;

const RIG_PATH: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/launch_configs/rig_deep360.yaml"
);
const BENCH_WIDTH: usize = 512;
const SAMPLES: usize = 10;
const MEASUREMENT_TIME: Duration = Duration::from_secs(40);

fn photometric(c: &mut Criterion) {
    let setup = || -> Result<_, Box<dyn std::error::Error>> {
        let rig = Rig::from_file(RIG_PATH)?;
        let renderer = SynthRenderer::new(SynthConfig {
            seed: 0,
            width: BENCH_WIDTH,
            soiled: false,
            ..Default::default()
        })?;
        let frame = renderer.render_frame(&rig, 0);
        let est = PhotometricSweep::new(PhotometricConfig::default())?;
        Ok((rig, frame, est, ErpGrid::new(BENCH_WIDTH)?))
    };
    let (rig, frame, mut est, grid) = match setup() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("photometric bench setup failed: {e}");
            return;
        }
    };
    let mut group = c.benchmark_group("photometric");
    group.sample_size(SAMPLES);
    group.measurement_time(MEASUREMENT_TIME);
    group.bench_function("estimate_512x256_4cam", |b| {
        b.iter(|| {
            est.estimate(&rig, &frame.images, grid)
                .map(|d| d.range_m.data.len())
        })
    });
    group.finish();
}

/// The network's photometric channel, alone: the sweep tables are built once (as the node
/// builds them once per rig), the images are the input tensors at the cost volume's size.
fn photometric_channel(c: &mut Criterion) {
    let setup = || -> Result<_, Box<dyn std::error::Error>> {
        let cfg = SsmodeConfig::parallax_zncc_log();
        let rig = Rig::from_file(RIG_PATH)?;
        let frame = SynthRenderer::new(SynthConfig {
            seed: 0,
            width: cfg.width,
            ..Default::default()
        })?
        .render_frame(&rig, 0);
        let sampling = SweepSampling::new(&rig, &cfg)?;
        let images = frame
            .images
            .iter()
            .map(|img| input_tensor(img, cfg.width, &candle_core::Device::Cpu))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((sampling, images))
    };
    let (sampling, images) = match setup() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("photometric channel bench setup failed: {e}");
            return;
        }
    };
    let mut group = c.benchmark_group("photometric");
    group.sample_size(SAMPLES);
    group.measurement_time(MEASUREMENT_TIME);
    group.bench_function("ssmode_channel_256x128_4cam", |b| {
        b.iter(|| photometric_cost(&images, &sampling).map(|t| t.elem_count()))
    });
    group.finish();
}

criterion_group!(benches, photometric, photometric_channel);
criterion_main!(benches);
