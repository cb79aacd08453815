//! Photometric matching cost of one sphere: windowed ZNCC between every camera pair, combined
//! robustly to occlusion by averaging only the best pairs.
//!
//! For a pair `(a, b)` of warped grey images and a `(2r+1)^2` window (box means `E[.]`):
//!
//! ```text
//! var_a = E[a^2] - E[a]^2,   cov = E[ab] - E[a] E[b]
//! zncc  = cov / sqrt((var_a + eps) (var_b + eps))
//! cost  = (1 - w_mean) (1 - zncc) / 2 + w_mean min(|E[a] - E[b]| / s_mean, 1)
//! ```
//!
//! The variance floor `eps` sends flat windows to `zncc = 0` (cost 1/2, undecided) rather than to
//! noise; the mean term separates flat regions of different brightness. The pixel's cost is the
//! mean of its `k` smallest pair costs: a camera that is occluded spoils only its own pairs.
//!
//! The functions are `#[inline(always)]` so that a caller compiled for AVX2 (SSMODE's
//! photometric channel, [`crate::cpu`]) gets them in 8-wide vectors too.

/// Cost of a pair that cannot tell hypotheses apart.
pub const UNDECIDED_COST: f32 = 0.5;
/// Cost of a pair one of whose cameras does not see the point: never among the best.
const UNSEEN_COST: f32 = f32::INFINITY;
/// A warped validity mask at least this high counts as seen.
const SEEN_THRESHOLD: f32 = 0.5;

/// Windowed box mean with longitude wrap along rows and replicated rows at the poles.
///
/// `out[v][u] = mean_{|dv|<=r, |du|<=r} in[clamp(v+dv)][(u+du) mod W]`; `tmp` is scratch of
/// the same size.
#[inline(always)]
pub fn box_mean(input: &[f32], w: usize, h: usize, r: usize, tmp: &mut [f32], out: &mut [f32]) {
    // Direct sums of shifted rows (2 r + 1 vectorised adds per element) rather than running
    // sums: no loop-carried dependency, and no rounding error accumulated along a row.
    let taps = 2 * r + 1;
    let inv_area = 1.0 / (taps * taps) as f32;
    // the column (u + du - r) mod w without negative intermediates
    let wrap = |u: usize, du: usize| (u + w * (r / w + 1) + du - r) % w;
    for (row_in, row_tmp) in input.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        let interior = w.saturating_sub(2 * r);
        if interior > 0 {
            let dst = &mut row_tmp[r..r + interior];
            dst.copy_from_slice(&row_in[..interior]);
            for du in 1..taps {
                for (d, x) in dst.iter_mut().zip(&row_in[du..du + interior]) {
                    *d += x;
                }
            }
        }
        let edges = (0..r.min(w)).chain((r + interior).max(r.min(w))..w);
        for u in edges {
            row_tmp[u] = (0..taps).map(|du| row_in[wrap(u, du)]).sum();
        }
    }
    let row = |v: isize| -> usize { v.clamp(0, h as isize - 1) as usize };
    for v in 0..h {
        let out_row = &mut out[v * w..v * w + w];
        let first = row(v as isize - r as isize) * w;
        out_row.copy_from_slice(&tmp[first..first + w]);
        for dv in 1..taps as isize {
            let src = row(v as isize - r as isize + dv) * w;
            for (o, x) in out_row.iter_mut().zip(&tmp[src..src + w]) {
                *o += x;
            }
        }
        for o in out_row.iter_mut() {
            *o *= inv_area;
        }
    }
}

/// Parameters of the pair cost.
#[derive(Clone, Copy, Debug)]
pub struct PairCostParams {
    pub window_radius_px: usize,
    pub variance_floor: f32,
    pub mean_weight: f32,
    pub mean_scale: f32,
    /// How many of the pair costs (the smallest) are averaged per pixel.
    pub best_pairs: usize,
}

/// Windowed statistics of one warped view.
pub struct ViewStats {
    pub image: Vec<f32>,
    pub mean: Vec<f32>,
    /// `E[a^2] - E[a]^2`.
    pub variance: Vec<f32>,
}

