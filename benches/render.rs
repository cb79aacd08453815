//! Synthetic street rendering speed: one full rig frame (4 ERP views and the ground truth)
//! at 512x256 and 256x128, and the per-frame scene build.

use criterion::{criterion_group, criterion_main, Criterion};
use mode360::geometry::Rig;
use mode360::synth::{SynthConfig, SynthRenderer};
use std::hint::black_box;

fn rig() -> Option<Rig> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/launch_configs/rig_deep360.yaml"
    );
    match Rig::from_file(path) {
        Ok(r) => Some(r),
        Err(e) => {
            eprintln!("render bench skipped: {e}");
            None
        }
    }
}

fn bench_render(c: &mut Criterion) {
    let Some(rig) = rig() else { return };
    for (width, soiled) in [(512usize, false), (512, true), (256, false)] {
        let cfg = SynthConfig {
            width,
            soiled,
            ..SynthConfig::default()
        };
        let renderer = match SynthRenderer::new(cfg) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("render bench skipped: {e}");
                return;
            }
        };
        let mut index = 0usize;
        let name = format!(
            "render_frame_{width}x{}{}",
            width / 2,
            if soiled { "_soiled" } else { "" }
        );
        c.bench_function(&name, |b| {
            b.iter(|| {
                index += 1;
                black_box(renderer.render_frame(&rig, index))
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench_render
}
criterion_main!(benches);
