//! The same ops built only from candle ops that have gradients (matmul, pad, narrow, reshape,
//! index_select), so they run on any candle device: the path of devices without the custom CPU
//! kernels (CUDA, Metal), chosen by [`super::has_custom_kernels`]. Slower and more memory hungry
//! than the kernels on the CPU, but exact; tests check that both agree, forward and backward
//! (`tests/core/ops_composite.rs`). Unlike the fused kernels, the fused composites have
//! gradients.

use candle_core::{IndexOp, Result, Tensor};

use super::sample_table::SampleTable;
use super::types::{
    dims_of, Conv3dGeometry, Epilogue, LinearAxisMap, OpsError, COST_VOLUME_RANK, SPATIAL_AXES_3D,
};

/// First spatial axis of a channels-last volume `(B, D, H, W, C)`.
const FIRST_SPATIAL_AXIS: usize = 1;

/// The `n` positions `start, start + s, …, start + (n − 1) s` of `axis`.
fn strided_window(t: &Tensor, axis: usize, start: usize, n: usize, s: usize) -> Result<Tensor> {
    let t = t.narrow(axis, start, (n - 1) * s + 1)?;
    if s == 1 {
        return Ok(t);
    }
    // (…, (n−1)s+1, …) -> (…, n·s, …) -> (…, n, s, …) -> (…, n, 1, …) -> (…, n, …)
    let t = t.pad_with_zeros(axis, 0, s - 1)?;
    let mut dims = t.dims().to_vec();
    dims[axis] = n;
    dims.insert(axis + 1, s);
    t.reshape(dims)?.narrow(axis + 1, 0, 1)?.squeeze(axis + 1)
}

/// Adjoint of [`strided_window`]: places the `n` entries of `axis` at `start + i s` in a zero
/// axis of length `len`.
fn strided_place(t: &Tensor, axis: usize, start: usize, s: usize, len: usize) -> Result<Tensor> {
    let n = t.dim(axis)?;
    let t = if s == 1 {
        t.clone()
    } else {
        // (…, n, …) -> (…, n, 1, …) -> (…, n, s, …) -> (…, n·s, …) -> (…, (n−1)s+1, …)
        let t = t.unsqueeze(axis + 1)?.pad_with_zeros(axis + 1, 0, s - 1)?;
        let mut dims = t.dims().to_vec();
        dims.remove(axis + 1);
        dims[axis] = n * s;
        t.reshape(dims)?.narrow(axis, 0, (n - 1) * s + 1)?
    };
    let used = start + (n - 1) * s + 1;
    t.pad_with_zeros(axis, start, len - used)
}

fn pad_spatial(x: &Tensor, padding: [usize; 3]) -> Result<Tensor> {
    let mut x = x.clone();
    for (axis, &p) in padding.iter().enumerate() {
        if p > 0 {
            x = x.pad_with_zeros(FIRST_SPATIAL_AXIS + axis, p, p)?;
        }
    }
    Ok(x)
}

/// The input values one kernel tap `t` sees: `xp[b, o·s + t, ci]` as `(B·Do·Ho·Wo, Ci)`.
fn tap_columns(xp: &Tensor, g: &Conv3dGeometry, tap: [usize; 3]) -> Result<Tensor> {
    let mut t = xp.clone();
    let per_axis = tap.iter().zip(g.out_dims.iter().zip(g.stride.iter()));
    for (axis, (&start, (&n, &s))) in per_axis.enumerate() {
        t = strided_window(&t, FIRST_SPATIAL_AXIS + axis, start, n, s)?;
    }
    // (B, Do, Ho, Wo, Ci) -> (B·Do·Ho·Wo, Ci)
    t.reshape(((), g.c_in))
}

fn taps(kernel: [usize; 3]) -> impl Iterator<Item = [usize; 3]> {
    let [kd, kh, kw] = kernel;
    (0..kd).flat_map(move |a| (0..kh).flat_map(move |c| (0..kw).map(move |e| [a, c, e])))
}

