//! The device-generic path of every custom op (its composite, what a GPU runs) against the CPU
//! kernel, forward and backward: the same small random inputs through both, the outputs and
//! the gradients of `Σ r ⊙ y` (candle's backprop) compared with a tolerance. Also that the
//! choice is the op's own: inside `with_composites` the public op gives the composite's result.

use crate::common::{max_abs_diff, pseudo_random, tensor, values};
use candle_core::{Device, Result, Tensor, Var};
use mode360_core::geometry::{ErpGrid, PixelCoord};
use mode360_model::model::ops::{
    add_bias, conv3d, conv3d_composite, conv3d_fused, conv3d_fused_composite, conv3d_input_grad,
    conv3d_input_grad_composite, conv3d_weight_grad, conv3d_weight_grad_composite,
    conv_transpose3d, conv_transpose3d_composite, conv_transpose3d_x2_fused,
    conv_transpose3d_x2_fused_composite, has_custom_kernels, resample_linear_axis,
    resample_linear_axis_composite, soft_argmin_index, soft_argmin_index_composite, sweep_variance,
    sweep_variance_composite, sweep_variance_visible, table_sample, table_sample_composite,
    upsample_trilinear, upsample_trilinear_composite, view_scale, with_composites, Conv3dGeometry,
    Epilogue, LinearAxisMap, SampleTable,
};

/// Kernel and composite agree to this, relative to the largest magnitude compared (float32
/// sums of a few hundred products, in different orders).
const REL_TOL: f64 = 2e-5;
/// A gradient this large somewhere shows that the comparison is not between zeros.
const NONTRIVIAL: f64 = 1e-2;

/// A tracked variable of `dims` with values in [-1, 1).
fn var(dims: &[usize], seed: u64) -> Var {
    Var::from_tensor(&tensor(&pseudo_random(dims.iter().product(), seed), dims)).unwrap()
}

/// The output of `op` on `inputs` and the gradients of `Σ r ⊙ y` in each input, `r` fixed
/// pseudo-random values shaped like the output.
fn forward_backward(
    inputs: &[&Var],
    op: &dyn Fn(&[&Tensor]) -> Result<Tensor>,
) -> (Vec<usize>, Vec<f64>, Vec<Vec<f64>>) {
    let tensors: Vec<&Tensor> = inputs.iter().map(|v| v.as_tensor()).collect();
    let y = op(&tensors).unwrap();
    let r = tensor(&pseudo_random(y.elem_count(), 999), y.dims());
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let g = tensors
        .iter()
        .map(|t| values(grads.get(t).expect("a gradient for every input")))
        .collect();
    (y.dims().to_vec(), values(&y), g)
}

/// `a` and `b` agree to [`REL_TOL`] of their largest magnitude.
fn assert_close(what: &str, a: &[f64], b: &[f64]) {
    let scale = a.iter().chain(b).fold(1.0f64, |m, v| m.max(v.abs()));
    let err = max_abs_diff(a, b);
    assert!(
        err <= REL_TOL * scale,
        "{what}: differs by {err} (scale {scale})"
    );
}

/// Runs `kernel` and `composite` on the same inputs and compares outputs and gradients.
fn check(
    name: &str,
    inputs: &[&Var],
    kernel: &dyn Fn(&[&Tensor]) -> Result<Tensor>,
    composite: &dyn Fn(&[&Tensor]) -> Result<Tensor>,
) {
    assert!(has_custom_kernels(&Device::Cpu), "kernels switched off");
    let (dims_k, y_k, g_k) = forward_backward(inputs, kernel);
    let (dims_c, y_c, g_c) = forward_backward(inputs, composite);
    assert_eq!(dims_k, dims_c, "{name}: output shapes");
    assert!(
        y_k.iter().any(|v| v.abs() > NONTRIVIAL),
        "{name}: output ~0"
    );
    assert_close(&format!("{name} forward"), &y_k, &y_c);
    for (i, (gk, gc)) in g_k.iter().zip(&g_c).enumerate() {
        assert!(
            gk.iter().any(|v| v.abs() > NONTRIVIAL),
            "{name}: gradient {i} ~0"
        );
        assert_close(&format!("{name} gradient of input {i}"), gk, gc);
    }
}

