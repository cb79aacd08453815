//! Synthetic rendering speed: one full rig frame (4 ERP views and the ground truth) of streets
//! at 512x256 and 256x128, and of random objects and varied streets at 256x128 (objects trace
//! more primitives per ray; they should stay within about 2x of streets), with the per-frame
//! scene build.

use criterion::{criterion_group, criterion_main, Criterion};
use mode360::geometry::Rig;
use mode360::synth::{SceneKind, StreetStyle, SynthConfig, SynthRenderer};
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
    let cases = [
        (512usize, false, SceneKind::Street, StreetStyle::Regular, ""),
        (
            512,
            true,
            SceneKind::Street,
            StreetStyle::Regular,
            "_soiled",
        ),
        (256, false, SceneKind::Street, StreetStyle::Regular, ""),
        (
            256,
            false,
            SceneKind::Objects,
            StreetStyle::Regular,
            "_objects",
        ),
        (
            256,
            false,
            SceneKind::Street,
            StreetStyle::Varied,
            "_varied",
        ),
    ];
    for (width, soiled, scene, street, suffix) in cases {
        let cfg = SynthConfig {
            width,
            soiled,
            scene,
            street,
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
        let name = format!("render_frame_{width}x{}{suffix}", width / 2);
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