fn geometry(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
) -> Result<Conv3dGeometry> {
    const OP: &str = "conv3d_composite";
    let x_dims = dims_of(x, OP, "x", 5)?;
    let w_dims = dims_of(w, OP, "w", 5)?;
    if x_dims[4] != w_dims[3] {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("x {x_dims:?} and w {w_dims:?} disagree on Cin"),
        }
        .into());
    }
    Ok(Conv3dGeometry::new(
        x_dims[0],
        [x_dims[1], x_dims[2], x_dims[3]],
        [w_dims[0], w_dims[1], w_dims[2]],
        stride,
        padding,
        w_dims[3],
        w_dims[4],
    )?)
}

/// [`super::conv3d`] as a sum over the `kD·kH·kW` taps of `(N, Cin) · (Cin, Cout)` matmuls.
pub fn conv3d_composite(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
) -> Result<Tensor> {
    let g = geometry(x, w, stride, padding)?;
    let xp = pad_spatial(x, padding)?; // (B, Dp, Hp, Wp, Ci)
    let mut acc: Option<Tensor> = None;
    for tap in taps(g.kernel) {
        let cols = tap_columns(&xp, &g, tap)?; // (N, Ci)
        let w_tap = w.i((tap[0], tap[1], tap[2]))?; // (Ci, Co)
        let y = cols.matmul(&w_tap)?; // (N, Co)
        acc = Some(match acc {
            None => y,
            Some(a) => (a + y)?,
        });
    }
    let [d, h, wd] = g.out_dims;
    match acc {
        Some(a) => a.reshape((g.batch, d, h, wd, g.c_out)), // (B, Do, Ho, Wo, Co)
        None => Err(OpsError::Shape {
            op: "conv3d_composite",
            what: "empty kernel".to_string(),
        }
        .into()),
    }
}

/// [`super::conv3d_input_grad`]: each tap's `(N, Cout) · (Cout, Cin)` product placed at
/// `o·s + t` in the padded input, summed, then cropped.
pub fn conv3d_input_grad_composite(
    dy: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    in_dims: [usize; 3],
) -> Result<Tensor> {
    let dy_dims = dims_of(dy, "conv3d_input_grad_composite", "dy", 5)?;
    let w_dims = dims_of(w, "conv3d_input_grad_composite", "w", 5)?;
    let g = Conv3dGeometry::new(
        dy_dims[0],
        in_dims,
        [w_dims[0], w_dims[1], w_dims[2]],
        stride,
        padding,
        w_dims[3],
        w_dims[4],
    )?;
    let padded = g.padded_dims();
    let dy_flat = dy.reshape(((), g.c_out))?; // (N, Co)
    let [od, oh, ow] = g.out_dims;
    let mut acc: Option<Tensor> = None;
    for tap in taps(g.kernel) {
        let w_tap = w.i((tap[0], tap[1], tap[2]))?; // (Ci, Co)
        let mut t = dy_flat
            .matmul(&w_tap.t()?)? // (N, Ci)
            .reshape((g.batch, od, oh, ow, g.c_in))?;
        for axis in 0..SPATIAL_AXES_3D {
            t = strided_place(
                &t,
                FIRST_SPATIAL_AXIS + axis,
                tap[axis],
                g.stride[axis],
                padded[axis],
            )?;
        }
        acc = Some(match acc {
            None => t,
            Some(a) => (a + t)?,
        });
    }
    let Some(mut dx) = acc else {
        return Err(OpsError::Shape {
            op: "conv3d_input_grad_composite",
            what: "empty kernel".to_string(),
        }
        .into());
    };
    // (B, Dp, Hp, Wp, Ci) -> (B, D, H, W, Ci)
    for axis in 0..SPATIAL_AXES_3D {
        dx = dx.narrow(FIRST_SPATIAL_AXIS + axis, padding[axis], in_dims[axis])?;
    }
    dx.contiguous()
}

