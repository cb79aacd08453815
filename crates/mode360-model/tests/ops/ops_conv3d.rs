//! conv3d / conv_transpose3d: custom kernels against nested-loop f64 references, gradients
//! against central differences of the reference, and custom == composite.

use crate::common::{dot, max_abs_diff, pseudo_random, tensor, values};
use candle_core::{Device, Tensor, Var};
use mode360_model::model::ops::{
    conv3d, conv3d_composite, conv3d_fused, conv3d_weight_grad, conv3d_weight_grad_composite,
    conv_transpose3d, conv_transpose3d_composite, conv_transpose3d_x2_fused, flop_count,
    is_inference, Conv3dGeometry, Epilogue,
};

/// Forward tolerance (f32 sums of a few hundred products of values in [-1, 1]).
const FWD_TOL: f64 = 1e-4;
/// Gradient tolerance against f64 central differences.
const GRAD_TOL: f64 = 1e-3;
/// Central-difference step (the reference is f64 and linear, so the step barely matters).
const FD_STEP: f64 = 1e-3;

/// Naive f64 conv3d, x `(B, D, H, W, Ci)`, w `(kD, kH, kW, Ci, Co)`.
fn conv3d_ref(x: &[f64], w: &[f64], g: &Conv3dGeometry) -> Vec<f64> {
    let [d, h, wd] = g.in_dims;
    let [od, oh, ow] = g.out_dims;
    let [kd, kh, kw] = g.kernel;
    let (ci, co) = (g.c_in, g.c_out);
    let mut y = vec![0.0; g.batch * od * oh * ow * co];
    for b in 0..g.batch {
        for z in 0..od {
            for r in 0..oh {
                for c in 0..ow {
                    for a in 0..kd {
                        for bb in 0..kh {
                            for e in 0..kw {
                                let iz = (z * g.stride[0] + a) as isize - g.padding[0] as isize;
                                let ir = (r * g.stride[1] + bb) as isize - g.padding[1] as isize;
                                let ic = (c * g.stride[2] + e) as isize - g.padding[2] as isize;
                                if iz < 0
                                    || ir < 0
                                    || ic < 0
                                    || iz >= d as isize
                                    || ir >= h as isize
                                    || ic >= wd as isize
                                {
                                    continue;
                                }
                                let (iz, ir, ic) = (iz as usize, ir as usize, ic as usize);
                                for i in 0..ci {
                                    let xv = x[(((b * d + iz) * h + ir) * wd + ic) * ci + i];
                                    for o in 0..co {
                                        y[(((b * od + z) * oh + r) * ow + c) * co + o] +=
                                            xv * w[(((a * kh + bb) * kw + e) * ci + i) * co + o];
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    y
}

/// Naive f64 transposed conv by scattering: x `(B, D, H, W, Ci)`, w `(kD, kH, kW, Ci, Co)`.
fn conv_transpose3d_ref(
    x: &[f64],
    x_dims: [usize; 5],
    w: &[f64],
    w_dims: [usize; 5],
    stride: [usize; 3],
    padding: [usize; 3],
    output_padding: [usize; 3],
) -> (Vec<f64>, [usize; 3]) {
    let [bn, d, h, wd, ci] = x_dims;
    let [kd, kh, kw, _, co] = w_dims;
    let out: [usize; 3] = std::array::from_fn(|a| {
        ([d, h, wd][a] - 1) * stride[a] + [kd, kh, kw][a] + output_padding[a] - 2 * padding[a]
    });
    let [od, oh, ow] = out;
    let mut y = vec![0.0; bn * od * oh * ow * co];
    for b in 0..bn {
        for z in 0..d {
            for r in 0..h {
                for c in 0..wd {
                    for a in 0..kd {
                        for bb in 0..kh {
                            for e in 0..kw {
                                let tz = (z * stride[0] + a) as isize - padding[0] as isize;
                                let tr = (r * stride[1] + bb) as isize - padding[1] as isize;
                                let tc = (c * stride[2] + e) as isize - padding[2] as isize;
                                if tz < 0
                                    || tr < 0
                                    || tc < 0
                                    || tz >= od as isize
                                    || tr >= oh as isize
                                    || tc >= ow as isize
                                {
                                    continue;
                                }
                                let (tz, tr, tc) = (tz as usize, tr as usize, tc as usize);
                                for i in 0..ci {
                                    let xv = x[(((b * d + z) * h + r) * wd + c) * ci + i];
                                    for o in 0..co {
                                        y[(((b * od + tz) * oh + tr) * ow + tc) * co + o] +=
                                            xv * w[(((a * kh + bb) * kw + e) * ci + i) * co + o];
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    (y, out)
}

/// Central differences of `loss(v) = <f(v), r>` in every coordinate of `v` listed in `coords`.
fn central_differences(
    v: &[f64],
    coords: impl Iterator<Item = usize>,
    f: impl Fn(&[f64]) -> Vec<f64>,
    r: &[f64],
) -> Vec<(usize, f64)> {
    coords
        .map(|i| {
            let mut p = v.to_vec();
            p[i] += FD_STEP;
            let lp = dot(&f(&p), r);
            p[i] -= 2.0 * FD_STEP;
            let lm = dot(&f(&p), r);
            (i, (lp - lm) / (2.0 * FD_STEP))
        })
        .collect()
}

struct ConvCase {
    x_dims: [usize; 5],
    kernel: [usize; 3],
    c_out: usize,
    stride: [usize; 3],
    padding: [usize; 3],
}

fn check_conv3d_case(case: &ConvCase, seed: u64) {
    let [bn, d, h, wd, ci] = case.x_dims;
    let [kd, kh, kw] = case.kernel;
    let g = Conv3dGeometry::new(
        bn,
        [d, h, wd],
        case.kernel,
        case.stride,
        case.padding,
        ci,
        case.c_out,
    )
    .unwrap();
    let w_dims = [kd, kh, kw, ci, case.c_out];
    let xv = pseudo_random(case.x_dims.iter().product(), seed);
    let wv = pseudo_random(w_dims.iter().product(), seed + 1);
    let [od, oh, ow] = g.out_dims;
    let y_dims = [bn, od, oh, ow, case.c_out];
    let rv = pseudo_random(y_dims.iter().product(), seed + 2);

    let x = Var::from_tensor(&tensor(&xv, &case.x_dims)).unwrap();
    let w = Var::from_tensor(&tensor(&wv, &w_dims)).unwrap();
    let r = tensor(&rv, &y_dims);

    // forward vs reference
    let y = conv3d(x.as_tensor(), w.as_tensor(), case.stride, case.padding).unwrap();
    assert_eq!(y.dims(), &y_dims);
    let y_ref = conv3d_ref(&xv, &wv, &g);
    let err = max_abs_diff(&values(&y), &y_ref);
    assert!(err < FWD_TOL, "forward error {err}");

    // gradients vs central differences of the f64 reference
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let gx = values(grads.get(x.as_tensor()).unwrap());
    let gw = values(grads.get(w.as_tensor()).unwrap());
    let x_step = (xv.len() / 97).max(1);
    for (i, fd) in central_differences(
        &xv,
        (0..xv.len()).step_by(x_step),
        |p| conv3d_ref(p, &wv, &g),
        &rv,
    ) {
        assert!(
            (gx[i] - fd).abs() < GRAD_TOL,
            "dx[{i}] {} vs fd {fd}",
            gx[i]
        );
    }
    for (i, fd) in central_differences(&wv, 0..wv.len(), |p| conv3d_ref(&xv, p, &g), &rv) {
        assert!(
            (gw[i] - fd).abs() < GRAD_TOL,
            "dw[{i}] {} vs fd {fd}",
            gw[i]
        );
    }

    // composite == custom, forward and gradients
    let yc = conv3d_composite(x.as_tensor(), w.as_tensor(), case.stride, case.padding).unwrap();
    assert!(max_abs_diff(&values(&yc), &values(&y)) < FWD_TOL);
    let gc = (&yc * &r).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(max_abs_diff(&values(gc.get(x.as_tensor()).unwrap()), &gx) < FWD_TOL);
    assert!(max_abs_diff(&values(gc.get(w.as_tensor()).unwrap()), &gw) < FWD_TOL);
}

#[test]
fn conv3d_stride1_pad1_odd_sizes() {
    check_conv3d_case(
        &ConvCase {
            x_dims: [2, 5, 7, 9, 3],
            kernel: [3, 3, 3],
            c_out: 4,
            stride: [1, 1, 1],
            padding: [1, 1, 1],
        },
        1,
    );
}

#[test]
fn conv3d_stride2_pad1_odd_sizes() {
    check_conv3d_case(
        &ConvCase {
            x_dims: [1, 5, 7, 9, 4],
            kernel: [3, 3, 3],
            c_out: 3,
            stride: [2, 2, 2],
            padding: [1, 1, 1],
        },
        11,
    );
}

#[test]
fn conv3d_stride_in_depth_only_odd_sizes() {
    // the fine head's geometry (stride 2 over spheres, 1 over rows and columns), whose weight
    // gradient runs by planes, here with an uneven kernel and padding
    check_conv3d_case(
        &ConvCase {
            x_dims: [2, 7, 5, 9, 3],
            kernel: [3, 3, 2],
            c_out: 4,
            stride: [2, 1, 1],
            padding: [1, 0, 1],
        },
        31,
    );
}

#[test]
fn conv3d_mixed_stride_padding_kernel() {
    check_conv3d_case(
        &ConvCase {
            x_dims: [1, 6, 7, 8, 2],
            kernel: [2, 3, 1],
            c_out: 5,
            stride: [1, 2, 3],
            padding: [0, 2, 1],
        },
        21,
    );
}

#[test]
fn a_detached_input_gets_no_gradient_and_costs_none() {
    // the fine head reads the cost volume detached: backward must run the weight gradient
    // only (one pass's multiply-adds, not two), and that gradient must be the same
    let (x_dims, c_out, stride) = ([1, 7, 6, 8, 3], 4, [2, 1, 1]);
    let [_, d, h, wd, ci] = x_dims;
    let g = Conv3dGeometry::new(1, [d, h, wd], [3, 3, 3], stride, [1; 3], ci, c_out).unwrap();
    let w_dims = [3, 3, 3, ci, c_out];
    let x = Var::from_tensor(&tensor(
        &pseudo_random(x_dims.iter().product(), 41),
        &x_dims,
    ))
    .unwrap();
    let w = Var::from_tensor(&tensor(
        &pseudo_random(w_dims.iter().product(), 42),
        &w_dims,
    ))
    .unwrap();
    let [od, oh, ow] = g.out_dims;
    let y_dims = [1, od, oh, ow, c_out];
    let r = tensor(&pseudo_random(y_dims.iter().product(), 43), &y_dims);
    let backward = |input: &Tensor| {
        let loss = (conv3d(input, w.as_tensor(), stride, [1; 3]).unwrap() * &r)
            .unwrap()
            .sum_all()
            .unwrap();
        let before = flop_count();
        let grads = loss.backward().unwrap();
        (grads, flop_count() - before)
    };
    let (tracked, tracked_flops) = backward(x.as_tensor());
    let (detached, detached_flops) = backward(&x.as_tensor().detach());
    assert!(tracked.get(x.as_tensor()).is_some());
    assert!(detached.get(x.as_tensor()).is_none());
    assert_eq!(
        tracked_flops,
        2 * g.flops() as u64,
        "input and weight gradients"
    );
    assert_eq!(
        detached_flops,
        g.flops() as u64,
        "the weight gradient alone"
    );
    let dw = |grads: &candle_core::backprop::GradStore| values(grads.get(w.as_tensor()).unwrap());
    assert_eq!(max_abs_diff(&dw(&detached), &dw(&tracked)), 0.0);
}

// The narrow layers of the aggregation (Cout 4, 8 or 16, and Cout 1 over 8 or 16 channels) take
// the direct register-blocked kernel on AVX2 machines: rows wide enough for full blocks, a
// remainder and both padded edges.

#[test]
fn conv3d_direct_kernels_match_the_reference() {
    let case = |x_dims, kernel, c_out, stride, padding| ConvCase {
        x_dims,
        kernel,
        c_out,
        stride,
        padding,
    };
    let cases = [
        // Cout 8, unit stride (full blocks, a remainder and both padded edges)
        case([1, 4, 5, 21, 8], [3, 3, 3], 8, [1, 1, 1], [1, 1, 1]),
        // Cout 16, stride 2
        case([2, 5, 6, 23, 8], [3, 3, 3], 16, [2, 2, 2], [1, 1, 1]),
        // Cout 4 from 9 channels, stride 2 over depth only (the fine head's first layer)
        case([2, 7, 5, 21, 9], [3, 3, 3], 4, [2, 1, 1], [1, 1, 1]),
        // Cout 8 from 3 channels, planar kernel, no padding
        case([1, 1, 6, 19, 3], [1, 3, 3], 8, [1, 2, 2], [0, 0, 0]),
        // Cout 1: dot products over 8 and 16 channels
        case([1, 3, 4, 13, 8], [3, 3, 3], 1, [1, 1, 1], [1, 1, 1]),
        case([1, 3, 4, 13, 16], [3, 3, 3], 1, [1, 1, 1], [1, 1, 1]),
        // 4 x 3 = 12 (depth, height) tap pairs: more than the register kernel's table holds
        case([1, 6, 5, 10, 2], [4, 3, 2], 8, [1, 1, 2], [2, 1, 1]),
    ];
    for (k, c) in cases.iter().enumerate() {
        check_conv3d_case(c, 41 + 2 * k as u64);
    }
}

/// `relu?(y + bias + residual)` on f64 values with `co` channels.
fn epilogue_ref(y: &[f64], bias: &[f64], residual: &[f64], relu: bool) -> Vec<f64> {
    y.iter()
        .enumerate()
        .map(|(i, v)| {
            let s = v + bias[i % bias.len()] + residual[i];
            if relu {
                s.max(0.0)
            } else {
                s
            }
        })
        .collect()
}

#[test]
fn fused_conv_matches_the_composed_layers() {
    // Cout 8 (direct kernel) and Cout 5 (GEMM kernel then the epilogue)
    for (c_out, stride, seed) in [(8, [2, 2, 2], 61), (5, [1, 1, 1], 63)] {
        let (x_dims, pad) = ([1, 4, 6, 18, 3], [1, 1, 1]);
        let g = Conv3dGeometry::new(1, [4, 6, 18], [3; 3], stride, pad, 3, c_out).unwrap();
        let [od, oh, ow] = g.out_dims;
        let y_dims = [1, od, oh, ow, c_out];
        let xv = pseudo_random(x_dims.iter().product(), seed);
        let wv = pseudo_random(27 * 3 * c_out, seed + 1);
        let bv = pseudo_random(c_out, seed + 2);
        let rv = pseudo_random(y_dims.iter().product(), seed + 3);
        let (x, w) = (tensor(&xv, &x_dims), tensor(&wv, &[3, 3, 3, 3, c_out]));
        let (b, r) = (tensor(&bv, &[c_out]), tensor(&rv, &y_dims));
        assert!(is_inference(&x, &w));
        let y_ref = conv3d_ref(&xv, &wv, &g);
        for relu in [false, true] {
            let epilogue = Epilogue {
                bias: Some(&b),
                residual: Some(&r),
                relu,
            };
            let y = conv3d_fused(&x, &w, stride, pad, epilogue).unwrap();
            assert_eq!(y.dims(), &y_dims);
            let expected = epilogue_ref(&y_ref, &bv, &rv, relu);
            let err = max_abs_diff(&values(&y), &expected);
            assert!(err < FWD_TOL, "Cout {c_out}, relu {relu}: error {err}");
            if relu {
                assert!(values(&y).contains(&0.0), "ReLU clipped nothing");
            }
        }
        // bias only
        let y = conv3d_fused(
            &x,
            &w,
            stride,
            pad,
            Epilogue {
                bias: Some(&b),
                ..Default::default()
            },
        );
        let zeros = vec![0.0; rv.len()];
        let err = max_abs_diff(
            &values(&y.unwrap()),
            &epilogue_ref(&y_ref, &bv, &zeros, false),
        );
        assert!(err < FWD_TOL, "bias only: {err}");
        // a residual of the wrong shape is an error naming both shapes
        let bad = tensor(
            &rv[..od * oh * (ow - 1) * c_out],
            &[1, od, oh, ow - 1, c_out],
        );
        let e = conv3d_fused(
            &x,
            &w,
            stride,
            pad,
            Epilogue {
                residual: Some(&bad),
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("residual"), "{e}");
    }
    // tracked tensors are not inference
    let x = Var::from_tensor(&tensor(&pseudo_random(24, 3), &[1, 2, 2, 2, 3])).unwrap();
    let w = tensor(&pseudo_random(27 * 3 * 8, 4), &[3, 3, 3, 3, 8]);
    assert!(!is_inference(x.as_tensor(), &w));
}

#[test]
fn fused_x2_upsampling_matches_the_composed_layers() {
    for (c_in, c_out, seed) in [(16, 8, 71), (4, 6, 73)] {
        let x_dims = [1, 3, 4, 7, c_in];
        let y_dims = [1, 6, 8, 14, c_out];
        let xv = pseudo_random(x_dims.iter().product(), seed);
        let wv = pseudo_random(27 * c_in * c_out, seed + 1);
        let bv = pseudo_random(c_out, seed + 2);
        let rv = pseudo_random(y_dims.iter().product(), seed + 3);
        let (x, w) = (tensor(&xv, &x_dims), tensor(&wv, &[3, 3, 3, c_in, c_out]));
        let (b, r) = (tensor(&bv, &[c_out]), tensor(&rv, &y_dims));
        let up = conv_transpose3d(&x, &w, [2; 3], [1; 3], [1; 3]).unwrap();
        assert_eq!(up.dims(), &y_dims);
        for relu in [false, true] {
            let epilogue = Epilogue {
                bias: Some(&b),
                residual: Some(&r),
                relu,
            };
            let y = conv_transpose3d_x2_fused(&x, &w, epilogue).unwrap();
            let expected = epilogue_ref(&values(&up), &bv, &rv, relu);
            let err = max_abs_diff(&values(&y), &expected);
            assert!(err < FWD_TOL, "{c_in} -> {c_out}, relu {relu}: error {err}");
        }
    }
}

struct TransposeCase {
    x_dims: [usize; 5],
    w_dims: [usize; 5],
    stride: [usize; 3],
    padding: [usize; 3],
    output_padding: [usize; 3],
}

fn check_transpose_case(case: &TransposeCase, seed: u64) {
    let xv = pseudo_random(case.x_dims.iter().product(), seed);
    let wv = pseudo_random(case.w_dims.iter().product(), seed + 1);
    let (y_ref, out) = conv_transpose3d_ref(
        &xv,
        case.x_dims,
        &wv,
        case.w_dims,
        case.stride,
        case.padding,
        case.output_padding,
    );
    let y_dims = [case.x_dims[0], out[0], out[1], out[2], case.w_dims[4]];
    let rv = pseudo_random(y_ref.len(), seed + 2);
    let x = Var::from_tensor(&tensor(&xv, &case.x_dims)).unwrap();
    let w = Var::from_tensor(&tensor(&wv, &case.w_dims)).unwrap();
    let r = tensor(&rv, &y_dims);
    let y = conv_transpose3d(
        x.as_tensor(),
        w.as_tensor(),
        case.stride,
        case.padding,
        case.output_padding,
    )
    .unwrap();
    assert_eq!(y.dims(), &y_dims);
    let err = max_abs_diff(&values(&y), &y_ref);
    assert!(err < FWD_TOL, "forward error {err}");

    let reference = |xs: &[f64], ws: &[f64]| {
        conv_transpose3d_ref(
            xs,
            case.x_dims,
            ws,
            case.w_dims,
            case.stride,
            case.padding,
            case.output_padding,
        )
        .0
    };
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let gx = values(grads.get(x.as_tensor()).unwrap());
    let gw = values(grads.get(w.as_tensor()).unwrap());
    for (i, fd) in central_differences(&xv, 0..xv.len(), |p| reference(p, &wv), &rv) {
        assert!(
            (gx[i] - fd).abs() < GRAD_TOL,
            "dx[{i}] {} vs fd {fd}",
            gx[i]
        );
    }
    for (i, fd) in central_differences(&wv, 0..wv.len(), |p| reference(&xv, p), &rv) {
        assert!(
            (gw[i] - fd).abs() < GRAD_TOL,
            "dw[{i}] {} vs fd {fd}",
            gw[i]
        );
    }

    let yc = conv_transpose3d_composite(
        x.as_tensor(),
        w.as_tensor(),
        case.stride,
        case.padding,
        case.output_padding,
    )
    .unwrap();
    assert!(max_abs_diff(&values(&yc), &values(&y)) < FWD_TOL);
    let gc = (&yc * &r).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(max_abs_diff(&values(gc.get(x.as_tensor()).unwrap()), &gx) < FWD_TOL);
    assert!(max_abs_diff(&values(gc.get(w.as_tensor()).unwrap()), &gw) < FWD_TOL);
}

#[test]
fn conv_transpose3d_x2_upsampling_odd_and_even_targets() {
    // (3, 4, 5) -> (5, 8, 10): output padding 0 on D (odd target), 1 on H and W.
    check_transpose_case(
        &TransposeCase {
            x_dims: [1, 3, 4, 5, 4],
            w_dims: [3, 3, 3, 4, 2],
            stride: [2, 2, 2],
            padding: [1, 1, 1],
            output_padding: [0, 1, 1],
        },
        31,
    );
}

#[test]
fn conv_transpose3d_stride1_and_mixed() {
    check_transpose_case(
        &TransposeCase {
            x_dims: [2, 3, 4, 3, 2],
            w_dims: [2, 3, 3, 2, 3],
            stride: [1, 2, 3],
            padding: [0, 1, 1],
            output_padding: [0, 0, 2],
        },
        41,
    );
}

/// `<conv3d(a, w), b> = <a, conv_transpose3d(b, wᵀ)>` with the sizes restored by output padding.
#[test]
fn conv_transpose3d_is_adjoint_of_conv3d() {
    let (stride, padding) = ([2, 2, 2], [1, 1, 1]);
    let a_dims = [1, 5, 8, 7, 3];
    let w_dims = [3, 3, 3, 3, 4];
    let g = Conv3dGeometry::new(1, [5, 8, 7], [3, 3, 3], stride, padding, 3, 4).unwrap();
    assert_eq!(g.output_padding(), [0, 1, 0]);
    let [od, oh, ow] = g.out_dims;
    let b_dims = [1, od, oh, ow, 4];
    let av = pseudo_random(a_dims.iter().product(), 51);
    let bv = pseudo_random(b_dims.iter().product(), 52);
    let wv = pseudo_random(w_dims.iter().product(), 53);
    let w = tensor(&wv, &w_dims);
    let lhs = values(&conv3d(&tensor(&av, &a_dims), &w, stride, padding).unwrap());
    let wt = w.transpose(3, 4).unwrap();
    let back = conv_transpose3d(
        &tensor(&bv, &b_dims),
        &wt,
        stride,
        padding,
        g.output_padding(),
    )
    .unwrap();
    assert_eq!(back.dims(), &a_dims);
    let l = dot(&lhs, &bv);
    let r = dot(&av, &values(&back));
    assert!((l - r).abs() < 1e-3 * l.abs().max(1.0), "{l} vs {r}");
}

/// The weight-gradient op is itself differentiable (its backward is conv3d and the input
/// gradient): custom and composite agree on it, forward and backward, under a nonlinear loss.
#[test]
fn conv3d_weight_grad_op_is_differentiable() {
    let (kernel, stride, padding) = ([3, 2, 3], [1, 2, 1], [1, 1, 0]);
    let x_dims = [1, 4, 5, 6, 2];
    let g = Conv3dGeometry::new(1, [4, 5, 6], kernel, stride, padding, 2, 3).unwrap();
    let [od, oh, ow] = g.out_dims;
    let dy_dims = [1, od, oh, ow, 3];
    let xv = pseudo_random(x_dims.iter().product(), 61);
    let dyv = pseudo_random(dy_dims.iter().product(), 62);
    let run = |composite: bool| {
        let x = Var::from_tensor(&tensor(&xv, &x_dims)).unwrap();
        let dy = Var::from_tensor(&tensor(&dyv, &dy_dims)).unwrap();
        let dw = if composite {
            conv3d_weight_grad_composite(x.as_tensor(), dy.as_tensor(), kernel, stride, padding)
        } else {
            conv3d_weight_grad(x.as_tensor(), dy.as_tensor(), kernel, stride, padding)
        }
        .unwrap();
        let grads = dw.sqr().unwrap().sum_all().unwrap().backward().unwrap();
        let mut out = values(&dw);
        out.extend(values(grads.get(x.as_tensor()).unwrap()));
        out.extend(values(grads.get(dy.as_tensor()).unwrap()));
        out
    };
    let custom = run(false);
    let composite = run(true);
    assert!(custom.iter().any(|v| v.abs() > 1e-1));
    let err = max_abs_diff(&custom, &composite);
    assert!(err < 1e-3, "custom vs composite {err}");
}

#[test]
fn conv3d_rejects_bad_shapes() {
    let x = Tensor::zeros((1, 4, 4, 4, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
    let w = Tensor::zeros((3, 3, 3, 2, 4), candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = conv3d(&x, &w, [1, 1, 1], [1, 1, 1])
        .unwrap_err()
        .to_string();
    assert!(err.contains("channels"), "{err}");
    let w = Tensor::zeros((3, 3, 3, 3, 4), candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = conv3d(&x, &w, [0, 1, 1], [1, 1, 1])
        .unwrap_err()
        .to_string();
    assert!(err.contains("stride"), "{err}");
    let err = conv_transpose3d(&x, &w, [2, 2, 2], [1, 1, 1], [2, 0, 0])
        .unwrap_err()
        .to_string();
    assert!(err.contains("output_padding"), "{err}");
}
