//! table_sample and trilinear upsampling: against nested-loop f64 references, gradients against
//! central differences, custom == composite.

use crate::common::{dot, max_abs_diff, pseudo_random, tensor, values};
use candle_core::{Device, Tensor, Var};
use mode360_core::geometry::{ErpGrid, PixelCoord};
use mode360_model::model::ops::{
    resample_linear_axis, sweep_variance, sweep_variance_visible, table_sample,
    table_sample_composite, upsample_trilinear, upsample_trilinear_composite, view_scale,
    SampleTable,
};

const FWD_TOL: f64 = 1e-5;
const GRAD_TOL: f64 = 1e-4;
const FD_STEP: f64 = 1e-3;

/// Gradient of `<f(v), r>` by central differences in every coordinate.
fn fd_gradient(v: &[f64], f: impl Fn(&[f64]) -> Vec<f64>, r: &[f64]) -> Vec<f64> {
    (0..v.len())
        .map(|i| {
            let mut p = v.to_vec();
            p[i] += FD_STEP;
            let lp = dot(&f(&p), r);
            p[i] -= 2.0 * FD_STEP;
            (lp - dot(&f(&p), r)) / (2.0 * FD_STEP)
        })
        .collect()
}

/// Bilinear sampling of an ERP image `(H, W, C)` at continuous `(u, v)`, written directly from
/// the wrap-around / clamp rules (not through `BilinearTaps`).
fn erp_bilinear_ref(img: &[f64], h: usize, w: usize, c: usize, p: PixelCoord) -> Vec<f64> {
    let u0 = p.u.floor();
    let fu = p.u - u0;
    let v = p.v.clamp(0.0, (h - 1) as f64);
    let v0 = v.floor();
    let fv = v - v0;
    let col = |k: f64| (k as i64).rem_euclid(w as i64) as usize;
    let row = |k: f64| (k as usize).min(h - 1);
    let at = |r: usize, q: usize, ch: usize| img[(r * w + q) * c + ch];
    (0..c)
        .map(|ch| {
            (1.0 - fu) * (1.0 - fv) * at(row(v0), col(u0), ch)
                + fu * (1.0 - fv) * at(row(v0), col(u0 + 1.0), ch)
                + (1.0 - fu) * fv * at(row(v0 + 1.0), col(u0), ch)
                + fu * fv * at(row(v0 + 1.0), col(u0 + 1.0), ch)
        })
        .collect()
}