/// [`super::conv3d_weight_grad`]: per tap `(N, Cin)ᵀ · (N, Cout)`, stacked.
pub fn conv3d_weight_grad_composite(
    x: &Tensor,
    dy: &Tensor,
    kernel: [usize; 3],
    stride: [usize; 3],
    padding: [usize; 3],
) -> Result<Tensor> {
    let x_dims = dims_of(x, "conv3d_weight_grad_composite", "x", 5)?;
    let dy_dims = dims_of(dy, "conv3d_weight_grad_composite", "dy", 5)?;
    let g = Conv3dGeometry::new(
        x_dims[0],
        [x_dims[1], x_dims[2], x_dims[3]],
        kernel,
        stride,
        padding,
        x_dims[4],
        dy_dims[4],
    )?;
    let xp = pad_spatial(x, padding)?;
    let dy_flat = dy.reshape(((), g.c_out))?; // (N, Co)
    let per_tap = taps(kernel)
        .map(|tap| tap_columns(&xp, &g, tap)?.t()?.matmul(&dy_flat)) // (Ci, Co)
        .collect::<Result<Vec<_>>>()?;
    let [kd, kh, kw] = kernel;
    Tensor::stack(&per_tap, 0)?.reshape((kd, kh, kw, g.c_in, g.c_out))
}

/// [`super::conv_transpose3d`] from [`conv3d_input_grad_composite`].
pub fn conv_transpose3d_composite(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    output_padding: [usize; 3],
) -> Result<Tensor> {
    let x_dims = dims_of(x, "conv_transpose3d_composite", "x", 5)?;
    let w_dims = dims_of(w, "conv_transpose3d_composite", "w", 5)?;
    let out_dims: [usize; 3] = std::array::from_fn(|axis| {
        ((x_dims[axis + 1] - 1) * stride[axis] + w_dims[axis] + output_padding[axis])
            .saturating_sub(2 * padding[axis])
    });
    conv3d_input_grad_composite(x, &w.transpose(3, 4)?, stride, padding, out_dims)
}

/// [`super::table_sample`] with `index_select`: features `(B, H, W, C)` -> `(B, N, C)`.
pub fn table_sample_composite(features: &Tensor, table: &SampleTable) -> Result<Tensor> {
    let dims = dims_of(features, "table_sample_composite", "features", 4)?;
    let (b, pixels, c) = (dims[0], dims[1] * dims[2], dims[3]);
    table.check_pixels(pixels, "table_sample_composite")?;
    let n = table.len();
    let on_device = table.on_device(features.device())?;
    features
        .reshape((b, pixels, c))? // (B, H·W, C)
        .index_select(&on_device.index, 1)? // (B, 4N, C)
        .reshape((b, n, SampleTable::TAPS, c))? // (B, N, 4, C)
        .broadcast_mul(&on_device.weight)?
        .sum(2) // (B, N, C)
}

/// [`super::sweep_variance`] (`view_scale: None`) and [`super::sweep_variance_visible`]
/// (`Some`) from [`table_sample_composite`]: stacked features `(M B, H, W, C)`, one table per
/// camera -> `(B, N, C)`, `var = s Σ_c v_c² − (s Σ_c v_c)²` with `s = 1/M` or the per-sample
/// view scale.
pub fn sweep_variance_composite(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&[f32]>,
) -> Result<Tensor> {
    sweep_variance_with(features, tables, view_scale, table_sample_composite)
}

