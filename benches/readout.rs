//! Seconds per frame of the SSMODE readout stages after the network, at the shipped network
//! width (256) and the node's default output width (512): the regression of the last cost
//! into range and confidence without and with the near mode
//! ([`mode360::model::regression::regress_inference`]), the edge refinement
//! ([`mode360::estimator::edge_refine`]) and the guided upsampling
//! ([`mode360::estimator::guided_upsample`]), on a rendered street frame's reference image and
//! a range with noise and edges.
//!
//! `cargo bench --bench readout`

use criterion::{criterion_group, criterion_main, Criterion};
use mode360::estimator::edge_refine::{rgb_on_grid, weighted_median_refine, EdgeRefineParams};
use mode360::estimator::guided_upsample::{grey_on_grid, guided_upsample};
use mode360::geometry::{ErpGrid, Rig};
use mode360::model::readout::{
    DEFAULT_NEAR_MODE_PROBABILITY, DEFAULT_REFINE_RADIUS_CELLS, NEAR_MODE_OFF,
};
use mode360::model::regression::{regress_inference, RangeReadout};
use mode360::model::SsmodeConfig;
use mode360::synth::{SynthConfig, SynthRenderer};

const RIG_PATH: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/launch_configs/rig_deep360.yaml"
);
const NET_WIDTH: usize = 256;
const OUTPUT_WIDTH: usize = 512;
const SAMPLES: usize = 20;

fn readout(c: &mut Criterion) {
    let setup = || -> Result<_, Box<dyn std::error::Error>> {
        let rig = Rig::from_file(RIG_PATH)?;
        let renderer = SynthRenderer::new(SynthConfig {
            seed: 0,
            width: OUTPUT_WIDTH,
            soiled: false,
            ..Default::default()
        })?;
        let frame = renderer.render_frame(&rig, 0);
        let image = frame
            .images
            .get(rig.reference)
            .ok_or("the rig has no reference image")?
            .clone();
        Ok((image, ErpGrid::new(NET_WIDTH)?, ErpGrid::new(OUTPUT_WIDTH)?))
    };
    let (image, net, out) = match setup() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("readout bench setup failed: {e}");
            return;
        }
    };
    let (Some(rgb), Some(grey_net), Some(grey_out)) = (
        rgb_on_grid(&image, net),
        grey_on_grid(&image, net),
        grey_on_grid(&image, out),
    ) else {
        eprintln!("readout bench: the rendered image is not ERP");
        return;
    };
    // Ranges from 1 to 1000 m with blocky edges, confidences in [0, 1].
    let range: Vec<f32> = (0..net.len())
        .map(|k| (((k * 7919) % 997) as f32 / 997.0 * 6.9).exp())
        .collect();
    let confidence: Vec<f32> = (0..net.len())
        .map(|k| ((k * 104_729) % 1000) as f32 / 1000.0)
        .collect();
    let params = EdgeRefineParams::with_radius(DEFAULT_REFINE_RADIUS_CELLS);
    let mut group = c.benchmark_group("readout");
    group.sample_size(SAMPLES);
    // the shipped preset's last cost: (1, D/2, H/2, W/2) with pseudo-random values
    let cfg = SsmodeConfig::parallax_zncc_log();
    let Ok(hypotheses) = cfg.output_hypotheses() else {
        eprintln!("readout bench: no hypotheses");
        return;
    };
    let dims = (1, cfg.hypotheses / 2, net.height() / 2, net.width() / 2);
    let values: Vec<f32> = (0..dims.1 * dims.2 * dims.3)
        .map(|k| ((k * 7919) % 1009) as f32 / 126.0 - 4.0)
        .collect();
    let Ok(cost) = candle_core::Tensor::from_vec(values, dims, &candle_core::Device::Cpu) else {
        eprintln!("readout bench: no cost tensor");
        return;
    };
    for (name, near_mode_probability) in [
        ("regress_256x128_near_mode_off", NEAR_MODE_OFF),
        ("regress_256x128_near_mode", DEFAULT_NEAR_MODE_PROBABILITY),
    ] {
        let readout = RangeReadout {
            near_mode_probability,
            ..RangeReadout::far_plane_only(0.5)
        };
        group.bench_function(name, |b| {
            b.iter(|| {
                regress_inference(&cost, &hypotheses, net.height(), net.width(), readout)
                    .map(|r| r.range_m.elem_count())
            })
        });
    }
    group.bench_function("edge_refine_256x128", |b| {
        b.iter(|| weighted_median_refine(&range, &confidence, &rgb, net, &params).len())
    });
    group.bench_function("guided_upsample_256_to_512", |b| {
        b.iter(|| guided_upsample(&range, &grey_net, net, &grey_out, out).len())
    });
    group.finish();
}

criterion_group!(benches, readout);
criterion_main!(benches);