#[test]
fn conv3d_and_its_gradient_ops_match_their_composites() {
    for (x_dims, kernel, stride, pad, c_out, seed) in [
        ([2, 5, 6, 7, 3], [3, 3, 3], [1, 1, 1], [1, 1, 1], 4, 1),
        ([1, 5, 6, 7, 3], [3, 3, 3], [2, 2, 2], [1, 1, 1], 8, 11),
        ([1, 4, 5, 9, 2], [2, 3, 1], [2, 1, 3], [0, 1, 0], 5, 21),
    ] {
        let [kd, kh, kw] = kernel;
        let w_dims = [kd, kh, kw, x_dims[4], c_out];
        let g = Conv3dGeometry::new(
            x_dims[0],
            [x_dims[1], x_dims[2], x_dims[3]],
            kernel,
            stride,
            pad,
            x_dims[4],
            c_out,
        )
        .unwrap();
        let [od, oh, ow] = g.out_dims;
        let dy_dims = [x_dims[0], od, oh, ow, c_out];
        let (x, w, dy) = (
            var(&x_dims, seed),
            var(&w_dims, seed + 1),
            var(&dy_dims, seed + 2),
        );
        let case = format!("x {x_dims:?}, k {kernel:?}, s {stride:?}, p {pad:?}");
        check(
            &format!("conv3d {case}"),
            &[&x, &w],
            &|t| conv3d(t[0], t[1], stride, pad),
            &|t| conv3d_composite(t[0], t[1], stride, pad),
        );
        let in_dims = g.in_dims;
        check(
            &format!("conv3d_input_grad {case}"),
            &[&dy, &w],
            &|t| conv3d_input_grad(t[0], t[1], stride, pad, in_dims),
            &|t| conv3d_input_grad_composite(t[0], t[1], stride, pad, in_dims),
        );
        check(
            &format!("conv3d_weight_grad {case}"),
            &[&x, &dy],
            &|t| conv3d_weight_grad(t[0], t[1], kernel, stride, pad),
            &|t| conv3d_weight_grad_composite(t[0], t[1], kernel, stride, pad),
        );
    }
}

#[test]
fn conv_transpose3d_matches_its_composite() {
    for (x_dims, w_dims, stride, pad, out_pad, seed) in [
        (
            [1, 3, 4, 5, 4],
            [3, 3, 3, 4, 2],
            [2, 2, 2],
            [1, 1, 1],
            [1, 0, 1],
            31,
        ),
        (
            [2, 2, 3, 3, 3],
            [3, 2, 3, 3, 5],
            [1, 2, 1],
            [1, 0, 1],
            [0, 1, 0],
            41,
        ),
    ] {
        let (x, w) = (var(&x_dims, seed), var(&w_dims, seed + 1));
        check(
            &format!("conv_transpose3d x {x_dims:?} w {w_dims:?}"),
            &[&x, &w],
            &|t| conv_transpose3d(t[0], t[1], stride, pad, out_pad),
            &|t| conv_transpose3d_composite(t[0], t[1], stride, pad, out_pad),
        );
    }
}

/// The fused kernels carry no gradient: their outputs are compared with the composites', and
/// the composites' gradients with those of the same layers composed from the kernel ops.
#[test]
fn fused_convolutions_match_their_composites() {
    for relu in [false, true] {
        // relu?(conv3d(x, w) + bias + residual), Cout 8 (direct kernel) and 5 (GEMM)
        for (c_out, stride, seed) in [(8, [2, 2, 2], 51), (5, [1, 1, 1], 53)] {
            let x_dims = [1, 4, 6, 10, 3];
            let g = Conv3dGeometry::new(1, [4, 6, 10], [3; 3], stride, [1; 3], 3, c_out).unwrap();
            let [od, oh, ow] = g.out_dims;
            let (x, w) = (var(&x_dims, seed), var(&[3, 3, 3, 3, c_out], seed + 1));
            let (b, r) = (
                var(&[c_out], seed + 2),
                var(&[1, od, oh, ow, c_out], seed + 3),
            );
            let fused = |t: &[&Tensor], composite: bool| {
                let epilogue = Epilogue {
                    bias: Some(t[2]),
                    residual: Some(t[3]),
                    relu,
                };
                if composite {
                    conv3d_fused_composite(t[0], t[1], stride, [1; 3], epilogue)
                } else {
                    let (x, w) = (t[0].detach(), t[1].detach());
                    let (b, r) = (t[2].detach(), t[3].detach());
                    let epilogue = Epilogue {
                        bias: Some(&b),
                        residual: Some(&r),
                        relu,
                    };
                    conv3d_fused(&x, &w, stride, [1; 3], epilogue)
                }
            };
            let inputs = [&x, &w, &b, &r];
            let y_kernel = values(&fused(&tensors(&inputs), false).unwrap());
            let y_composite = values(&fused(&tensors(&inputs), true).unwrap());
            let name = format!("conv3d_fused Cout {c_out}, relu {relu}");
            assert_close(&name, &y_kernel, &y_composite);
            if relu {
                assert!(y_kernel.contains(&0.0), "{name}: ReLU clipped nothing");
            }
            check(
                &name,
                &inputs,
                &|t| composed(conv3d(t[0], t[1], stride, [1; 3])?, t[2], t[3], relu),
                &|t| fused(t, true),
            );
        }
        // relu?(conv_transpose3d_x2(x, w) + bias + residual)
        let (c_in, c_out, seed) = (4, 6, 61);
        let (x, w) = (
            var(&[1, 3, 4, 5, c_in], seed),
            var(&[3, 3, 3, c_in, c_out], seed + 1),
        );
        let (b, r) = (
            var(&[c_out], seed + 2),
            var(&[1, 6, 8, 10, c_out], seed + 3),
        );
        let inputs = [&x, &w, &b, &r];
        let detached: Vec<Tensor> = inputs.iter().map(|v| v.as_tensor().detach()).collect();
        let y_kernel =
            conv_transpose3d_x2_fused(&detached[0], &detached[1], epilogue_of(&detached, relu));
        let y_composite = conv_transpose3d_x2_fused_composite(
            &detached[0],
            &detached[1],
            epilogue_of(&detached, relu),
        );
        let name = format!("conv_transpose3d_x2_fused, relu {relu}");
        assert_close(
            &name,
            &values(&y_kernel.unwrap()),
            &values(&y_composite.unwrap()),
        );
        check(
            &name,
            &inputs,
            &|t| {
                let up = conv_transpose3d(t[0], t[1], [2; 3], [1; 3], [1; 3])?;
                composed(up, t[2], t[3], relu)
            },
            &|t| {
                let epilogue = Epilogue {
                    bias: Some(t[2]),
                    residual: Some(t[3]),
                    relu,
                };
                conv_transpose3d_x2_fused_composite(t[0], t[1], epilogue)
            },
        );
    }
}