/// [`sweep_variance_composite`] with another gather than [`table_sample_composite`] (a GPU's
/// own kernel).
pub(super) fn sweep_variance_with(
    features: &Tensor,
    tables: &[SampleTable],
    view_scale: Option<&[f32]>,
    sample: impl Fn(&Tensor, &SampleTable) -> Result<Tensor>,
) -> Result<Tensor> {
    const OP: &str = "sweep_variance_composite";
    let dims = dims_of(features, OP, "features", 4)?;
    let cameras = tables.len();
    let samples = tables.first().map_or(0, SampleTable::len);
    let shape_error = |what: String| OpsError::Shape { op: OP, what };
    if cameras == 0 || !dims[0].is_multiple_of(cameras) {
        return Err(shape_error(format!("features {dims:?} for {cameras} cameras' tables")).into());
    }
    if tables.iter().any(|t| t.len() != samples) || view_scale.is_some_and(|s| s.len() != samples) {
        return Err(shape_error(format!(
            "tables or view scales not all of {samples} samples"
        ))
        .into());
    }
    let batch = dims[0] / cameras;
    let mut sum: Option<Tensor> = None;
    let mut sum_sq: Option<Tensor> = None;
    for (cam, table) in tables.iter().enumerate() {
        // (B, N, C)
        let v = sample(&features.narrow(0, cam * batch, batch)?, table)?;
        let sq = v.sqr()?;
        sum = Some(match sum {
            Some(s) => (s + v)?,
            None => v,
        });
        sum_sq = Some(match sum_sq {
            Some(s) => (s + sq)?,
            None => sq,
        });
    }
    let (Some(s), Some(q)) = (sum, sum_sq) else {
        return Err(shape_error("no cameras".to_string()).into());
    };
    match view_scale {
        None => {
            let m = cameras as f64;
            let mean = (s / m)?;
            (q / m)? - mean.sqr()?
        }
        Some(scale) => {
            // (N) -> (1, N, 1)
            let scale = Tensor::from_slice(scale, (1, samples, 1), features.device())?;
            let mean = s.broadcast_mul(&scale)?;
            q.broadcast_mul(&scale)? - mean.sqr()?
        }
    }
}

/// [`super::conv3d_fused`] from [`conv3d_composite`] and the epilogue as candle ops.
pub fn conv3d_fused_composite(
    x: &Tensor,
    w: &Tensor,
    stride: [usize; 3],
    padding: [usize; 3],
    epilogue: Epilogue,
) -> Result<Tensor> {
    apply_epilogue(conv3d_composite(x, w, stride, padding)?, epilogue)
}

/// [`super::conv_transpose3d_x2_fused`] from [`conv_transpose3d_composite`] (kernel 3,
/// stride 2, padding 1, output padding 1: exactly twice the size) and the epilogue.
pub fn conv_transpose3d_x2_fused_composite(
    x: &Tensor,
    w: &Tensor,
    epilogue: Epilogue,
) -> Result<Tensor> {
    let w_dims = dims_of(w, "conv_transpose3d_x2_fused_composite", "w", 5)?;
    if w_dims[..3] != [3, 3, 3] {
        return Err(OpsError::Shape {
            op: "conv_transpose3d_x2_fused_composite",
            what: format!("w {w_dims:?}: expected a 3x3x3 kernel"),
        }
        .into());
    }
    let up = conv_transpose3d_composite(x, w, [2; 3], [1; 3], [1; 3])?;
    apply_epilogue(up, epilogue)
}

/// `relu?(y + bias + residual)`.
fn apply_epilogue(y: Tensor, epilogue: Epilogue) -> Result<Tensor> {
    let y = match epilogue.bias {
        Some(b) => y.broadcast_add(b)?,
        None => y,
    };
    let y = match epilogue.residual {
        Some(r) if r.dims() != y.dims() => {
            return Err(OpsError::Shape {
                op: "conv3d_fused_composite",
                what: format!("residual {:?} for an output {:?}", r.dims(), y.dims()),
            }
            .into())
        }
        Some(r) => (y + r)?,
        None => y,
    };
    if epilogue.relu {
        y.relu()
    } else {
        Ok(y)
    }
}