impl ViewStats {
    #[inline(always)]
    pub fn new(image: Vec<f32>, w: usize, h: usize, r: usize, tmp: &mut [f32]) -> Self {
        let mut mean = vec![0.0; image.len()];
        box_mean(&image, w, h, r, tmp, &mut mean);
        let sq: Vec<f32> = image.iter().map(|x| x * x).collect();
        let mut variance = vec![0.0; image.len()];
        box_mean(&sq, w, h, r, tmp, &mut variance);
        for (var, m) in variance.iter_mut().zip(&mean) {
            *var = (*var - m * m).max(0.0);
        }
        Self {
            image,
            mean,
            variance,
        }
    }
}

/// Matching cost of every output pixel for one sphere from the warped views.
///
/// `pair_weights` (one per pair, in `(a, b)`, `a < b` order, each per pixel or empty) blend a
/// pair's cost toward the undecided `1/2` where the pair has little parallax:
/// `cost' = w cost + (1 - w) / 2`. `seen[c]` (per pixel, `None`: everywhere) says where camera
/// `c` sees the sphere's point; a pair counts only where both see it, and a pixel no pair
/// sees is undecided.
#[inline(always)]
pub fn sphere_cost(
    views: &[&ViewStats],
    seen: &[Option<&[f32]>],
    pair_weights: &[Vec<f32>],
    w: usize,
    h: usize,
    p: &PairCostParams,
) -> Vec<f32> {
    let n = w * h;
    let mut tmp = vec![0.0f32; n];
    let mut product = vec![0.0f32; n];
    let mut cross = vec![0.0f32; n];
    let mut pair_costs: Vec<Vec<f32>> = Vec::new();
    for a in 0..views.len() {
        for b in a + 1..views.len() {
            let (va, vb) = (&views[a], &views[b]);
            for ((x, ia), ib) in product.iter_mut().zip(&va.image).zip(&vb.image) {
                *x = ia * ib;
            }
            box_mean(&product, w, h, p.window_radius_px, &mut tmp, &mut cross);
            let mut cost = vec![0.0f32; n];
            // Branch-free over zipped slices, so that it vectorizes.
            let stats = va
                .mean
                .iter()
                .zip(&vb.mean)
                .zip(va.variance.iter().zip(&vb.variance));
            for ((c, &cr), ((&ma, &mb), (&var_a, &var_b))) in
                cost.iter_mut().zip(&cross[..n]).zip(stats)
            {
                let cov = cr - ma * mb;
                let denom = ((var_a + p.variance_floor) * (var_b + p.variance_floor)).sqrt();
                let zncc = (cov / denom).clamp(-1.0, 1.0);
                let mean_term = ((ma - mb).abs() / p.mean_scale).min(1.0);
                *c = (1.0 - p.mean_weight) * 0.5 * (1.0 - zncc) + p.mean_weight * mean_term;
            }
            if let Some(weights) = pair_weights.get(pair_costs.len()).filter(|x| !x.is_empty()) {
                for (c, wt) in cost.iter_mut().zip(weights) {
                    *c = wt * *c + (1.0 - wt) * UNDECIDED_COST;
                }
            }
            for mask in [seen.get(a), seen.get(b)].into_iter().flatten().flatten() {
                for (c, m) in cost.iter_mut().zip(mask.iter()) {
                    if *m < SEEN_THRESHOLD {
                        *c = UNSEEN_COST;
                    }
                }
            }
            pair_costs.push(cost);
        }
    }
    combine_best(pair_costs, n, p.best_pairs)
}

