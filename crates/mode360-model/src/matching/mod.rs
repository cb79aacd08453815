//! Learning-free photometric matching shared by the photometric sweep
//! (`mode360_estimator::photometric`) and SSMODE's photometric cost channel
//! ([`crate::model::photometric_cost`]): windowed ZNCC between camera pairs combined over the
//! best pairs ([`zncc`]) and the per-pair parallax weights ([`pair_parallax_weights`]).
//!
//! Pure numerics over row-major `f32` images: no tensors, no ROS.

pub mod zncc;

use mode360_core::geometry::ErpGrid;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Rec. 601 luma weights of the grey images every matcher compares.
pub const LUMA_WEIGHTS: [f32; 3] = [0.299, 0.587, 0.114];
/// 8-bit intensity to [0, 1].
pub const INTENSITY_SCALE: f32 = 1.0 / 255.0;

/// Grey level `0.299 R + 0.587 G + 0.114 B` of one pixel (in the pixel's own scale).
#[inline]
pub fn luma(rgb: [f32; 3]) -> f32 {
    LUMA_WEIGHTS[0] * rgb[0] + LUMA_WEIGHTS[1] * rgb[1] + LUMA_WEIGHTS[2] * rgb[2]
}

/// Parallax weight of every camera pair `(a < b)` and pixel of `output`: `|dir x b_hat|^k`, with
/// `b_hat` the unit baseline between the two camera centres (given in the output frame) and
/// `k = exponent`. A pair sees no parallax along its baseline, so its cost is blended toward
/// undecided there. Empty when `k = 0`; a pair of coincident centres gets weight 0 everywhere.
pub fn pair_parallax_weights(
    output: ErpGrid,
    centres: &[Vector3<f64>],
    exponent: f32,
) -> Vec<Vec<f32>> {
    if exponent == 0.0 {
        return Vec::new();
    }
    let mut weights = Vec::new();
    for a in 0..centres.len() {
        for b in a + 1..centres.len() {
            let baseline = centres[b] - centres[a];
            let norm = baseline.norm();
            if norm == 0.0 {
                weights.push(vec![0.0; output.len()]);
                continue;
            }
            let b_hat = baseline / norm;
            weights.push(
                (0..output.len())
                    .into_par_iter()
                    .map(|k| {
                        let dir = output.dir_from_pixel(output.pixel_of_index(k));
                        (dir.cross(&b_hat).norm() as f32).powf(exponent)
                    })
                    .collect(),
            );
        }
    }
    weights
}
