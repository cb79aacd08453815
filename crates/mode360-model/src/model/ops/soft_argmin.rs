//! `soft_argmin_index`: the regression's expected hypothesis index, softmax and expectation in
//! one pass, for training (inference has its own fused readout, `regression::regress_inference`).
//!
//! ```text
//! p[b, n, k] = exp(z[b, n, k] − m[b, k]) / S[b, k]     m = max_n z, S = Σ_n exp(z − m)
//! E[b, k]    = Σ_n p[b, n, k] · n / (N − 1)
//! ∂L/∂z[b, n, k] = g[b, k] · p[b, n, k] · (n / (N − 1) − E[b, k])
//! ```
//!
//! With `z (B, N, H, W)` (`k` a pixel) and `E (B, H, W)`. As candle ops (softmax over the
//! hypothesis axis, a broadcast product and a sum) the backward pass reduces over two
//! broadcasts along a strided axis of 3 million values per stage at 256, which took a fifth of
//! a one-thread training step (perf); the kernel recomputes `m`, `S` and `E` per pixel row and
//! writes the gradient plane by plane. Its gradient is computed by the kernel, not by further
//! ops, so it has no second derivative (nothing here needs one).

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

use super::composite::soft_argmin_index_composite;
use super::types::{cpu_slice, dims_of, has_custom_kernels, COST_VOLUME_RANK};

/// The op's name in errors.
const OP: &str = "soft_argmin_index";

/// See the module docs: `z (B, N, H, W)` -> `(B, H, W)`, the expected index over `N`
/// hypotheses normalised to [0, 1].
pub fn soft_argmin_index(z: &Tensor) -> Result<Tensor> {
    let dims = dims_of(z, OP, "z", COST_VOLUME_RANK)?;
    if !has_custom_kernels(z.device()) || z.dtype() != DType::F32 || dims[1] < 2 {
        return soft_argmin_index_composite(z);
    }
    z.contiguous()?.apply_op1(SoftArgminOp)
}

struct SoftArgminOp;

/// Per pixel of one `(b, row)`: the max `m`, the sum `S` of `exp(z − m)` and the expectation
/// `E` (see the module docs), from `z`'s `N` planes of `pixels` values each.
fn row_moments(
    z: &[f32],
    n: usize,
    pixels: usize,
    start: usize,
    m: &mut [f32],
    s: &mut [f32],
    e: &mut [f32],
) {
    let width = m.len();
    m.fill(f32::NEG_INFINITY);
    for i in 0..n {
        let plane = &z[i * pixels + start..][..width];
        m.iter_mut().zip(plane).for_each(|(a, &v)| *a = a.max(v));
    }
    s.fill(0.0);
    e.fill(0.0);
    let step = 1.0 / (n - 1) as f32;
    for i in 0..n {
        let plane = &z[i * pixels + start..][..width];
        let k = i as f32 * step;
        for ((&v, &mx), (sum, ex)) in plane
            .iter()
            .zip(m.iter())
            .zip(s.iter_mut().zip(e.iter_mut()))
        {
            let p = (v - mx).exp();
            *sum += p;
            *ex += p * k;
        }
    }
    e.iter_mut().zip(s.iter()).for_each(|(ex, &sum)| *ex /= sum);
}

impl CustomOp1 for SoftArgminOp {
    fn name(&self) -> &'static str {
        OP
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let z = cpu_slice(s, l, OP)?;
        let (b, n, h, w) = l.shape().dims4()?;
        let pixels = h * w;
        let mut e = vec![0f32; b * pixels];
        e.par_chunks_mut(w).enumerate().for_each(|(row, e_row)| {
            let (bi, v) = (row / h, row % h);
            let (mut m, mut sum) = (vec![0f32; w], vec![0f32; w]);
            let zb = &z[bi * n * pixels..(bi + 1) * n * pixels];
            row_moments(zb, n, pixels, v * w, &mut m, &mut sum, e_row);
        });
        Ok((CpuStorage::F32(e), Shape::from((b, h, w))))
    }

    fn bwd(&self, z: &Tensor, _e: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        let (b, n, h, w) = z.dims4()?;
        let pixels = h * w;
        let zv = z.flatten_all()?.to_vec1::<f32>()?;
        let g = grad.flatten_all()?.to_vec1::<f32>()?;
        // per pixel: m, 1 / S and E
        let (mut m, mut inv_s, mut e) = (
            vec![0f32; b * pixels],
            vec![0f32; b * pixels],
            vec![0f32; b * pixels],
        );
        m.par_chunks_mut(w)
            .zip(inv_s.par_chunks_mut(w))
            .zip(e.par_chunks_mut(w))
            .enumerate()
            .for_each(|(row, ((m_row, s_row), e_row))| {
                let (bi, v) = (row / h, row % h);
                let zb = &zv[bi * n * pixels..(bi + 1) * n * pixels];
                row_moments(zb, n, pixels, v * w, m_row, s_row, e_row);
                s_row.iter_mut().for_each(|s| *s = 1.0 / *s);
            });
        let step = 1.0 / (n - 1) as f32;
        let mut dz = vec![0f32; zv.len()];
        dz.par_chunks_mut(pixels)
            .enumerate()
            .for_each(|(plane, dz_plane)| {
                let (bi, i) = (plane / n, plane % n);
                let k = i as f32 * step;
                let zp = &zv[plane * pixels..(plane + 1) * pixels];
                for (j, d) in dz_plane.iter_mut().enumerate() {
                    let q = bi * pixels + j;
                    let p = (zp[j] - m[q]).exp() * inv_s[q];
                    *d = g[q] * p * (k - e[q]);
                }
            });
        Ok(Some(Tensor::from_vec(dz, z.shape(), z.device())?))
    }
}