/// Per pixel, the mean of the smallest of the pair costs that were seen (an unseen pair is
/// [`UNSEEN_COST`]): `ceil(best S / P)` of the `S` seen of the `P` pairs, the same share as
/// `best` of all pairs; undecided where no pair was seen.
#[inline(always)]
fn combine_best(mut pair_costs: Vec<Vec<f32>>, n: usize, best: usize) -> Vec<f32> {
    let pairs = pair_costs.len();
    if pairs == 0 {
        // A single camera cannot match anything.
        return vec![UNDECIDED_COST; n];
    }
    let best = best.clamp(1, pairs);
    // Sort every pixel's pair costs at once, in place: an odd-even transposition network over
    // the pair axis, one branch-free min/max pass over whole rows per comparator (vectorised),
    // rather than a sort per pixel. Unseen pairs (infinite) end last.
    for c in &mut pair_costs {
        c.truncate(n);
    }
    let sorted = &mut pair_costs;
    for round in 0..pairs {
        for i in (round % 2..pairs.saturating_sub(1)).step_by(2) {
            let (lo, hi) = sorted.split_at_mut(i + 1);
            for (x, y) in lo[i].iter_mut().zip(hi[0].iter_mut()) {
                let (a, b) = (x.min(*y), x.max(*y));
                *x = a;
                *y = b;
            }
        }
    }
    // seen pairs per pixel, then the number of the smallest to average
    let mut seen = vec![0u32; n];
    for row in sorted.iter() {
        for (s, c) in seen.iter_mut().zip(row) {
            *s += u32::from(c.is_finite());
        }
    }
    // The same share of the pairs seen here as of all pairs (an unseen camera must not make the
    // rest of the pairs all count, occluded ones included). Measured at 512 on held-out frames:
    // the sweep +2.9 δ1 points on a fisheye rack, +0.8 with a lens masked; SSMODE +1.1 on the
    // fisheye rack.
    let take: Vec<u32> = seen
        .iter()
        .map(|&s| ((best * s as usize).div_ceil(pairs).max(1)) as u32)
        .collect();
    let mut sum = vec![0.0f32; n];
    for (j, row) in sorted.iter().enumerate() {
        for ((acc, c), &t) in sum.iter_mut().zip(row).zip(&take) {
            *acc += if (j as u32) < t { *c } else { 0.0 };
        }
    }
    sum.iter()
        .zip(&take)
        .zip(&seen)
        .map(|((&acc, &t), &s)| {
            if s == 0 {
                UNDECIDED_COST
            } else {
                acc / t as f32
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mean_wraps_columns_and_clamps_rows() {
        let (w, h, r) = (6usize, 3usize, 1usize);
        let input: Vec<f32> = (0..w * h).map(|i| ((i * 13) % 7) as f32).collect();
        let mut tmp = vec![0.0; w * h];
        let mut out = vec![0.0; w * h];
        box_mean(&input, w, h, r, &mut tmp, &mut out);
        for v in 0..h as isize {
            for u in 0..w as isize {
                let mut sum = 0.0;
                for dv in -1..=1isize {
                    for du in -1..=1isize {
                        let vv = (v + dv).clamp(0, h as isize - 1) as usize;
                        let uu = (u + du).rem_euclid(w as isize) as usize;
                        sum += input[vv * w + uu];
                    }
                }
                let got = out[v as usize * w + u as usize];
                assert!(
                    (got - sum / 9.0).abs() < 1e-5,
                    "({u},{v}) {got} vs {}",
                    sum / 9.0
                );
            }
        }
    }

    #[test]
    fn best_pairs_ignore_an_outlier() {
        let costs = vec![vec![0.1f32], vec![0.9], vec![0.2]];
        let out = combine_best(costs.clone(), 1, 2);
        assert!((out[0] - 0.15).abs() < 1e-6);
        assert!((combine_best(costs.clone(), 1, 3)[0] - 0.4).abs() < 1e-6);
        assert_eq!(combine_best(Vec::new(), 2, 1), vec![UNDECIDED_COST; 2]);
        // Unseen pairs never count; a pixel no pair sees is undecided.
        let costs = vec![
            vec![0.1f32, UNSEEN_COST],
            vec![UNSEEN_COST, UNSEEN_COST],
            vec![0.3, UNSEEN_COST],
        ];
        let out = combine_best(costs.clone(), 2, 3);
        assert!((out[0] - 0.2).abs() < 1e-6);
        assert_eq!(out[1], UNDECIDED_COST);
        // The best 3 of 6 pairs: with one camera of four unseen (3 pairs left), the best 2.
        let costs = vec![
            vec![0.1f32],
            vec![UNSEEN_COST],
            vec![0.5],
            vec![UNSEEN_COST],
            vec![0.2],
            vec![UNSEEN_COST],
        ];
        assert!((combine_best(costs.clone(), 1, 3)[0] - 0.15).abs() < 1e-6);
    }
}