/// Bias `t[2]` and residual `t[3]`.
fn epilogue_of(t: &[Tensor], relu: bool) -> Epilogue<'_> {
    Epilogue {
        bias: Some(&t[2]),
        residual: Some(&t[3]),
        relu,
    }
}

fn tensors<'a>(vars: &[&'a Var]) -> Vec<&'a Tensor> {
    vars.iter().map(|v| v.as_tensor()).collect()
}

/// `relu?(y + bias + residual)` from candle ops, as the layers compose it when training.
fn composed(y: Tensor, bias: &Tensor, residual: &Tensor, relu: bool) -> Result<Tensor> {
    let y = (y.broadcast_add(bias)? + residual)?;
    if relu {
        y.relu()
    } else {
        Ok(y)
    }
}

/// `n` bilinear taps at pseudo-random positions of `grid`, across the seam too; a tap whose
/// `blind(k)` is true gets zero weights (its camera does not see sample `k`).
fn random_table(grid: ErpGrid, n: usize, seed: u64, blind: impl Fn(usize) -> bool) -> SampleTable {
    let (w, h) = (grid.width() as f64, grid.height() as f64);
    let taps: Vec<_> = pseudo_random(2 * n, seed)
        .chunks(2)
        .enumerate()
        .map(|(k, p)| {
            let mut t = grid.bilinear_taps(PixelCoord {
                u: (p[0] + 1.0) * 0.5 * w,
                v: (p[1] + 1.0) * 0.5 * h - 0.5,
            });
            if blind(k) {
                t.weight = [0.0; 4];
            }
            t
        })
        .collect();
    SampleTable::new(&taps)
}

#[test]
fn table_sample_matches_its_composite() {
    let grid = ErpGrid::new(8).unwrap(); // 4 x 8
                                         // fewer samples than pixels (transposed gather) and many more (per-thread scatter)
    for (n, c, seed) in [(20, 3, 71), (3000, 2, 73)] {
        let table = random_table(grid, n, seed, |_| false);
        let f = var(&[2, grid.height(), grid.width(), c], seed + 1);
        check(
            &format!("table_sample of {n} samples"),
            &[&f],
            &|t| table_sample(t[0], &table),
            &|t| table_sample_composite(t[0], &table),
        );
    }
}

#[test]
fn sweep_variance_matches_its_composite() {
    let grid = ErpGrid::new(8).unwrap();
    let (cameras, batch, n) = (3, 2, 40);
    // 2 channels: the generic kernel; 4, 8 and 16 the unrolled ones
    for c in [2, 4, 8, 16] {
        let f = var(
            &[cameras * batch, grid.height(), grid.width(), c],
            80 + c as u64,
        );
        let tables: Vec<SampleTable> = (0..cameras)
            .map(|cam| random_table(grid, n, 90 + cam as u64, |_| false))
            .collect();
        check(
            &format!("sweep_variance, {c} channels"),
            &[&f],
            &|t| sweep_variance(t[0], &tables),
            &|t| sweep_variance_composite(t[0], &tables, None),
        );
        // cameras blind to some samples, some samples seen by fewer than two
        let blind =
            |cam: usize, k: usize| (k + cam).is_multiple_of(4) || (k.is_multiple_of(7) && cam < 2);
        let masked: Vec<SampleTable> = (0..cameras)
            .map(|cam| random_table(grid, n, 90 + cam as u64, |k| blind(cam, k)))
            .collect();
        let scale = view_scale(&masked);
        assert!(scale.contains(&0.0) && scale.iter().any(|&s| s > 0.4));
        check(
            &format!("sweep_variance_visible, {c} channels"),
            &[&f],
            &|t| sweep_variance_visible(t[0], &masked, &scale),
            &|t| sweep_variance_composite(t[0], &masked, Some(&scale)),
        );
    }
}

