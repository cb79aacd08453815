//! Throughput of the custom ops against their composites (GFLOP/s, forward and backward):
//! `cargo run --release --example ops_timing`. Each panics if the custom kernel is slower than
//! the composite. (criterion figures: `cargo bench --bench ops`.)

use std::time::Instant;

use candle_core::{Device, Tensor, Var};
use mode360::geometry::{ErpGrid, PixelCoord};
use mode360::model::ops::{
    conv3d, conv3d_composite, conv3d_input_grad, conv3d_weight_grad, conv_transpose3d, fine_mix,
    table_sample, table_sample_composite, upsample_trilinear, Conv3dGeometry, SampleTable,
};

const REPEATS: usize = 3;
const GIGA: f64 = 1e9;

/// Best wall time of `REPEATS` runs, seconds.
fn best_s(mut f: impl FnMut()) -> f64 {
    f(); // warm-up
    (0..REPEATS)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn randn(dims: &[usize]) -> Tensor {
    Tensor::randn(0f32, 1f32, dims, &Device::Cpu).unwrap()
}

fn conv3d_throughput() {
    let (d, h, w, c) = (24, 64, 128, 32);
    let unit = [1, 1, 1];
    let g = Conv3dGeometry::new(1, [d, h, w], [3, 3, 3], unit, unit, c, c).unwrap();
    let x = randn(&[1, d, h, w, c]);
    let wt = randn(&[3, 3, 3, c, c]);
    let dy = randn(&[1, d, h, w, c]);
    let gflop = g.flops() / GIGA;
    let fwd = best_s(|| {
        conv3d(&x, &wt, unit, unit).unwrap();
    });
    let dx = best_s(|| {
        conv3d_input_grad(&dy, &wt, unit, unit, [d, h, w]).unwrap();
    });
    let dw = best_s(|| {
        conv3d_weight_grad(&x, &dy, [3, 3, 3], unit, unit).unwrap();
    });
    let xv = Var::from_tensor(&x).unwrap();
    let wv = Var::from_tensor(&wt).unwrap();
    let fwd_bwd = best_s(|| {
        let y = conv3d(xv.as_tensor(), wv.as_tensor(), unit, unit).unwrap();
        (y * &dy).unwrap().sum_all().unwrap().backward().unwrap();
    });
    let composite = best_s(|| {
        conv3d_composite(&x, &wt, unit, unit).unwrap();
    });
    println!("conv3d (1,{d},{h},{w},{c}->{c}) k3 s1: {gflop:.2} GFLOP per pass");
    println!(
        "  forward      {:.1} ms  {:.1} GFLOP/s",
        fwd * 1e3,
        gflop / fwd
    );
    println!(
        "  input grad   {:.1} ms  {:.1} GFLOP/s",
        dx * 1e3,
        gflop / dx
    );
    println!(
        "  weight grad  {:.1} ms  {:.1} GFLOP/s",
        dw * 1e3,
        gflop / dw
    );
    println!(
        "  fwd+bwd      {:.1} ms  {:.1} GFLOP/s",
        fwd_bwd * 1e3,
        3.0 * gflop / fwd_bwd
    );
    println!(
        "  composite fwd {:.1} ms  {:.1} GFLOP/s",
        composite * 1e3,
        gflop / composite
    );

    // x2 transposed conv (1, 12, 32, 64, 32) -> (1, 24, 64, 128, 32)
    let s2 = [2, 2, 2];
    let g2 = Conv3dGeometry::new(1, [d, h, w], [3, 3, 3], s2, unit, c, c).unwrap();
    let small = randn(&[1, d / 2, h / 2, w / 2, c]);
    let tr = best_s(|| {
        conv_transpose3d(&small, &wt, s2, unit, g2.output_padding()).unwrap();
    });
    println!(
        "  transpose x2 {:.1} ms  {:.1} GFLOP/s",
        tr * 1e3,
        g2.flops() / GIGA / tr
    );
    assert!(
        fwd < composite,
        "custom {fwd} s slower than composite {composite} s"
    );
}

fn table_sample_throughput() {
    let grid = ErpGrid::new(256).unwrap();
    let (h, w, c) = (grid.height(), grid.width(), 32);
    let n = 48 * 64 * 128;
    let taps: Vec<_> = (0..n)
        .map(|i| {
            let t = i as f64 / n as f64;
            grid.bilinear_taps(PixelCoord {
                u: (t * 977.0 * w as f64) % w as f64,
                v: (t * 31.0 * h as f64) % h as f64,
            })
        })
        .collect();
    let table = SampleTable::new(&taps);
    let f = randn(&[1, h, w, c]);
    let fv = Var::from_tensor(&f).unwrap();
    let g = Tensor::ones((1, n, c), candle_core::DType::F32, &Device::Cpu).unwrap();
    let fwd = best_s(|| {
        table_sample(&f, &table).unwrap();
    });
    let fwd_bwd = best_s(|| {
        let out = table_sample(fv.as_tensor(), &table).unwrap();
        (out * &g).unwrap().sum_all().unwrap().backward().unwrap();
    });
    // the loss and its own backward, to isolate the gather's backward
    let out_fixed = table_sample(&f, &table).unwrap();
    let ov = Var::from_tensor(&out_fixed).unwrap();
    let loss_only = best_s(|| {
        (ov.as_tensor() * &g)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
    });
    let comp = best_s(|| {
        table_sample_composite(&f, &table).unwrap();
    });
    let comp_bwd = best_s(|| {
        let out = table_sample_composite(fv.as_tensor(), &table).unwrap();
        (out * &g).unwrap().sum_all().unwrap().backward().unwrap();
    });
    let out_gb = (n * c * 4) as f64 / GIGA;
    println!("table_sample ({h}x{w}x{c}, N={n}): output {out_gb:.3} GB");
    println!(
        "  custom    fwd {:.1} ms, fwd+bwd {:.1} ms",
        fwd * 1e3,
        fwd_bwd * 1e3
    );
    println!(
        "  custom backward alone ~{:.1} ms (fwd+bwd - fwd - loss {:.1} ms)",
        (fwd_bwd - fwd - loss_only) * 1e3,
        loss_only * 1e3
    );
    println!(
        "  composite fwd {:.1} ms, fwd+bwd {:.1} ms",
        comp * 1e3,
        comp_bwd * 1e3
    );
    assert!(fwd < comp, "custom {fwd} s slower than composite {comp} s");
}

/// The fine head's parts at a training step's shapes (256 input: a volume of 96 spheres,
/// 128 x 256 cells, 9 channels; the head's 4 channels at stride 2 over spheres), forward and
/// backward each, and the regression's upsampling with and without the head.
fn fine_head_parts() {
    let (d, h, w, c, cf, s) = (96, 128, 256, 9, 4, 2);
    let stride = [s, 1, 1];
    let unit = [1, 1, 1];
    let volume = randn(&[1, d, h, w, c]);
    let weight = Var::from_tensor(&randn(&[3, 3, 3, c, cf])).unwrap();
    let g = Conv3dGeometry::new(1, [d, h, w], [3, 3, 3], stride, unit, c, cf).unwrap();
    let gflop = g.flops() / GIGA;
    let cost_fwd = best_s(|| {
        conv3d(&volume, weight.as_tensor(), stride, unit).unwrap();
    });
    let cost_fwd_bwd = best_s(|| {
        let y = conv3d(&volume, weight.as_tensor(), stride, unit).unwrap();
        y.sum_all().unwrap().backward().unwrap();
    });
    println!(
        "fine head cost conv (1,{d},{h},{w},{c}->{cf}) stride {stride:?}: {gflop:.2} GFLOP; \
         forward {:.0} ms ({:.1} GFLOP/s), forward+weight grad {:.0} ms",
        cost_fwd * 1e3,
        gflop / cost_fwd,
        cost_fwd_bwd * 1e3
    );
    let coarse = Var::from_tensor(&randn(&[1, d / s, h / s, w / s])).unwrap();
    let part = Var::from_tensor(&randn(&[1, d / s, h, w, cf])).unwrap();
    let mix = Var::from_tensor(&randn(&[2, cf])).unwrap();
    let up_fwd_bwd = best_s(|| {
        let up = upsample_trilinear(coarse.as_tensor(), d / s, h, w).unwrap();
        up.sum_all().unwrap().backward().unwrap();
    });
    let mix_fwd_bwd = best_s(|| {
        let up = upsample_trilinear(coarse.as_tensor(), d / s, h, w).unwrap();
        let fine = fine_mix(&up, part.as_tensor(), mix.as_tensor()).unwrap();
        fine.sum_all().unwrap().backward().unwrap();
    });
    println!(
        "  coarse upsampled to (1,{},{h},{w}): forward+backward {:.0} ms; with fine_mix {:.0} ms",
        d / s,
        up_fwd_bwd * 1e3,
        mix_fwd_bwd * 1e3
    );
    let fine = Var::from_tensor(&randn(&[1, d / s, h, w])).unwrap();
    let regress_up = |x: &Tensor| {
        best_s(|| {
            let up = upsample_trilinear(x, d, h, w).unwrap();
            up.sum_all().unwrap().backward().unwrap();
        })
    };
    println!(
        "  regression's upsampling to (1,{d},{h},{w}), forward+backward: from the coarse cost \
         {:.0} ms, from the head's {:.0} ms",
        regress_up(coarse.as_tensor()) * 1e3,
        regress_up(fine.as_tensor()) * 1e3
    );
}

fn main() {
    conv3d_throughput();
    table_sample_throughput();
    fine_head_parts();
}
