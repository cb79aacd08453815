//! Edge-aware refinement of the network's range on its own grid: a joint weighted median in
//! log range, guided by the reference camera's colours and the network's confidence.
//!
//! The aggregation works at half the cost volume's resolution, so its ranges bleed a few cells
//! across depth edges (a facade's range spills into the sky beside it). Each cell `p` takes the
//! weighted median of the log ranges of its `(2 R + 1)^2` neighbours `n`, with
//!
//! ```text
//! w_n = c_n^a exp(-|rgb_p - rgb_n|^2 / (2 sigma_c^2)) exp(-d(p, n)^2 / (2 sigma_s^2))
//! ```
//!
//! `c_n` the network's confidence, `rgb` the reference image on the network's grid (in
//! `[0, 1]`) and `d` the distance in cells. A cell whose colour is the sky's takes the sky's
//! range from confident sky cells around it. Longitude wraps, latitude clamps.

use mode360_core::frame::RgbImage;
use mode360_core::geometry::{resample_erp, ErpGrid};
use rayon::prelude::*;

use mode360_model::matching::INTENSITY_SCALE;

/// Colour scale `sigma_c` of the weights (RGB in [0, 1]). Validation moved by at most 0.3 δ1
/// points between 0.1 and 1 (models/README.md, "Edge refinement"): the confidence does most.
pub const COLOUR_SIGMA: f32 = 0.25;
/// Spatial scale `sigma_s` of the weights, in cells.
pub const SPATIAL_SIGMA_CELLS: f32 = 2.0;
/// Exponent `a` of the confidence in the weights.
pub const CONFIDENCE_POWER: f32 = 1.0;
/// Keeps the weights positive where the network is sure of nothing.
const MIN_CONFIDENCE: f32 = 1e-6;

/// Parameters of [`weighted_median_refine`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeRefineParams {
    /// Window radius `R` in cells.
    pub radius_cells: usize,
    /// Colour scale `sigma_c` (RGB in [0, 1]).
    pub colour_sigma: f32,
    /// Spatial scale `sigma_s` in cells.
    pub spatial_sigma_cells: f32,
    /// Confidence exponent `a`.
    pub confidence_power: f32,
}

impl EdgeRefineParams {
    /// The shipped weights over a window of radius `radius_cells`.
    pub fn with_radius(radius_cells: usize) -> Self {
        Self {
            radius_cells,
            colour_sigma: COLOUR_SIGMA,
            spatial_sigma_cells: SPATIAL_SIGMA_CELLS,
            confidence_power: CONFIDENCE_POWER,
        }
    }
}

/// RGB in [0, 1] of an ERP image resampled (bilinear) to `grid`, interleaved.
pub fn rgb_on_grid(image: &RgbImage, grid: ErpGrid) -> Option<Vec<f32>> {
    let src = ErpGrid::new(image.width() as usize).ok()?;
    if src.height() != image.height() as usize {
        return None;
    }
    let rgb: Vec<f32> = image
        .as_raw()
        .iter()
        .map(|&b| f32::from(b) * INTENSITY_SCALE)
        .collect();
    Some(resample_erp(&rgb, 3, src, grid))
}