#[test]
fn linear_resampling_matches_its_composite() {
    let x = var(&[2, 5, 3, 4], 101);
    // up, down, to the same length, and to and from a single sample
    for (dim, out_len) in [(1, 9), (3, 2), (2, 3), (2, 1), (0, 5)] {
        let map = LinearAxisMap::new(x.dim(dim).unwrap(), out_len).unwrap();
        check(
            &format!("resample_linear_axis axis {dim} -> {out_len}"),
            &[&x],
            &|t| resample_linear_axis(t[0], dim, out_len),
            &|t| resample_linear_axis_composite(t[0], dim, &map),
        );
    }
    check(
        "upsample_trilinear",
        &[&x],
        &|t| upsample_trilinear(t[0], 6, 9, 8),
        &|t| upsample_trilinear_composite(t[0], 6, 9, 8),
    );
}

#[test]
fn add_bias_matches_its_composite() {
    // a volume's channels (more rows than one task takes) and a 2-D layer's
    for (dims, seed) in [(vec![1, 5, 30, 31, 8], 131), (vec![2, 3, 4, 3], 132)] {
        let c = dims[dims.len() - 1];
        let (y, b) = (var(&dims, seed), var(&[c], seed + 1));
        check(
            &format!("add_bias {dims:?}"),
            &[&y, &b],
            &|t| add_bias(t[0], t[1]),
            &|t| t[0].broadcast_add(t[1]),
        );
    }
    let y = var(&[2, 3, 4], 133);
    let wrong = var(&[3], 134);
    let err = add_bias(y.as_tensor(), wrong.as_tensor())
        .unwrap_err()
        .to_string();
    assert!(err.contains("add_bias") && err.contains("[3]"), "{err}");
}

#[test]
fn soft_argmin_index_matches_its_composite() {
    // costs spread over several units, so that the softmax is neither flat nor one-hot; two
    // batches, an odd width, and rows of one pixel
    for (dims, seed) in [
        ([2, 7, 3, 5], 121),
        ([1, 24, 4, 1], 122),
        ([1, 2, 1, 3], 123),
    ] {
        let z = var(&dims, seed);
        let scaled = |t: &Tensor| t * 4.0;
        check(
            &format!("soft_argmin_index {dims:?}"),
            &[&z],
            &|t| soft_argmin_index(&scaled(t[0])?),
            &|t| soft_argmin_index_composite(&scaled(t[0])?),
        );
    }
    // a pixel whose cost peaks on one hypothesis reads that hypothesis' index
    let mut peaked = vec![0f32; 5];
    peaked[3] = 50.0;
    let z = Tensor::from_vec(peaked, (1, 5, 1, 1), &Device::Cpu).unwrap();
    let index = values(&soft_argmin_index(&z).unwrap());
    assert!((index[0] - 0.75).abs() < 1e-6, "index {index:?}");
}

/// Inside `with_composites` the ops themselves take the composites (what a GPU gets), forward
/// and backward; the kernels come back afterwards, also after a panic.
#[test]
fn with_composites_switches_every_op_to_its_composite() {
    let (x, w) = (var(&[1, 4, 5, 6, 3], 111), var(&[3, 3, 3, 3, 4], 112));
    let run = || forward_backward(&[&x, &w], &|t| conv3d(t[0], t[1], [2; 3], [1; 3]));
    let kernel = run();
    let switched = with_composites(|| {
        assert!(!has_custom_kernels(&Device::Cpu));
        run()
    });
    let composite = forward_backward(&[&x, &w], &|t| conv3d_composite(t[0], t[1], [2; 3], [1; 3]));
    // the same candle ops in the same order: identical, not just close
    assert_eq!(switched, composite);
    assert_close("conv3d", &kernel.1, &switched.1);
    assert!(has_custom_kernels(&Device::Cpu));
    let caught = std::panic::catch_unwind(|| with_composites(|| panic!("inside")));
    assert!(caught.is_err());
    assert!(has_custom_kernels(&Device::Cpu), "restored after a panic");
}
