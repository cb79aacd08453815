//! `fine_mix`: the fine head's per-cell layers ([`crate::model::fine_head`]) in one pass,
//!
//! ```text
//! h[n, c]  = part[n, c] + up[n] · w[0, c]
//! out[n]   = up[n] + Σ_c w[1, c] · relu(h[n, c])
//! ∂L/∂up[n]      = g[n] (1 + Σ_{c: h > 0} w[1, c] w[0, c])
//! ∂L/∂part[n, c] = g[n] w[1, c]            where h[n, c] > 0, else 0
//! ∂L/∂w[0, c]    = Σ_{n: h > 0} g[n] w[1, c] up[n]
//! ∂L/∂w[1, c]    = Σ_n g[n] relu(h[n, c])
//! ```
//!
//! With `up (B, D, H, W)`, `part (B, D, H, W, Cf)` and `w (2, Cf)`. As candle ops these are six
//! broadcasts, a ReLU and a sum over 1.5 million cells at 256, whose backward passes (each a
//! reduction over a broadcast) took about 1.5 s of a one-thread training step; the kernel
//! takes one pass each way. Its gradient is computed by that kernel, not by further ops, so
//! it has no second derivative (nothing here needs one).

use candle_core::{CpuStorage, CustomOp3, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

use super::composite::{fine_mix_channels, fine_mix_composite, FINE_MIX_OP as OP};
use super::types::{cpu_slice, has_custom_kernels};

/// Cells per rayon task in the backward pass's weight sums.
const CHUNK_CELLS: usize = 1 << 14;

/// See the module docs: `up (…)`, `part (…, Cf)`, `w (2, Cf)` -> `(…)`.
pub fn fine_mix(up: &Tensor, part: &Tensor, w: &Tensor) -> Result<Tensor> {
    if !has_custom_kernels(up.device()) || up.dtype() != DType::F32 {
        return fine_mix_composite(up, part, w); // checks the shapes itself
    }
    fine_mix_channels(up, part, w)?;
    up.contiguous()?
        .apply_op3(&part.contiguous()?, &w.contiguous()?, FineMixOp)
}

struct FineMixOp;

impl CustomOp3 for FineMixOp {
    fn name(&self) -> &'static str {
        OP
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (up, part, w) = (
            cpu_slice(s1, l1, OP)?,
            cpu_slice(s2, l2, OP)?,
            cpu_slice(s3, l3, OP)?,
        );
        let cf = w.len() / 2;
        let (w_up, w_out) = w.split_at(cf);
        let mut out = vec![0f32; up.len()];
        out.par_chunks_mut(CHUNK_CELLS)
            .enumerate()
            .for_each(|(k, chunk)| {
                let start = k * CHUNK_CELLS;
                for (i, o) in chunk.iter_mut().enumerate() {
                    let n = start + i;
                    let u = up[n];
                    let hidden = &part[n * cf..(n + 1) * cf];
                    *o = u
                        + (0..cf)
                            .map(|c| w_out[c] * (hidden[c] + u * w_up[c]).max(0.0))
                            .sum::<f32>();
                }
            });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        up: &Tensor,
        part: &Tensor,
        w: &Tensor,
        _out: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let values = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let (u, p, wv, g) = (values(up)?, values(part)?, values(w)?, values(grad)?);
        let cf = wv.len() / 2;
        let (w_up, w_out) = wv.split_at(cf);
        let mut d_up = vec![0f32; u.len()];
        let mut d_part = vec![0f32; p.len()];
        // (∂w[0], ∂w[1]) per chunk, summed after
        let partial: Vec<Vec<f32>> = d_up
            .par_chunks_mut(CHUNK_CELLS)
            .zip(d_part.par_chunks_mut(CHUNK_CELLS * cf))
            .enumerate()
            .map(|(k, (du_chunk, dp_chunk))| {
                let start = k * CHUNK_CELLS;
                let mut dw = vec![0f32; 2 * cf];
                for (i, du) in du_chunk.iter_mut().enumerate() {
                    let n = start + i;
                    let (un, gn) = (u[n], g[n]);
                    let mut d = gn;
                    for c in 0..cf {
                        let h = p[n * cf + c] + un * w_up[c];
                        if h > 0.0 {
                            let gh = gn * w_out[c];
                            d += gh * w_up[c];
                            dp_chunk[i * cf + c] = gh;
                            dw[c] += gh * un;
                            dw[cf + c] += gn * h;
                        }
                    }
                    *du = d;
                }
                dw
            })
            .collect();
        let mut dw = vec![0f32; 2 * cf];
        for chunk in &partial {
            dw.iter_mut().zip(chunk).for_each(|(a, b)| *a += b);
        }
        let device = up.device();
        Ok((
            Some(Tensor::from_vec(d_up, up.shape(), device)?),
            Some(Tensor::from_vec(d_part, part.shape(), device)?),
            Some(Tensor::from_vec(dw, w.shape(), device)?),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};

    fn max_diff(a: &Tensor, b: &Tensor) -> Result<f32> {
        (a - b)?.abs()?.max_all()?.to_scalar::<f32>()
    }

    #[test]
    fn the_kernel_matches_the_composite_forward_and_backward() -> Result<()> {
        let dev = Device::Cpu;
        // enough cells for several chunks and a remainder, both signs of h
        let dims = (1, 3, 70, 90);
        let up = Var::from_tensor(&Tensor::randn(0f32, 1.0, dims, &dev)?)?;
        let part = Var::from_tensor(&Tensor::randn(0f32, 1.0, (1, 3, 70, 90, 4), &dev)?)?;
        let w = Var::from_tensor(&Tensor::randn(0f32, 1.0, (2, 4), &dev)?)?;
        let r = Tensor::randn(0f32, 1.0, dims, &dev)?;
        let fast = fine_mix(up.as_tensor(), part.as_tensor(), w.as_tensor())?;
        let slow = fine_mix_composite(up.as_tensor(), part.as_tensor(), w.as_tensor())?;
        assert!(max_diff(&fast, &slow)? < 1e-5);
        let gf = (fast * &r)?.sum_all()?.backward()?;
        let gs = (slow * &r)?.sum_all()?.backward()?;
        for (name, v, tol) in [("up", &up, 1e-5), ("part", &part, 1e-5), ("w", &w, 1e-4)] {
            let (a, b) = (gf.get(v.as_tensor()), gs.get(v.as_tensor()));
            let (a, b) = (a.expect("kernel grad"), b.expect("composite grad"));
            // the weight gradients are sums over 18,900 cells: relative tolerance
            let scale = b.abs()?.max_all()?.to_scalar::<f32>()?.max(1.0);
            let d = max_diff(a, b)? / scale;
            assert!(d < tol, "{name}: {d}");
        }
        Ok(())
    }

    #[test]
    fn mismatched_shapes_are_named() {
        let dev = Device::Cpu;
        let up = Tensor::zeros((1, 2, 3, 4), DType::F32, &dev).expect("zeros");
        let part = Tensor::zeros((1, 2, 3, 5, 4), DType::F32, &dev).expect("zeros");
        let w = Tensor::zeros((2, 4), DType::F32, &dev).expect("zeros");
        let err = fine_mix(&up, &part, &w).expect_err("mismatched cells");
        assert!(err.to_string().contains("[1, 2, 3, 5, 4]"), "{err}");
    }
}