/// `range` (metres, on `grid`) refined by the joint weighted median of the module docs;
/// `confidence` per cell in [0, 1], `rgb` interleaved per cell in [0, 1].
pub fn weighted_median_refine(
    range: &[f32],
    confidence: &[f32],
    rgb: &[f32],
    grid: ErpGrid,
    p: &EdgeRefineParams,
) -> Vec<f32> {
    let (w, h) = (grid.width() as isize, grid.height() as isize);
    let r = p.radius_cells as isize;
    let two_c = 2.0 * p.colour_sigma * p.colour_sigma;
    let two_s = 2.0 * p.spatial_sigma_cells * p.spatial_sigma_cells;
    let log_range: Vec<f32> = range
        .iter()
        .map(|x| x.max(f32::MIN_POSITIVE).ln())
        .collect();
    let conf: Vec<f32> = confidence
        .iter()
        .map(|c| c.clamp(0.0, 1.0).powf(p.confidence_power) + MIN_CONFIDENCE)
        .collect();
    (0..grid.len())
        .into_par_iter()
        .with_min_len(grid.width())
        .map_init(Vec::new, |taps: &mut Vec<(f32, f32)>, k| {
            let (u, v) = ((k as isize) % w, (k as isize) / w);
            let c = &rgb[3 * k..3 * k + 3];
            taps.clear();
            let mut total = 0f32;
            for dv in -r..=r {
                let vv = v + dv;
                if vv < 0 || vv >= h {
                    continue;
                }
                for du in -r..=r {
                    let uu = (u + du).rem_euclid(w);
                    let n = (vv * w + uu) as usize;
                    let cn = &rgb[3 * n..3 * n + 3];
                    let dc =
                        (c[0] - cn[0]).powi(2) + (c[1] - cn[1]).powi(2) + (c[2] - cn[2]).powi(2);
                    let ds = (du * du + dv * dv) as f32;
                    let wt = conf[n] * (-dc / two_c - ds / two_s).exp();
                    taps.push((log_range[n], wt));
                    total += wt;
                }
            }
            taps.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            let half = 0.5 * total;
            let mut acc = 0f32;
            for &(x, wt) in taps.iter() {
                acc += wt;
                if acc >= half {
                    return x.exp();
                }
            }
            range[k]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const WIDTH: usize = 32;

    fn grid() -> ErpGrid {
        ErpGrid::new(WIDTH).expect("grid")
    }

    /// Sky-blue above row `horizon`, facade-grey below, per cell.
    fn two_colours(horizon: usize) -> Vec<f32> {
        let g = grid();
        (0..g.len())
            .flat_map(|k| {
                if k / g.width() < horizon {
                    [0.4, 0.6, 0.9]
                } else {
                    [0.5, 0.5, 0.5]
                }
            })
            .collect()
    }

    #[test]
    fn a_bleed_of_unsure_cells_takes_the_range_of_its_colour() {
        let g = grid();
        let (horizon, sky_m, facade_m) = (8, 1000.0, 30.0);
        let rgb = two_colours(horizon);
        // The facade's range bleeds two rows into the sky, where the network is unsure.
        let range: Vec<f32> = (0..g.len())
            .map(|k| {
                if k / g.width() < horizon - 2 {
                    sky_m
                } else {
                    facade_m
                }
            })
            .collect();
        let confidence: Vec<f32> = (0..g.len())
            .map(|k| {
                let v = k / g.width();
                if (horizon - 2..horizon).contains(&v) {
                    0.1
                } else {
                    0.9
                }
            })
            .collect();
        let out = weighted_median_refine(
            &range,
            &confidence,
            &rgb,
            g,
            &EdgeRefineParams::with_radius(2),
        );
        for (k, &r) in out.iter().enumerate() {
            let want = if k / g.width() < horizon {
                sky_m
            } else {
                facade_m
            };
            assert!(
                (r / want - 1.0).abs() < 1e-4,
                "cell {k}: {r} m, want {want} m"
            );
        }
    }

    #[test]
    fn smooth_ranges_and_thin_confident_structures_stay() {
        let g = grid();
        let rgb = vec![0.5; 3 * g.len()];
        // Range rising along longitude (a wall seen at a slant), and a confident 1-cell pole.
        let pole_u = 20;
        let range: Vec<f32> = (0..g.len())
            .map(|k| {
                let u = k % g.width();
                if u == pole_u {
                    2.0
                } else {
                    (1.0 + 0.05 * u as f32).exp()
                }
            })
            .collect();
        let mut confidence = vec![0.05; g.len()];
        for v in 0..g.height() {
            confidence[v * g.width() + pole_u] = 1.0;
        }
        let out = weighted_median_refine(
            &range,
            &confidence,
            &rgb,
            g,
            &EdgeRefineParams::with_radius(1),
        );
        for v in 0..g.height() {
            for u in 2..pole_u - 2 {
                let k = v * g.width() + u;
                assert!(
                    (out[k] / range[k] - 1.0).abs() < 1e-4,
                    "ramp cell ({u}, {v}): {} vs {}",
                    out[k],
                    range[k]
                );
            }
            let k = v * g.width() + pole_u;
            assert!((out[k] - 2.0).abs() < 1e-4, "pole row {v}: {} m", out[k]);
        }
    }

    #[test]
    fn longitude_wraps() {
        let g = grid();
        let rgb = vec![0.5; 3 * g.len()];
        let mut range = vec![10.0; g.len()];
        let mut confidence = vec![0.9; g.len()];
        // A wrong, unsure cell on the seam: its window reaches across it.
        let k = 5 * g.width();
        range[k] = 500.0;
        confidence[k] = 0.1;
        let out = weighted_median_refine(
            &range,
            &confidence,
            &rgb,
            g,
            &EdgeRefineParams::with_radius(1),
        );
        assert!((out[k] - 10.0).abs() < 1e-4, "seam cell: {} m", out[k]);
    }
}