/// [`super::resample_linear_axis`] with two `index_select`s and a weighted sum.
pub fn resample_linear_axis_composite(
    x: &Tensor,
    dim: usize,
    map: &LinearAxisMap,
) -> Result<Tensor> {
    let device = x.device();
    let out_len = map.out_len();
    let i0 = Tensor::from_slice(map.lower_indices(), out_len, device)?;
    let i1 = Tensor::from_slice(map.upper_indices(), out_len, device)?;
    let mut wshape = vec![1usize; x.rank()];
    wshape[dim] = out_len;
    let w1 = Tensor::from_slice(map.upper_weights(), wshape.as_slice(), device)?;
    let w0 = w1.affine(-1.0, 1.0)?;
    let lo = x.index_select(&i0, dim)?.broadcast_mul(&w0)?;
    let hi = x.index_select(&i1, dim)?.broadcast_mul(&w1)?;
    lo + hi
}

/// [`super::upsample_trilinear`] from [`resample_linear_axis_composite`].
pub fn upsample_trilinear_composite(
    x: &Tensor,
    out_d: usize,
    out_h: usize,
    out_w: usize,
) -> Result<Tensor> {
    let dims = dims_of(x, "upsample_trilinear_composite", "x", 4)?;
    let mut t = x.clone();
    for (axis, out_len) in [(1, out_d), (2, out_h), (3, out_w)] {
        let map = LinearAxisMap::new(dims[axis], out_len)?;
        t = resample_linear_axis_composite(&t, axis, &map)?;
    }
    Ok(t)
}

/// [`fine_mix`]'s name, in errors and as the custom op's.
pub(super) const FINE_MIX_OP: &str = "fine_mix";

/// [`fine_mix`]'s hidden channels `Cf`, after checking the three shapes agree (here, so the
/// kernel and this composite share it without importing each other).
pub(super) fn fine_mix_channels(up: &Tensor, part: &Tensor, w: &Tensor) -> Result<usize> {
    let (du, dp, dw) = (up.dims(), part.dims(), w.dims());
    let cf = dp.last().copied().unwrap_or(0);
    if dp.len() != du.len() + 1 || dp[..du.len()] != *du || dw != [2, cf] || cf == 0 {
        return Err(OpsError::Shape {
            op: FINE_MIX_OP,
            what: format!("up {du:?}, part {dp:?} and w {dw:?}: want (…), (…, Cf) and (2, Cf)"),
        }
        .into());
    }
    Ok(cf)
}

/// [`fine_mix`] from candle ops (the path a GPU takes).
pub fn fine_mix_composite(up: &Tensor, part: &Tensor, w: &Tensor) -> Result<Tensor> {
    fine_mix_channels(up, part, w)?;
    let last = part.rank() - 1;
    // (…, Cf)
    let hidden = up
        .unsqueeze(last)?
        .broadcast_mul(&w.get(0)?)?
        .add(part)?
        .relu()?;
    up + hidden.broadcast_mul(&w.get(1)?)?.sum(last)?
}

/// [`super::soft_argmin_index`] from candle ops: the softmax over the hypothesis axis of
/// `z (B, N, H, W)`, then the expected index `n / (N − 1)`: `(B, H, W)`.
pub fn soft_argmin_index_composite(z: &Tensor) -> Result<Tensor> {
    const HYPOTHESIS_AXIS: usize = 1;
    let n = dims_of(z, "soft_argmin_index_composite", "z", COST_VOLUME_RANK)?[HYPOTHESIS_AXIS];
    let probabilities = candle_nn::ops::softmax(z, HYPOTHESIS_AXIS)?;
    let step = 1.0 / n.saturating_sub(1).max(1) as f32;
    let index: Vec<f32> = (0..n).map(|i| i as f32 * step).collect();
    // (1, N, 1, 1)
    let index = Tensor::from_vec(index, (1, n, 1, 1), z.device())?.to_dtype(z.dtype())?;
    probabilities.broadcast_mul(&index)?.sum(HYPOTHESIS_AXIS)
}