#[test]
fn table_sample_matches_bilinear_reference_across_the_seam() {
    let grid = ErpGrid::new(10).unwrap(); // 5 x 10
    let (h, w, c, b) = (grid.height(), grid.width(), 3, 2);
    // positions everywhere, including across the u = 0 / u = W seam and beyond the poles
    let mut coords: Vec<PixelCoord> = pseudo_random(40, 7)
        .chunks(2)
        .map(|p| PixelCoord {
            u: (p[0] + 1.0) * 0.5 * w as f64 - 0.5,
            v: (p[1] + 1.0) * 0.5 * h as f64 - 0.5,
        })
        .collect();
    coords.push(PixelCoord { u: 9.7, v: 2.3 });
    coords.push(PixelCoord { u: -0.4, v: 0.6 });
    coords.push(PixelCoord { u: 3.0, v: 4.8 });
    let table = SampleTable::from(
        coords
            .iter()
            .map(|&p| grid.bilinear_taps(p))
            .collect::<Vec<_>>(),
    );
    assert_eq!(table.len(), coords.len());
    let n = coords.len();
    let fv = pseudo_random(b * h * w * c, 8);
    let rv = pseudo_random(b * n * c, 9);
    let reference = |f: &[f64]| -> Vec<f64> {
        (0..b)
            .flat_map(|bi| {
                let img = &f[bi * h * w * c..(bi + 1) * h * w * c];
                coords
                    .iter()
                    .flat_map(|&p| erp_bilinear_ref(img, h, w, c, p))
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let features = Var::from_tensor(&tensor(&fv, &[b, h, w, c])).unwrap();
    let out = table_sample(features.as_tensor(), &table).unwrap();
    assert_eq!(out.dims(), &[b, n, c]);
    let err = max_abs_diff(&values(&out), &reference(&fv));
    assert!(err < FWD_TOL, "forward error {err}");

    let r = tensor(&rv, &[b, n, c]);
    let grads = (&out * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let g = values(grads.get(features.as_tensor()).unwrap());
    let g_fd = fd_gradient(&fv, reference, &rv);
    let err = max_abs_diff(&g, &g_fd);
    assert!(err < GRAD_TOL, "gradient error {err}");
    // the seam sample (u = 9.7) reads column 0: its gradient is non-zero there
    assert!(g.iter().any(|v| v.abs() > 1e-2));

    let outc = table_sample_composite(features.as_tensor(), &table).unwrap();
    assert!(max_abs_diff(&values(&outc), &values(&out)) < FWD_TOL);
    let gc = (&outc * &r).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(max_abs_diff(&values(gc.get(features.as_tensor()).unwrap()), &g) < FWD_TOL);
}

#[test]
fn table_sample_rejects_features_smaller_than_the_table() {
    let grid = ErpGrid::new(8).unwrap();
    let table = SampleTable::from(vec![grid.bilinear_taps(PixelCoord { u: 7.5, v: 3.0 })]);
    let small = Tensor::zeros((1, 2, 4, 1), candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = table_sample(&small, &table).unwrap_err().to_string();
    assert!(err.contains("out of range"), "{err}");
}

/// PyTorch `align_corners=False` linear weights, computed independently per output index.
fn linear_ref(input: &[f64], out_len: usize) -> Vec<f64> {
    let n = input.len();
    (0..out_len)
        .map(|j| {
            let src = ((j as f64 + 0.5) * n as f64 / out_len as f64 - 0.5).max(0.0);
            let i0 = src.floor() as usize;
            let lambda = src - i0 as f64;
            let i1 = if i0 + 1 < n { i0 + 1 } else { i0 };
            (1.0 - lambda) * input[i0] + lambda * input[i1]
        })
        .collect()
}

/// Naive trilinear on `(B, D, H, W)`: each output voxel from its 8 neighbours.
fn trilinear_ref(x: &[f64], dims: [usize; 4], out: [usize; 3]) -> Vec<f64> {
    let [b, d, h, w] = dims;
    let [od, oh, ow] = out;
    let taps = |o: usize, n: usize, j: usize| {
        let src = ((j as f64 + 0.5) * n as f64 / o as f64 - 0.5).max(0.0);
        let i0 = (src.floor() as usize).min(n - 1);
        [
            (i0, 1.0 - (src - i0 as f64)),
            ((i0 + 1).min(n - 1), src - i0 as f64),
        ]
    };
    let mut y = Vec::with_capacity(b * od * oh * ow);
    for bi in 0..b {
        for z in 0..od {
            for r in 0..oh {
                for c in 0..ow {
                    let mut acc = 0.0;
                    for (iz, wz) in taps(od, d, z) {
                        for (ir, wr) in taps(oh, h, r) {
                            for (ic, wc) in taps(ow, w, c) {
                                acc += wz * wr * wc * x[((bi * d + iz) * h + ir) * w + ic];
                            }
                        }
                    }
                    y.push(acc);
                }
            }
        }
    }
    y
}

#[test]
fn linear_axis_matches_pytorch_formula() {
    // x2 and odd factors, and down-sampling
    for (n, m) in [(4, 8), (5, 9), (7, 3), (1, 4), (6, 6)] {
        let v = pseudo_random(n, n as u64 * 100 + m as u64);
        let out = resample_linear_axis(&tensor(&v, &[1, n, 1]), 1, m).unwrap();
        assert_eq!(out.dims(), &[1, m, 1]);
        let err = max_abs_diff(&values(&out), &linear_ref(&v, m));
        assert!(err < FWD_TOL, "{n}->{m}: {err}");
    }
    // x2 upsampling of [0, 1, 2, 3]: PyTorch gives [0, .25, .75, 1.25, 1.75, 2.25, 2.75, 3]
    let ramp = tensor(&[0.0, 1.0, 2.0, 3.0], &[4]);
    let up = values(&resample_linear_axis(&ramp, 0, 8).unwrap());
    let expected = [0.0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.0];
    assert!(max_abs_diff(&up, &expected) < FWD_TOL, "{up:?}");
}

#[test]
fn upsample_trilinear_forward_gradient_and_composite() {
    let dims = [2, 3, 5, 4];
    let out = [6, 9, 8];
    let xv = pseudo_random(dims.iter().product(), 71);
    let x = Var::from_tensor(&tensor(&xv, &dims)).unwrap();
    let y = upsample_trilinear(x.as_tensor(), out[0], out[1], out[2]).unwrap();
    assert_eq!(y.dims(), &[2, 6, 9, 8]);
    let err = max_abs_diff(&values(&y), &trilinear_ref(&xv, dims, out));
    assert!(err < FWD_TOL, "forward error {err}");

    let rv = pseudo_random(y.elem_count(), 72);
    let r = tensor(&rv, y.dims());
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let g = values(grads.get(x.as_tensor()).unwrap());
    let g_fd = fd_gradient(&xv, |p| trilinear_ref(p, dims, out), &rv);
    let err = max_abs_diff(&g, &g_fd);
    assert!(err < GRAD_TOL, "gradient error {err}");

    let yc = upsample_trilinear_composite(x.as_tensor(), out[0], out[1], out[2]).unwrap();
    assert!(max_abs_diff(&values(&yc), &values(&y)) < FWD_TOL);
    let gc = (&yc * &r).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(max_abs_diff(&values(gc.get(x.as_tensor()).unwrap()), &g) < FWD_TOL);
}

/// Many more samples than pixels (the sweep case): the backward scatters per thread.
#[test]
fn table_sample_dense_table_gradient_matches_composite() {
    let grid = ErpGrid::new(8).unwrap(); // 4 x 8 = 32 pixels
    let (h, w, c) = (grid.height(), grid.width(), 2);
    let n = 4000;
    let table = SampleTable::new(
        &pseudo_random(2 * n, 81)
            .chunks(2)
            .map(|p| {
                grid.bilinear_taps(PixelCoord {
                    u: (p[0] + 1.0) * 0.5 * w as f64,
                    v: (p[1] + 1.0) * 0.5 * h as f64 - 0.5,
                })
            })
            .collect::<Vec<_>>(),
    );
    let fv = pseudo_random(h * w * c, 82);
    let rv = pseudo_random(n * c, 83);
    let features = Var::from_tensor(&tensor(&fv, &[1, h, w, c])).unwrap();
    let r = tensor(&rv, &[1, n, c]);
    let grad_of = |out: Tensor| {
        let grads = (&out * &r).unwrap().sum_all().unwrap().backward().unwrap();
        values(grads.get(features.as_tensor()).unwrap())
    };
    let g = grad_of(table_sample(features.as_tensor(), &table).unwrap());
    let gc = grad_of(table_sample_composite(features.as_tensor(), &table).unwrap());
    // each pixel collects ~500 products of magnitude < 1
    assert!(g.iter().any(|v| v.abs() > 1.0));
    let err = max_abs_diff(&g, &gc);
    assert!(err < 1e-3, "custom vs composite {err}");
    // and the exact adjoint identity <S f, r> = <f, Sᵀ r>
    let out = values(&table_sample(features.as_tensor(), &table).unwrap());
    let (l, rr) = (dot(&out, &rv), dot(&fv, &g));
    assert!((l - rr).abs() < 1e-3 * l.abs().max(1.0), "{l} vs {rr}");
}

#[test]
fn sweep_variance_matches_a_per_camera_reference_with_gradients() {
    // 2 channels run the generic kernel, 4 and 8 the unrolled ones.
    for c in [2, 4, 8] {
        sweep_variance_matches_reference(c, false);
    }
}

#[test]
fn sweep_variance_over_the_cameras_that_see_each_sample() {
    // Cameras that do not see a sample (zero taps) are left out of its mean and variance;
    // a sample fewer than two cameras see has variance 0 and no gradient.
    for c in [2, 4, 8] {
        sweep_variance_matches_reference(c, true);
    }
}

/// Whether camera `cam` is blind to sample `k` in the masked variant: every fourth sample
/// for one camera each, and every seventh for cameras 0 and 1 together (one view left).
fn blind(cam: usize, k: usize) -> bool {
    (k + cam).is_multiple_of(4) || (k.is_multiple_of(7) && cam < 2)
}

fn sweep_variance_matches_reference(c: usize, masked: bool) {
    // Three cameras, two batch items, 30 samples per camera table: the fused kernel against
    // the variance of the bilinear reference samples, and its gradient against differences.
    let grid = ErpGrid::new(8).unwrap(); // 4 x 8
    let (h, w, b, m) = (grid.height(), grid.width(), 2, 3);
    let coords: Vec<Vec<PixelCoord>> = (0..m)
        .map(|cam| {
            pseudo_random(60, 20 + cam as u64)
                .chunks(2)
                .map(|p| PixelCoord {
                    u: (p[0] + 1.0) * 0.5 * w as f64 - 0.5,
                    v: (p[1] + 1.0) * 0.5 * h as f64 - 0.5,
                })
                .collect()
        })
        .collect();
    let n = coords[0].len();
    let tables: Vec<SampleTable> = coords
        .iter()
        .enumerate()
        .map(|(cam, cs)| {
            SampleTable::from(
                cs.iter()
                    .enumerate()
                    .map(|(k, &p)| {
                        let mut t = grid.bilinear_taps(p);
                        if masked && blind(cam, k) {
                            t.weight = [0.0; 4];
                        }
                        t
                    })
                    .collect::<Vec<_>>(),
            )
        })
        .collect();
    let fv = pseudo_random(m * b * h * w * c, 30);
    let rv = pseudo_random(b * n * c, 31);
    let image = h * w * c;
    let reference = |f: &[f64]| -> Vec<f64> {
        let mut out = Vec::with_capacity(b * n * c);
        for bi in 0..b {
            for k in 0..n {
                let samples: Vec<Vec<f64>> = coords
                    .iter()
                    .enumerate()
                    .filter(|(cam, _)| !(masked && blind(*cam, k)))
                    .map(|(cam, cs)| {
                        let img = &f[(cam * b + bi) * image..(cam * b + bi + 1) * image];
                        erp_bilinear_ref(img, h, w, c, cs[k])
                    })
                    .collect();
                let views = samples.len() as f64;
                for ch in 0..c {
                    if samples.len() < 2 {
                        out.push(0.0);
                        continue;
                    }
                    let mean = samples.iter().map(|s| s[ch]).sum::<f64>() / views;
                    let var = samples.iter().map(|s| (s[ch] - mean).powi(2)).sum::<f64>() / views;
                    out.push(var);
                }
            }
        }
        out
    };
    let features = Var::from_tensor(&tensor(&fv, &[m * b, h, w, c])).unwrap();
    let out = if masked {
        let scale = view_scale(&tables);
        assert_eq!(
            scale.iter().filter(|&&s| s == 0.0).count(),
            5,
            "samples fewer than two cameras see"
        );
        sweep_variance_visible(features.as_tensor(), &tables, &scale).unwrap()
    } else {
        sweep_variance(features.as_tensor(), &tables).unwrap()
    };
    assert_eq!(out.dims(), &[b, n, c]);
    let err = max_abs_diff(&values(&out), &reference(&fv));
    assert!(err < FWD_TOL, "{c} channels: forward error {err}");
    let r = tensor(&rv, &[b, n, c]);
    let grads = (&out * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let g = values(grads.get(features.as_tensor()).unwrap());
    let g_fd = fd_gradient(&fv, reference, &rv);
    let err = max_abs_diff(&g, &g_fd);
    assert!(err < GRAD_TOL, "{c} channels: gradient error {err}");
    assert!(g.iter().any(|v| v.abs() > 1e-2));
    // Mismatched tables are an error, not a panic.
    let short = SampleTable::from(vec![grid.bilinear_taps(PixelCoord { u: 1.0, v: 1.0 })]);
    let bad = [tables[0].clone(), short, tables[2].clone()];
    assert!(sweep_variance(features.as_tensor(), &bad).is_err());
}

/// The sweep's tables in compact form (8 bytes a sample: corner and fractions, expanded on
/// read) hold exactly the taps of the flat form (32 bytes), unseen fisheye samples included,
/// and the ops give bit-identical results on either.
#[test]
fn compact_sweep_tables_equal_the_flat_ones_bit_for_bit() -> Result<(), Box<dyn std::error::Error>>
{
    use mode360_core::geometry::{DepthHypotheses, DepthRange, Rig, SweepGeometry};
    let rig = Rig::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_omnimvs.yaml"
    ))?;
    let grid = ErpGrid::new(32)?;
    let cameras = rig.cameras.len();
    let geometry = SweepGeometry::new(
        &rig,
        grid,
        vec![grid; cameras],
        DepthHypotheses::new(DepthRange::paper(), 6)?,
    )?;
    let (mut flat, mut compact) = (Vec::new(), Vec::new());
    let mut unseen = 0;
    for cam in 0..cameras {
        let f = SampleTable::new(&geometry.camera_taps(cam));
        let c = SampleTable::from_erp(geometry.camera_grid(cam), geometry.camera_samples(cam));
        assert_eq!(f.len(), c.len());
        for n in 0..f.len() {
            assert_eq!(f.taps(n), c.taps(n), "camera {cam}, sample {n}");
            unseen += usize::from(c.taps(n).weight == [0.0; 4]);
        }
        assert_eq!((f.tap_bytes(), c.tap_bytes()), (32 * f.len(), 8 * f.len()));
        flat.push(f);
        compact.push(c);
    }
    // the fisheyes do not see everything: the unseen samples are kept as such
    assert!(unseen > 0);
    let ch = 4;
    let features = Tensor::from_vec(
        pseudo_random(cameras * grid.len() * ch, 17)
            .into_iter()
            .map(|x| x as f32)
            .collect::<Vec<_>>(),
        (cameras, grid.height(), grid.width(), ch),
        &Device::Cpu,
    )?;
    let bits = |t: &Tensor| -> candle_core::Result<Vec<u32>> {
        Ok(t.flatten_all()?
            .to_vec1::<f32>()?
            .into_iter()
            .map(f32::to_bits)
            .collect())
    };
    let scale = view_scale(&flat);
    assert_eq!(scale, view_scale(&compact));
    assert_eq!(
        bits(&sweep_variance_visible(&features, &flat, &scale)?)?,
        bits(&sweep_variance_visible(&features, &compact, &scale)?)?
    );
    // table_sample and its gradient (the transposed table)
    let one = features.narrow(0, 0, 1)?;
    let var = Var::from_tensor(&one)?;
    let (a, b) = (
        table_sample(var.as_tensor(), &flat[0])?,
        table_sample(var.as_tensor(), &compact[0])?,
    );
    assert_eq!(bits(&a)?, bits(&b)?);
    let (ga, gb) = (a.sum_all()?.backward()?, b.sum_all()?.backward()?);
    let grad = |g: &candle_core::backprop::GradStore| g.get(var.as_tensor()).cloned();
    assert_eq!(
        bits(&grad(&ga).ok_or("no gradient")?)?,
        bits(&grad(&gb).ok_or("no gradient")?)?
    );
    Ok(())
}

/// `sweep_variance_appended` (the cost volume with the photometric channel written in one
/// pass) equals `append_channels(sweep_variance(..), extra)` bit for bit, forward and both
/// gradients, with and without per-sample view scales.
#[test]
fn sweep_variance_with_a_channel_appended_equals_the_two_ops(
) -> Result<(), Box<dyn std::error::Error>> {
    use mode360_model::model::ops::{
        append_channels, sweep_variance_appended, sweep_variance_appended_window,
    };
    let grid = ErpGrid::new(16)?;
    let (cameras, c, n) = (3, 8, 300);
    let tables: Vec<SampleTable> = (0..cameras)
        .map(|cam| {
            let coords = pseudo_random(2 * n, 40 + cam as u64);
            SampleTable::from(
                (0..n)
                    .map(|k| {
                        grid.bilinear_taps(PixelCoord {
                            u: coords[2 * k] * 16.0,
                            v: coords[2 * k + 1] * 8.0,
                        })
                    })
                    .collect::<Vec<_>>(),
            )
        })
        .collect();
    let features = Var::from_tensor(&tensor(
        &pseudo_random(cameras * grid.len() * c, 7),
        &[cameras, grid.height(), grid.width(), c],
    ))?;
    let extra = Var::from_tensor(&tensor(&pseudo_random(n, 8), &[1, n, 1]))?;
    let bits = |t: &Tensor| -> candle_core::Result<Vec<u32>> {
        Ok(t.flatten_all()?
            .to_vec1::<f32>()?
            .into_iter()
            .map(f32::to_bits)
            .collect())
    };
    let r = tensor(&pseudo_random(n * (c + 1), 9), &[1, n, c + 1]);
    for scale in [None, Some(view_scale(&tables))] {
        let two = match &scale {
            None => sweep_variance(features.as_tensor(), &tables)?,
            Some(s) => sweep_variance_visible(features.as_tensor(), &tables, s)?,
        };
        let two = append_channels(&two, extra.as_tensor())?;
        let one = sweep_variance_appended(
            features.as_tensor(),
            &tables,
            scale.as_ref(),
            extra.as_tensor(),
        )?;
        assert_eq!(one.dims(), [1, n, c + 1]);
        assert_eq!(bits(&one)?, bits(&two)?);
        // a window of the samples (the cost volume in slabs) is the same samples bit for bit
        let window = 37..251;
        let part = sweep_variance_appended_window(
            &features.as_tensor().detach(),
            &tables,
            scale.as_ref(),
            &extra.as_tensor().narrow(1, window.start, window.len())?,
            window.clone(),
        )?;
        assert_eq!(part.dims(), [1, window.len(), c + 1]);
        assert_eq!(
            bits(&part)?,
            bits(&one.narrow(1, window.start, window.len())?)?
        );
        let past_end = sweep_variance_appended_window(
            features.as_tensor(),
            &tables,
            scale.as_ref(),
            &extra.as_tensor().narrow(1, 0, 10)?,
            n - 5..n + 5,
        )
        .expect_err("a window past the samples")
        .to_string();
        assert!(
            past_end.contains("window") && past_end.contains(&format!("{n} samples")),
            "{past_end}"
        );
        let (g1, g2) = (
            (one * &r)?.sum_all()?.backward()?,
            (two * &r)?.sum_all()?.backward()?,
        );
        for v in [&features, &extra] {
            let (a, b) = (g1.get(v.as_tensor()), g2.get(v.as_tensor()));
            assert_eq!(
                bits(a.ok_or("no gradient")?)?,
                bits(b.ok_or("no gradient")?)?
            );
        }
    }
    Ok(())
}
