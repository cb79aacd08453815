//! Times every 3-D convolution of a preset's cost aggregation, regression head and fine head,
//! layer by layer, at the preset's sizes (random weights cost the same as trained ones): the
//! forward pass, and for the strided and unit-stride layers the two halves of their backward
//! pass (the input's and the weight's gradient), which training runs.
//!
//! `cargo run --release --example aggregation_layers -- [PRESET] [runs]` (default `parallax`)

use std::time::Instant;

use candle_core::{Device, Tensor};
use mode360::model::ops::{conv3d, conv3d_input_grad, conv3d_weight_grad, conv_transpose3d};
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
    let c_in = cfg.cost_volume_channels();
    let c = cfg.hourglass_channels;
    let (d1, h1, w1) = (d / s, h / s, w / s);
    let lay = |name, input, c_out, stride, up| Layer {
        name,
        input,
        c_out,
        stride,
        up,
    };
    let fine_head = (cfg.fine_head_channels > 0).then(|| {
        lay(
            "fine_head.cost s(2,1,1)",
            [d, h, w, c_in],
            cfg.fine_head_channels,
            0,
            false,
        )
    });
    let mut layers = vec![
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
    ];
    layers.extend(fine_head);
    layers
}

/// A layer's stride: 1, 2, or 0 for the fine head's `(2, 1, 1)`.
fn stride_of(l: &Layer) -> [usize; 3] {
    match l.stride {
        0 => [2, 1, 1],
        1 => UNIT,
        _ => STRIDE2,
    }
}

/// Median wall time of `runs` calls of `f` after one warm-up, seconds.
fn median_s<T>(
    runs: usize,
    mut f: impl FnMut() -> candle_core::Result<T>,
) -> candle_core::Result<f64> {
    f()?;
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        let t = Instant::now();
        f()?;
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    Ok(times[times.len() / 2])
}

fn main() -> candle_core::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let cfg = SsmodeConfig::preset(args.get(1).map_or("parallax", String::as_str))
        .map_err(|e| candle_core::Error::Msg(e.to_string()))?;
    let runs: usize = args.get(2).and_then(|r| r.parse().ok()).unwrap_or(5);
    println!(
        "| {} layer | input | Cout | forward ms | GFLOP/s | input grad ms | weight grad ms | GFLOP/s |",
        cfg.name
    );
    println!("|---|---|---|---|---|---|---|---|");
    for l in layers(&cfg) {
        let [d, h, w, ci] = l.input;
        let x = Tensor::randn(0f32, 1f32, (1, d, h, w, ci), &Device::Cpu)?;
        let wt = Tensor::randn(0f32, 0.1f32, (3, 3, 3, ci, l.c_out), &Device::Cpu)?;
        let stride = stride_of(&l);
        let run = || {
            if l.up {
                conv_transpose3d(&x, &wt, STRIDE2, UNIT, UNIT)
            } else {
                conv3d(&x, &wt, stride, UNIT)
            }
        };
        let y = run()?;
        let forward = median_s(runs, run)?;
        // transposed: every input cell meets 27 taps; forward: every output cell
        let out_cells = y.elem_count() / l.c_out;
        let macs = if l.up { d * h * w } else { out_cells } * 27 * ci * l.c_out;
        let gflop = 2.0 * macs as f64 / 1e9;
        let backward = if l.up {
            "| – | – | – |".to_string()
        } else {
            let dy = y.randn_like(0.0, 1.0)?;
            let dx = median_s(runs, || {
                conv3d_input_grad(&dy, &wt, stride, UNIT, [d, h, w])
            })?;
            let dw = median_s(runs, || {
                conv3d_weight_grad(&x, &dy, [3, 3, 3], stride, UNIT)
            })?;
            format!("| {:.1} | {:.1} | {:.1} |", dx * 1e3, dw * 1e3, gflop / dw)
        };
        println!(
            "| {} | {d}x{h}x{w}x{ci} | {} | {:.1} | {:.1} {backward}",
            l.name,
            l.c_out,
            forward * 1e3,
            gflop / forward
        );
    }
    Ok(())
}
