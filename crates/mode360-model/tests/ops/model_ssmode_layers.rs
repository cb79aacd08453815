//! SSMODE's layers against independent computations: the cost volume samples features where
//! the sweep geometry says (mean and variance across cameras) and its variance vanishes where
//! every camera sees the same feature; the fused inference regression equals the training
//! path; the aggregation fed the volume in slabs equals the aggregation of the whole volume.

use crate::common::deep360_rig as rig;
use candle_core::{Device, Tensor};
use mode360_core::geometry::{ErpGrid, PixelCoord};
use mode360_model::model::config::CostKind;
use mode360_model::model::cost_volume::cost_volume;
use mode360_model::model::{SsmodeConfig, SweepSampling};

#[test]
fn cost_volume_samples_features_where_the_sweep_geometry_says() {
    let cfg = SsmodeConfig::tiny();
    let rig = rig();
    let sampling = SweepSampling::new(&rig, &cfg).expect("sampling");
    let geo = sampling.geometry();
    let grid: ErpGrid = geo.output();
    let (h, w, c) = (grid.height(), grid.width(), 2usize);
    // Feature of camera k, pixel p, channel ch: a smooth but non-trivial function.
    let feat = |k: usize, p: usize, ch: usize| -> f32 {
        ((p * 7 + k * 13 + ch * 5) % 23) as f32 / 23.0 + ch as f32
    };
    let cameras = rig.cameras.len();
    let features: Vec<Tensor> = (0..cameras)
        .map(|k| {
            let data: Vec<f32> = (0..h * w)
                .flat_map(|p| (0..c).map(move |ch| feat(k, p, ch)))
                .collect();
            Tensor::from_vec(data, (1, h, w, c), &Device::Cpu).unwrap()
        })
        .collect();
    let volume = cost_volume(
        &Tensor::cat(&features, 0).unwrap(),
        &sampling,
        CostKind::MeanVariance,
    )
    .expect("cost volume");
    assert_eq!(volume.dims(), &[1, cfg.spheres, h, w, 2 * c]);
    let vol: Vec<f32> = volume.flatten_all().unwrap().to_vec1().unwrap();
    let mut checked = 0;
    for sphere in [0, cfg.spheres / 2, cfg.spheres - 1] {
        for (u, v) in [
            (0usize, 0usize),
            (3, 2),
            (w - 1, h / 2),
            (w / 2, h - 1),
            (5, 5),
        ] {
            for ch in 0..c {
                let samples: Vec<f64> = (0..cameras)
                    .map(|k| {
                        let q = geo.sample(
                            k,
                            sphere,
                            PixelCoord {
                                u: u as f64,
                                v: v as f64,
                            },
                        );
                        let taps = geo.camera_grid(k).bilinear_taps(q);
                        taps.index
                            .iter()
                            .zip(taps.weight.iter())
                            .map(|(&i, &wt)| wt as f64 * feat(k, i as usize, ch) as f64)
                            .sum()
                    })
                    .collect();
                let n = cameras as f64;
                let mean = samples.iter().sum::<f64>() / n;
                let var = samples.iter().map(|x| x * x).sum::<f64>() / n - mean * mean;
                let base = (((sphere * h + v) * w) + u) * 2 * c;
                assert!(
                    (vol[base + ch] as f64 - mean).abs() < 1e-4,
                    "mean at {sphere},{v},{u}"
                );
                assert!(
                    (vol[base + c + ch] as f64 - var).abs() < 1e-3,
                    "var at {sphere},{v},{u}"
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 3 * 5 * c);
}

#[test]
fn fused_inference_regression_equals_the_training_path() {
    use mode360_model::model::regression::{confidence, regress, regress_inference, RangeReadout};
    let cfg = SsmodeConfig::tiny();
    let hyps = cfg.output_hypotheses().expect("hypotheses");
    let (height, width) = (18, 36);
    // Far fields of 1 to 4 hypotheses per pixel, for the cases that test them.
    let counts: Vec<u16> = (0..height * width)
        .map(|k| (k * 31 % 4) as u16 + 1)
        .collect();
    let cases = [
        (0.5f32, 0.7, false),
        (8.0, 0.7, false),
        (8.0, 0.3, false),
        (8.0, 2.0, false),
        (8.0, 0.7, true),
        (8.0, 0.3, true),
    ];
    for (scale, far, with_counts) in cases {
        let far_counts = with_counts.then_some(counts.as_slice());
        let far_of =
            |pixel: usize| far_counts.map_or(1, |c| usize::from(c[pixel % (height * width)]));
        // (B, D, h, w) with odd h and w; fixed pseudo-random values in [-scale, scale] so the
        // share of tied pixels (skipped below) is the same on every run
        const DIMS: (usize, usize, usize, usize) = (2, 5, 5, 9);
        let values: Vec<f32> = (0..DIMS.0 * DIMS.1 * DIMS.2 * DIMS.3)
            .map(|i| ((i * 7919 + 13) % 1009) as f32 / 504.5 - 1.0)
            .map(|v| v * scale)
            .collect();
        let cost = Tensor::from_vec(values, DIMS, &Device::Cpu).unwrap();
        let readout = RangeReadout {
            far_counts,
            ..RangeReadout::far_plane_only(far)
        };
        let slow = regress(&cost, &hyps, height, width, readout).unwrap();
        let slow_conf = confidence(&slow.probabilities).unwrap();
        let fast = regress_inference(&cost, &hyps, height, width, readout).unwrap();
        let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let max_abs = |a: &Tensor, b: &Tensor| {
            flat(a)
                .iter()
                .zip(flat(b))
                .map(|(x, y)| (x - y).abs())
                .fold(0f32, f32::max)
        };
        assert_eq!(fast.range_m.dims(), [2, height, width]);
        assert!(max_abs(&fast.inverse_depth_index, &slow.inverse_depth_index) < 1e-5);
        // The confidence window sits on the argmax; where two hypotheses tie (to rounding,
        // e.g. at the clamped ends of the interpolation) either choice is right, so such
        // pixels are skipped; every other pixel must agree.
        let n = hyps.count();
        let probs = slow
            .probabilities
            .permute((0, 2, 3, 1))
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let (a, b) = (flat(&fast.confidence), flat(&slow_conf));
        let mut compared = 0;
        for i in 0..a.len() {
            let mut p = probs[i * n..(i + 1) * n].to_vec();
            p.sort_by(|x, y| y.total_cmp(x));
            if p[0] - p[1] <= 1e-6 * p[0] {
                continue;
            }
            compared += 1;
            assert!(
                (a[i] - b[i]).abs() < 1e-5,
                "pixel {i}: confidence {} vs {}",
                a[i],
                b[i]
            );
        }
        assert!(compared * 2 > a.len(), "only {compared} untied pixels");
        // Far-plane readout: exactly the pixels whose far field (p_0 alone without counts)
        // holds at least `far` read max depth, in both paths.
        let max_depth = hyps.depth_m(0.0) as f32;
        let far_mass = |i: usize| -> f64 {
            probs[i * n..i * n + far_of(i)]
                .iter()
                .map(|&p| f64::from(p))
                .sum()
        };
        let expected_far = (0..a.len()).filter(|&i| far_mass(i) >= far).count();
        if with_counts {
            let alone = (0..a.len())
                .filter(|&i| f64::from(probs[i * n]) >= far)
                .count();
            assert!(expected_far > alone, "the far field adds no pixel at {far}");
        }
        for range in [&fast.range_m, &slow.range_m] {
            let snapped = flat(range).iter().filter(|&&r| r == max_depth).count();
            assert_eq!(snapped, expected_far, "far-plane pixels at threshold {far}");
        }
        if far < 0.5 {
            assert!(expected_far > 0, "no pixel reached the far plane at {far}");
        }
        let rel = flat(&fast.range_m)
            .iter()
            .zip(flat(&slow.range_m))
            .map(|(x, y)| ((x - y) / y).abs())
            .fold(0f32, f32::max);
        assert!(rel < 1e-4, "range differs by {rel} relative");
    }
}

/// Costs `(1, N, 1, pixels)` whose softmax is each pixel's `probabilities` (N each).
fn cost_of_probabilities(pixels: &[Vec<f32>]) -> Tensor {
    let n = pixels[0].len();
    let mut data = vec![0f32; n * pixels.len()];
    for (k, p) in pixels.iter().enumerate() {
        for (i, &x) in p.iter().enumerate() {
            data[i * pixels.len() + k] = x.max(1e-12).ln();
        }
    }
    Tensor::from_vec(data, (1, n, 1, pixels.len()), &Device::Cpu).unwrap()
}

#[test]
fn the_near_mode_reads_a_near_obstacle_the_expectation_melts_into_the_background() {
    use mode360_model::model::regression::{
        regress, regress_inference, RangeReadout, NEAR_MODE_MAX_RANGE_M, NEAR_MODE_RATIO,
    };
    // the shipped preset's hypotheses: 96 uniform in log depth over 0.5 to 1000 m
    let cfg = SsmodeConfig::parallax_zncc_log();
    let hyps = cfg.output_hypotheses().expect("hypotheses");
    let n = hyps.count();
    let index_of = |range_m: f64| hyps.index_of_depth(range_m).round() as usize;
    // two modes, `near_share` of the mass on hypothesis `near`, the rest on `far`, each
    // spread over its neighbours 1:2:1
    let bimodal = |near: usize, far: usize, near_share: f32| -> Vec<f32> {
        let mut p = vec![1e-6f32; n];
        for (centre, share) in [(near, near_share), (far, 1.0 - near_share)] {
            for (d, w) in [(-1i64, 0.25f32), (0, 0.5), (1, 0.25)] {
                let i = (centre as i64 + d).clamp(0, n as i64 - 1) as usize;
                p[i] += share * w;
            }
        }
        p
    };
    let pole = index_of(3.0);
    let facade = index_of(40.0);
    let beyond = index_of(f64::from(NEAR_MODE_MAX_RANGE_M) * 1.6);
    let pixels = vec![
        // a pole at 3 m with 30 % of the mass in front of a facade at 40 m
        bimodal(pole, facade, 0.3),
        // the same with 10 %: below the threshold
        bimodal(pole, facade, 0.1),
        // a nearer mode beyond the near mode's range
        bimodal(beyond, facade, 0.3),
        // one mode: the expectation
        bimodal(pole, pole, 0.5),
    ];
    let cost = cost_of_probabilities(&pixels);
    let readout = RangeReadout {
        near_mode_probability: 0.2,
        ..RangeReadout::far_plane_only(2.0)
    };
    let off = RangeReadout::far_plane_only(2.0);
    let read = |r: RangeReadout| -> [Vec<f32>; 2] {
        let fast = regress_inference(&cost, &hyps, 1, pixels.len(), r).unwrap();
        let slow = regress(&cost, &hyps, 1, pixels.len(), r).unwrap();
        let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        [flat(&fast.range_m), flat(&slow.range_m)]
    };
    let with = read(readout);
    let without = read(off);
    for [fast, slow] in [&with, &without] {
        for (a, b) in fast.iter().zip(slow) {
            assert!(((a - b) / b).abs() < 1e-4, "fused {a} against unfused {b}");
        }
    }
    let (with, without) = (&with[0], &without[0]);
    let pole_m = hyps.depth_m(pole as f64) as f32;
    // the expectation lands between the modes, well behind the pole
    assert!(without[0] > 2.0 * pole_m, "expectation {} m", without[0]);
    assert!(
        (with[0] / pole_m - 1.0).abs() < 0.02,
        "near mode {} m against the pole's {pole_m} m",
        with[0]
    );
    assert_eq!(with[1], without[1], "a 10 % mode is below the threshold");
    assert!(
        hyps.depth_m(beyond as f64) as f32 > NEAR_MODE_MAX_RANGE_M
            && without[2] > NEAR_MODE_RATIO * NEAR_MODE_MAX_RANGE_M,
        "the case does not test the range limit"
    );
    assert_eq!(
        with[2], without[2],
        "a mode beyond {NEAR_MODE_MAX_RANGE_M} m"
    );
    assert_eq!(with[3], without[3], "one mode reads its expectation");
}

#[test]
fn variance_volume_is_zero_where_every_camera_sees_the_same_feature() {
    // Identical features in every camera: on the far sphere every camera looks along the same
    // directions (the rig is 1 m across, the sphere 100 m away), so the variance there is
    // about zero; on the nearest sphere the cameras disagree.
    let cfg = SsmodeConfig::tiny_parallax();
    let sampling = SweepSampling::new(&rig(), &cfg).expect("sampling");
    // A smooth pattern (a tenth of a cell of parallax barely changes it).
    let (h, w) = (cfg.cost_height(), cfg.cost_width());
    let data: Vec<f32> = (0..h * w * 3)
        .map(|k| {
            let (v, u, ch) = (k / (3 * w), (k / 3) % w, k % 3);
            let lon = 2.0 * std::f32::consts::PI * u as f32 / w as f32;
            ((ch + 1) as f32 * lon + 0.2 * v as f32).sin()
        })
        .collect();
    let f = Tensor::from_vec(data, (1, h, w, 3), &Device::Cpu).unwrap();
    let features = vec![f.clone(), f.clone(), f.clone(), f];
    let volume = cost_volume(
        &Tensor::cat(&features, 0).unwrap(),
        &sampling,
        CostKind::Variance,
    )
    .expect("volume");
    let (b, d, h, w, c) = volume.dims5().expect("rank 5");
    assert_eq!(
        (b, d, h, w, c),
        (1, cfg.spheres, cfg.cost_height(), cfg.cost_width(), 3)
    );
    let mean_on = |sphere: usize| -> f32 {
        volume
            .narrow(1, sphere, 1)
            .unwrap()
            .mean_all()
            .unwrap()
            .to_scalar()
            .unwrap()
    };
    let (far, near) = (mean_on(0), mean_on(d - 1));
    assert!(
        far < 0.1 * near,
        "far sphere variance {far}, nearest {near}"
    );
}

/// Inference feeds the aggregation the cost volume a few spheres at a time
/// (`CostAggregation::forward_slabs`): with slabs that split the spheres unevenly, at entry
/// strides 2 and 1 (whose last slab needs the zero padding appended), every hourglass output
/// equals the whole volume's bit for bit, and the slabs asked for cover every sphere. So does
/// the fine head's first layer run on the same slabs.
#[test]
fn aggregation_in_slabs_equals_the_whole_volume() {
    use candle_core::DType;
    use candle_nn::{VarBuilder, VarMap};
    use mode360_model::model::fine_head::FineHead;
    use mode360_model::model::hourglass::{CostAggregation, SLAB_OUTPUT_SPHERES};
    for (stride, spheres) in [(2, 40), (1, 24)] {
        let cfg = SsmodeConfig {
            spheres,
            aggregation_stride: stride,
            fine_head_channels: 3,
            ..SsmodeConfig::tiny_zncc()
        };
        assert!(
            spheres / stride > 2 * SLAB_OUTPUT_SPHERES,
            "three slabs at least"
        );
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        CostAggregation::new(&cfg, vb.clone()).expect("aggregation");
        FineHead::new(&cfg, vb.pp("fine_head")).expect("fine head");
        // the same weights as plain tensors: both paths run the inference kernels
        let weights = varmap
            .data()
            .lock()
            .expect("varmap")
            .iter()
            .map(|(k, v)| (k.clone(), v.as_tensor().detach()))
            .collect();
        let vb = VarBuilder::from_tensors(weights, DType::F32, &Device::Cpu);
        let aggregation = CostAggregation::new(&cfg, vb.clone()).expect("aggregation");
        let head = FineHead::new(&cfg, vb.pp("fine_head")).expect("fine head");
        let dims = (
            1,
            spheres,
            cfg.cost_height(),
            cfg.cost_width(),
            cfg.cost_volume_channels(),
        );
        let volume = Tensor::rand(0f32, 1f32, dims, &Device::Cpu).expect("volume");
        let whole = aggregation
            .forward(&volume, cfg.seam_pad_cells)
            .expect("whole");
        let whole_side = head.cost_part(&volume).expect("fine head, whole");
        let mut asked = vec![0usize; spheres];
        let (slabs, side) = aggregation
            .forward_slabs(
                spheres,
                |range| {
                    range.clone().for_each(|d| asked[d] += 1);
                    volume.narrow(1, range.start, range.len())?.contiguous()
                },
                cfg.seam_pad_cells,
                Some(head.cost_conv()),
            )
            .expect("slabs");
        let side = side.expect("the fine head's slabs");
        assert!(asked.iter().all(|&k| k >= 1), "stride {stride}: {asked:?}");
        assert_eq!(whole.len(), slabs.len());
        let bits = |t: &Tensor| -> Vec<u32> {
            t.flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
                .into_iter()
                .map(f32::to_bits)
                .collect()
        };
        assert_eq!(
            whole_side.dims(),
            [
                1,
                spheres.div_ceil(stride),
                cfg.cost_height(),
                cfg.cost_width(),
                3
            ]
        );
        for (a, b) in whole.iter().zip(&slabs).chain([(&whole_side, &side)]) {
            assert_eq!(a.dims(), b.dims(), "stride {stride}");
            assert!(
                bits(a) == bits(b),
                "stride {stride}: slabs differ from the whole volume"
            );
        }
    }
}

/// `Ssmode::forward_fine_head_only` computes the network's final stage (range and confidence
/// as the full training forward computes them), and its gradient reaches the fine head's
/// variables and no other: the rest of the network is frozen. A network without the head is
/// refused by name.
#[test]
fn training_the_fine_head_alone_reads_the_final_stage_and_moves_only_the_head() {
    use crate::common::{pseudo_random, seed_weights, tensor, values};
    use candle_core::DType;
    use candle_nn::{VarBuilder, VarMap};
    use mode360_model::model::Ssmode;
    let cfg = SsmodeConfig {
        fine_head_channels: 3,
        ..SsmodeConfig::tiny_zncc()
    };
    let rig = rig();
    let varmap = VarMap::new();
    let net = Ssmode::new(
        &cfg,
        VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu),
    )
    .expect("network");
    // reproducible weights, and the head's output layer (which starts at zero) set, so that
    // the head changes the output
    seed_weights(&varmap, 3);
    varmap.data().lock().expect("varmap")["fine_head.out.weight"]
        .set(&tensor(&[0.5, -0.3, 0.8], &[3]))
        .expect("set the head's output weights");
    let sampling = SweepSampling::new(&rig, &cfg).expect("sampling");
    let images: Vec<Tensor> = (0..rig.cameras.len())
        .map(|c| {
            let n = cfg.height() * cfg.width * 3;
            let v: Vec<f64> = pseudo_random(n, 60 + c as u64)
                .iter()
                .map(|x| 0.5 + 0.5 * x)
                .collect();
            tensor(&v, &[1, cfg.height(), cfg.width, 3])
        })
        .collect();
    let full = net.forward(&images, &sampling, true).expect("full forward");
    let head = net
        .forward_fine_head_only(&images, &sampling)
        .expect("head-only forward");
    assert_eq!(head.stages.len(), 1, "the final stage alone");
    let close = |what: &str, a: &Tensor, b: &Tensor| {
        let (a, b) = (values(a), values(b));
        let err = crate::common::max_abs_diff(&a, &b);
        assert!(err <= 1e-6, "{what}: differs by {err}");
    };
    close(
        "range",
        &head.stages[0],
        full.stages.last().expect("stages"),
    );
    close("confidence", &head.confidence, &full.confidence);
    let loss = (&head.inverse_depth_stages[0] - 0.3)
        .and_then(|d| d.sqr())
        .and_then(|d| d.mean_all())
        .expect("loss");
    let grads = loss.backward().expect("backward");
    let data = varmap.data().lock().expect("varmap");
    let mut head_vars = 0;
    for (name, var) in data.iter() {
        let grad = grads.get(var.as_tensor());
        if name.starts_with("fine_head.") {
            let g = grad.unwrap_or_else(|| panic!("no gradient for {name}"));
            assert!(values(g).iter().any(|v| *v != 0.0), "{name}: zero gradient");
            head_vars += 1;
        } else {
            assert!(grad.is_none(), "{name} got a gradient; it is frozen");
        }
    }
    assert_eq!(head_vars, 4, "cost.weight, cost.bias, coarse and out");
    drop(data);

    let plain = Ssmode::new(
        &SsmodeConfig::tiny_zncc(),
        VarBuilder::zeros(DType::F32, &Device::Cpu),
    )
    .expect("network without a head");
    let sampling = SweepSampling::new(&rig, &SsmodeConfig::tiny_zncc()).expect("sampling");
    let err = plain
        .forward_fine_head_only(&images, &sampling)
        .expect_err("a network without the head")
        .to_string();
    assert!(err.contains("no fine head"), "{err}");
}
