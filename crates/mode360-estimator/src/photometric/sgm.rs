//! Semi-global aggregation of a cost volume along rows (with longitude wrap) and columns.
//!
//! The volume is laid out `[v][u][d]`. Along a path `r`, with `L_r(p - r, .)` the previous
//! pixel's path cost:
//!
//! ```text
//! L_r(p, d) = C(p, d) + min( L_r(p-r, d),
//!                            L_r(p-r, d-1) + P1,  L_r(p-r, d+1) + P1,
//!                            min_k L_r(p-r, k) + P2 ) - min_k L_r(p-r, k)
//! S(p, d)   = sum_r L_r(p, d)
//! ```
//!
//! `P2` adapts to the guide image `g` (the output view): across an intensity edge a depth jump
//! is likelier, so `P2' = max(P1, P2 / (1 + |g(p) - g(p - r)| / s_edge))`.
//!
//! Rows are closed loops on the sphere: a row path starts `warmup` columns before the column
//! where accumulation begins, so no seam appears at `u = 0`.

use rayon::prelude::*;

/// Smoothness penalties, in cost units (one pixel's matching cost lies in [0, 1]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SgmPenalties {
    /// Penalty for a one-hypothesis step between neighbours.
    pub p1: f32,
    /// Penalty for a larger jump.
    pub p2: f32,
    /// Guide intensity step at which `P2` is halved; 0 keeps `P2` fixed.
    pub edge_scale: f32,
}

impl SgmPenalties {
    /// Penalties between two neighbours of guide intensities `a` and `b`.
    #[inline]
    fn between(&self, a: f32, b: f32) -> SgmPenalties {
        if self.edge_scale <= 0.0 {
            return *self;
        }
        let p2 = (self.p2 / (1.0 + (a - b).abs() / self.edge_scale)).max(self.p1);
        SgmPenalties { p2, ..*self }
    }
}

/// Number of aggregation paths: left, right, down, up.
pub(crate) const PATH_COUNT: usize = 4;

/// One path step: `cur = cost + min(prev, prev±1 + P1, min(prev) + P2) - min(prev)`.
#[inline]
fn step(cost: &[f32], prev: &[f32], cur: &mut [f32], pen: SgmPenalties) {
    let d_count = cost.len();
    let min_prev = prev.iter().copied().fold(f32::INFINITY, f32::min);
    let jump = min_prev + pen.p2;
    for d in 0..d_count {
        let mut best = prev[d].min(jump);
        if d > 0 {
            best = best.min(prev[d - 1] + pen.p1);
        }
        if d + 1 < d_count {
            best = best.min(prev[d + 1] + pen.p1);
        }
        cur[d] = cost[d] + best - min_prev;
    }
}

/// Aggregated cost `S` of `volume` (`[v][u][d]`, `w x h` pixels, `d_count` hypotheses).
pub(crate) fn aggregate(
    volume: &[f32],
    guide: &[f32],
    w: usize,
    h: usize,
    d_count: usize,
    pen: SgmPenalties,
    warmup: usize,
) -> Vec<f32> {
    let row_len = w * d_count;
    let mut sum = vec![0.0f32; volume.len()];
    let warmup = warmup.min(w);
    // Row paths, both directions, one row per task.
    sum.par_chunks_mut(row_len)
        .zip(volume.par_chunks(row_len))
        .zip(guide.par_chunks(w))
        .for_each(|((sum_row, cost_row), guide_row)| {
            let mut prev = vec![0.0f32; d_count];
            let mut cur = vec![0.0f32; d_count];
            for forward in [true, false] {
                let col = |i: usize| -> usize {
                    // Start `warmup` columns before column 0 (forward) or column w-1 (backward).
                    let s = (i + w - warmup) % w;
                    if forward {
                        s
                    } else {
                        w - 1 - s
                    }
                };
                let first = col(0);
                prev.copy_from_slice(&cost_row[first * d_count..(first + 1) * d_count]);
                for i in 1..w + warmup {
                    let u = col(i);
                    let c = &cost_row[u * d_count..(u + 1) * d_count];
                    let here = pen.between(guide_row[u], guide_row[col(i - 1)]);
                    step(c, &prev, &mut cur, here);
                    if i >= warmup {
                        for (s, l) in sum_row[u * d_count..(u + 1) * d_count].iter_mut().zip(&cur) {
                            *s += l;
                        }
                    }
                    std::mem::swap(&mut prev, &mut cur);
                }
                if warmup == 0 {
                    // The first column was never accumulated.
                    for (s, c) in sum_row[first * d_count..(first + 1) * d_count]
                        .iter_mut()
                        .zip(&cost_row[first * d_count..(first + 1) * d_count])
                    {
                        *s += c;
                    }
                }
            }
        });
    // Column paths, both directions: rows in sequence, columns in parallel.
    for downward in [true, false] {
        let row_of = |i: usize| if downward { i } else { h - 1 - i };
        let first = row_of(0);
        let mut prev: Vec<f32> = volume[first * row_len..(first + 1) * row_len].to_vec();
        for (s, c) in sum[first * row_len..(first + 1) * row_len]
            .iter_mut()
            .zip(&prev)
        {
            *s += c;
        }
        let mut cur = vec![0.0f32; row_len];
        for i in 1..h {
            let v = row_of(i);
            let cost_row = &volume[v * row_len..(v + 1) * row_len];
            let sum_row = &mut sum[v * row_len..(v + 1) * row_len];
            let v_prev = row_of(i - 1);
            let guide_here = &guide[v * w..(v + 1) * w];
            let guide_prev = &guide[v_prev * w..(v_prev + 1) * w];
            cur.par_chunks_mut(d_count)
                .zip(prev.par_chunks(d_count))
                .zip(cost_row.par_chunks(d_count))
                .zip(sum_row.par_chunks_mut(d_count))
                .enumerate()
                .with_min_len(16)
                .for_each(|(u, (((c, p), cost), s))| {
                    step(cost, p, c, pen.between(guide_here[u], guide_prev[u]));
                    for (si, ci) in s.iter_mut().zip(c.iter()) {
                        *si += ci;
                    }
                });
            std::mem::swap(&mut prev, &mut cur);
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooths_a_noisy_minimum_and_keeps_the_wrap() {
        // 8x4 pixels, 5 hypotheses; every pixel prefers d = 2 except one that prefers d = 4
        // weakly: aggregation must vote it back to 2.
        let (w, h, d) = (8usize, 4usize, 5usize);
        let mut volume = vec![1.0f32; w * h * d];
        for k in 0..w * h {
            volume[k * d + 2] = 0.0;
        }
        let odd = 2 * w; // (u=0, v=2), on the seam
        volume[odd * d + 2] = 0.6;
        volume[odd * d + 4] = 0.5;
        let pen = SgmPenalties {
            p1: 0.1,
            p2: 0.4,
            edge_scale: 0.0,
        };
        let s = aggregate(&volume, &vec![0.0; w * h], w, h, d, pen, 4);
        let argmin = |k: usize| {
            (0..d)
                .min_by(|&a, &b| s[k * d + a].total_cmp(&s[k * d + b]))
                .unwrap_or(0)
        };
        for k in 0..w * h {
            assert_eq!(argmin(k), 2, "pixel {k}");
        }
    }
}
