//! Times every 3-D convolution of a preset's cost aggregation and regression head, layer by
//! layer, at the preset's inference sizes (random weights cost the same as trained ones).
//!
//! `cargo run --release --example aggregation_layers -- [parallax|compact] [runs]`

use std::time::Instant;

use candle_core::{Device, Tensor};
use mode360::model::ops::{conv3d, conv_transpose3d};
use mode360::model::SsmodeConfig;

const UNIT: [usize; 3] = [1, 1, 1];
const STRIDE2: [usize; 3] = [2, 2, 2];

/// One layer: name, input `(D, H, W, Cin)`, `Cout`, stride (1 or 2), transposed x2.
struct Layer {
    name: &'static str,
    input: [usize; 4],
    c_out: usize,
    stride: usize,
    up: bool,
}

fn layers(cfg: &SsmodeConfig) -> Vec<Layer> {
    let s = cfg.aggregation_stride;
    let (d, h, w) = (
        cfg.spheres,
        cfg.height() / cfg.cost_downsample,
        cfg.cost_width(),
    );
    let c_in = cfg.cost.channels(cfg.matching_channels());
    let c = cfg.hourglass_channels;
    let (d1, h1, w1) = (d / s, h / s, w / s);
    let lay = |name, input, c_out, stride, up| Layer {
        name,
        input,
        c_out,
        stride,
        up,
    };
    vec![
        lay("dres0.0", [d, h, w, c_in], c, s, false),
        lay("dres0.1 / dres1.x (x3)", [d1, h1, w1, c], c, 1, false),
        lay("hg.conv1 s2", [d1, h1, w1, c], 2 * c, 2, false),
        lay("hg.conv2", [d1 / 2, h1 / 2, w1 / 2, 2 * c], 2 * c, 1, false),
        lay(
            "hg.conv3 s2",
            [d1 / 2, h1 / 2, w1 / 2, 2 * c],
            2 * c,
            2,
            false,
        ),
        lay("hg.conv4", [d1 / 4, h1 / 4, w1 / 4, 2 * c], 2 * c, 1, false),
        lay(
            "hg.conv5 up",
            [d1 / 4, h1 / 4, w1 / 4, 2 * c],
            2 * c,
            2,
            true,
        ),
        lay("hg.conv6 up", [d1 / 2, h1 / 2, w1 / 2, 2 * c], c, 2, true),
        lay("classif.conv0", [d1, h1, w1, c], c, 1, false),
        lay("classif.conv1", [d1, h1, w1, c], 1, 1, false),
    ]
}

fn main() -> candle_core::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let cfg = match args.get(1).map(String::as_str) {
        Some("compact") => SsmodeConfig::compact(),
        _ => SsmodeConfig::parallax(),
    };
    let runs: usize = args.get(2).and_then(|r| r.parse().ok()).unwrap_or(5);
    println!(
        "| {} layer | input | Cout | median ms | GFLOP/s |",
        cfg.name
    );
    println!("|---|---|---|---|---|");
    for l in layers(&cfg) {
        let [d, h, w, ci] = l.input;
        let x = Tensor::randn(0f32, 1f32, (1, d, h, w, ci), &Device::Cpu)?;
        let wt = Tensor::randn(0f32, 0.1f32, (3, 3, 3, ci, l.c_out), &Device::Cpu)?;
        let stride = if l.stride == 2 { STRIDE2 } else { UNIT };
        let run = || {
            if l.up {
                conv_transpose3d(&x, &wt, STRIDE2, UNIT, UNIT)
            } else {
                conv3d(&x, &wt, stride, UNIT)
            }
        };
        let mut times = Vec::with_capacity(runs);
        let mut out_cells = 0;
        run()?;
        for _ in 0..runs {
            let t = Instant::now();
            let y = run()?;
            times.push(t.elapsed().as_secs_f64());
            out_cells = y.elem_count() / l.c_out;
        }
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        // transposed: every input cell meets 27 taps; forward: every output cell
        let macs = if l.up { d * h * w } else { out_cells } * 27 * ci * l.c_out;
        println!(
            "| {} | {d}x{h}x{w}x{ci} | {} | {:.1} | {:.1} |",
            l.name,
            l.c_out,
            median * 1e3,
            2.0 * macs as f64 / median / 1e9
        );
    }
    Ok(())
}
