//! Throughput of the custom tensor ops, in FLOP/s (criterion "elem/s" = FLOP/s here).
//!
//! `cargo bench --bench ops`

use candle_core::{DType, Device, Tensor};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mode360::geometry::{ErpGrid, PixelCoord};
use mode360::model::ops::{
    conv3d, conv3d_input_grad, conv3d_weight_grad, conv_transpose3d, table_sample, Conv3dGeometry,
    SampleTable,
};

/// The SSMODE-like cost-volume convolution: (B=1, D=24, H=64, W=128, 32 -> 32), 3x3x3.
const VOLUME: [usize; 5] = [1, 24, 64, 128, 32];
const C_OUT: usize = 32;
const KERNEL: [usize; 3] = [3, 3, 3];
const UNIT: [usize; 3] = [1, 1, 1];
const STRIDE2: [usize; 3] = [2, 2, 2];
/// Feature image for the sweep gather: 128 x 256 x 32, sampled at 48 x 64 x 128 points.
const ERP_WIDTH: usize = 256;
const FEATURE_CHANNELS: usize = 32;
const SWEEP_SAMPLES: [usize; 3] = [48, 64, 128];
/// FLOPs per output channel value of a 4-tap bilinear gather (4 multiply-adds).
const GATHER_FLOPS_PER_VALUE: usize = 8;

fn randn(dims: &[usize]) -> Tensor {
    Tensor::randn(0f32, 1f32, dims, &Device::Cpu).unwrap_or_else(|e| panic!("randn: {e}"))
}

fn bench_conv(c: &mut Criterion) {
    let [b, d, h, w, ci] = VOLUME;
    let g = Conv3dGeometry::new(b, [d, h, w], KERNEL, UNIT, UNIT, ci, C_OUT)
        .unwrap_or_else(|e| panic!("geometry: {e}"));
    let x = randn(&VOLUME);
    let wt = randn(&[3, 3, 3, ci, C_OUT]);
    let dy = randn(&[b, d, h, w, C_OUT]);
    let mut group = c.benchmark_group("conv3d");
    group.sample_size(10);
    group.throughput(Throughput::Elements(g.flops() as u64));
    group.bench_function("forward", |bench| {
        bench.iter(|| conv3d(&x, &wt, UNIT, UNIT).unwrap_or_else(|e| panic!("{e}")))
    });
    group.bench_function("input_grad", |bench| {
        bench.iter(|| {
            conv3d_input_grad(&dy, &wt, UNIT, UNIT, [d, h, w]).unwrap_or_else(|e| panic!("{e}"))
        })
    });
    group.bench_function("weight_grad", |bench| {
        bench.iter(|| {
            conv3d_weight_grad(&x, &dy, KERNEL, UNIT, UNIT).unwrap_or_else(|e| panic!("{e}"))
        })
    });
    // x2 upsampling (B, 12, 32, 64, 32) -> (B, 24, 64, 128, 32): the adjoint of a stride-2 conv
    let small = randn(&[b, d / 2, h / 2, w / 2, ci]);
    let g2 = Conv3dGeometry::new(b, [d, h, w], KERNEL, STRIDE2, UNIT, C_OUT, ci)
        .unwrap_or_else(|e| panic!("geometry: {e}"));
    group.throughput(Throughput::Elements(g2.flops() as u64));
    group.bench_function("transpose_x2", |bench| {
        bench.iter(|| {
            conv_transpose3d(&small, &wt, STRIDE2, UNIT, g2.output_padding())
                .unwrap_or_else(|e| panic!("{e}"))
        })
    });
    group.finish();
}

fn bench_table(c: &mut Criterion) {
    let grid = ErpGrid::new(ERP_WIDTH).unwrap_or_else(|e| panic!("grid: {e}"));
    let n: usize = SWEEP_SAMPLES.iter().product();
    let (h, w) = (grid.height(), grid.width());
    let taps: Vec<_> = (0..n)
        .map(|i| {
            // a smooth, non-trivial warp of the image, like a sweep sphere's projection
            let t = i as f64 / n as f64;
            grid.bilinear_taps(PixelCoord {
                u: (t * 977.0 * w as f64) % w as f64,
                v: (t * 31.0 * h as f64) % h as f64,
            })
        })
        .collect();
    let table = SampleTable::new(&taps);
    let features = randn(&[1, h, w, FEATURE_CHANNELS]);
    let grad = Tensor::ones((1, n, FEATURE_CHANNELS), DType::F32, &Device::Cpu)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut group = c.benchmark_group("table_sample");
    group.sample_size(10);
    group.throughput(Throughput::Elements(
        (n * FEATURE_CHANNELS * GATHER_FLOPS_PER_VALUE) as u64,
    ));
    group.bench_function("forward", |bench| {
        bench.iter(|| table_sample(&features, &table).unwrap_or_else(|e| panic!("{e}")))
    });
    group.bench_function("forward_backward", |bench| {
        let v = candle_core::Var::from_tensor(&features).unwrap_or_else(|e| panic!("{e}"));
        bench.iter(|| {
            let out = table_sample(v.as_tensor(), &table).unwrap_or_else(|e| panic!("{e}"));
            (out * &grad)
                .and_then(|t| t.sum_all())
                .and_then(|t| t.backward())
                .unwrap_or_else(|e| panic!("{e}"))
        })
    });
    group.finish();
}

/// The narrow layers of the shipped preset's aggregation at 256 (`bench-model`'s aggregation
/// stage), each over a slice of its volume's spheres to keep a sample short:
/// `(name, input (B, D, H, W, Cin), Cout, stride)`, kernel 3x3x3, padding 1.
const NARROW_LAYERS: [(&str, [usize; 5], usize, [usize; 3]); 4] = [
    // dres0.1 .. dres1.1 (and the hourglasses' last layer's size): 8 -> 8 at (48, 64, 132)
    ("co8", [1, 12, 64, 132, 8], 8, [1, 1, 1]),
    // hourglass conv2 and conv4: 16 -> 16 at (24, 32, 66)
    ("co16", [1, 24, 32, 66, 16], 16, [1, 1, 1]),
    // the entry convolution dres0.0: the 9-channel cost volume to 8, stride 2
    ("co8_entry", [1, 16, 128, 256, 9], 8, [2, 2, 2]),
    // the fine head's first layer: 9 -> 4, stride 2 over the spheres only
    ("co4_fine", [1, 16, 128, 256, 9], 4, [2, 1, 1]),
];

fn bench_conv_narrow(c: &mut Criterion) {
    let mut group = c.benchmark_group("conv3d_narrow");
    group.sample_size(10);
    for (name, dims, c_out, stride) in NARROW_LAYERS {
        let [b, d, h, w, ci] = dims;
        let g = Conv3dGeometry::new(b, [d, h, w], KERNEL, stride, UNIT, ci, c_out)
            .unwrap_or_else(|e| panic!("geometry: {e}"));
        let x = randn(&dims);
        let wt = randn(&[3, 3, 3, ci, c_out]);
        group.throughput(Throughput::Elements(g.flops() as u64));
        group.bench_function(name, |bench| {
            bench.iter(|| conv3d(&x, &wt, stride, UNIT).unwrap_or_else(|e| panic!("{e}")))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_conv, bench_conv_narrow, bench_table);
criterion_main!(benches);
