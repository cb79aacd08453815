//! Range upsampling from the network's grid to a finer output grid, guided by the reference
//! camera's image at the output resolution (a joint-bilateral choice among the four cells
//! around each output pixel).
//!
//! Bilinear upsampling of a range image invents ranges at every depth edge: a pixel between a
//! facade cell at 30 m and a sky cell at 1000 m gets 272 m, wrong for both. Here each output
//! pixel `p` weighs its four bilinear neighbours `n` by
//!
//! ```text
//! w_n = b_n exp(-(g_p - g_n)^2 / (2 sigma^2))
//! ```
//!
//! with `b_n` the bilinear weight and `g` the grey guide (the reference image at the output and
//! at the network resolution). Where the four ranges agree within [`SMOOTH_RANGE_RATIO`] the
//! output is their weighted mean in log range (smooth surfaces stay smooth); elsewhere it is the
//! range of the neighbour with the largest weight, the side of the edge whose colour the pixel
//! shares. Longitude wraps, latitude clamps, as in [`mode360_core::geometry::ErpGrid::bilinear_taps`].

use super::edge_refine::rgb_on_grid;
use mode360_core::frame::RgbImage;
use mode360_core::geometry::{ErpGrid, PixelCoord};
use mode360_model::matching::luma;
use rayon::prelude::*;

/// Colour scale of the guide weight (grey levels in [0, 1]).
pub const GUIDE_SIGMA: f32 = 0.05;
/// Neighbour ranges within this ratio of each other count as one smooth surface.
pub const SMOOTH_RANGE_RATIO: f32 = 1.1;
/// Keeps a pixel whose colour matches no neighbour on its bilinear weights.
const MIN_WEIGHT: f32 = 1e-6;

/// Grey levels in [0, 1] of an ERP image resampled (bilinear) to `grid`.
pub fn grey_on_grid(image: &RgbImage, grid: ErpGrid) -> Option<Vec<f32>> {
    Some(
        rgb_on_grid(image, grid)?
            .chunks_exact(3)
            .map(|p| luma([p[0], p[1], p[2]]))
            .collect(),
    )
}

/// `range` (on `net`) upsampled to `out` with the guides `guide_net` (on `net`) and
/// `guide_out` (on `out`); see the module docs.
pub fn guided_upsample(
    range: &[f32],
    guide_net: &[f32],
    net: ErpGrid,
    guide_out: &[f32],
    out: ErpGrid,
) -> Vec<f32> {
    let scale = net.width() as f64 / out.width() as f64;
    let two_sigma_sq = 2.0 * GUIDE_SIGMA * GUIDE_SIGMA;
    (0..out.len())
        .into_par_iter()
        .with_min_len(out.width())
        .map(|k| {
            let (u, v) = (k % out.width(), k / out.width());
            let p = PixelCoord {
                u: (u as f64 + 0.5) * scale - 0.5,
                v: (v as f64 + 0.5) * scale - 0.5,
            };
            let taps = net.bilinear_taps(p);
            let g = guide_out[k];
            let mut weights = [0f32; 4];
            let mut ranges = [0f32; 4];
            for j in 0..4 {
                let n = taps.index[j] as usize;
                let dg = g - guide_net[n];
                weights[j] = taps.weight[j] * (-dg * dg / two_sigma_sq).exp() + MIN_WEIGHT;
                ranges[j] = range[n];
            }
            let (lo, hi) = ranges
                .iter()
                .fold((f32::INFINITY, 0f32), |(lo, hi), &r| (lo.min(r), hi.max(r)));
            if lo > 0.0 && hi <= lo * SMOOTH_RANGE_RATIO {
                let (mut sum, mut total) = (0f32, 0f32);
                for (w, r) in weights.iter().zip(&ranges) {
                    sum += w * r.ln();
                    total += w;
                }
                (sum / total).exp()
            } else {
                let best = (0..4)
                    .max_by(|&a, &b| weights[a].total_cmp(&weights[b]))
                    .unwrap_or(0);
                ranges[best]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::resample_erp;

    /// A 1000 m sky above a 30 m facade, the edge between network rows: bilinear upsampling
    /// invents ranges on the edge's output rows, the guided one keeps every pixel at 30 or
    /// 1000 m on the side its colour belongs to.
    #[test]
    fn an_edge_keeps_its_two_ranges_on_the_side_of_its_colour() {
        let net = ErpGrid::new(16).unwrap();
        let out = ErpGrid::new(32).unwrap();
        // Output rows 0..7 sky (bright), 7..16 facade (dark); network rows 0..4 sky.
        let sky_rows_out = 7;
        let guide_out: Vec<f32> = (0..out.len())
            .map(|k| if k / 32 < sky_rows_out { 0.9 } else { 0.2 })
            .collect();
        let guide_net: Vec<f32> = (0..net.len())
            .map(|k| if k / 16 < 4 { 0.9 } else { 0.2 })
            .collect();
        let range: Vec<f32> = (0..net.len())
            .map(|k| if k / 16 < 4 { 1000.0 } else { 30.0 })
            .collect();
        let up = guided_upsample(&range, &guide_net, net, &guide_out, out);
        for (k, r) in up.iter().enumerate() {
            let want = if k / 32 < sky_rows_out { 1000.0 } else { 30.0 };
            assert!((r / want - 1.0).abs() < 1e-5, "pixel {k}: {r}, want {want}");
        }
        let bilinear = resample_erp(&range, 1, net, out);
        assert!(bilinear.iter().any(|&r| r > 40.0 && r < 900.0));
    }

    /// A smooth ramp stays a smooth ramp (the log-mean branch).
    #[test]
    fn a_smooth_surface_is_interpolated() {
        let net = ErpGrid::new(16).unwrap();
        let out = ErpGrid::new(32).unwrap();
        let range: Vec<f32> = (0..net.len())
            .map(|k| 10.0 + (k % 16) as f32 * 0.1)
            .collect();
        let guide_net = vec![0.5; net.len()];
        let guide_out = vec![0.5; out.len()];
        let up = guided_upsample(&range, &guide_net, net, &guide_out, out);
        let row: Vec<f32> = up[5 * 32..5 * 32 + 30].to_vec();
        for pair in row.windows(2).skip(1) {
            assert!(pair[1] >= pair[0] - 1e-4, "{row:?}");
        }
        assert!(
            (up[5 * 32 + 10] - 10.475).abs() < 0.01,
            "{}",
            up[5 * 32 + 10]
        );
    }
}
