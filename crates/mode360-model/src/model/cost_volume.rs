//! Spherical sweep cost volume with exact sampling tables and count-invariant view aggregation.
//!
//! For camera `c`, sphere `d` and output pixel `(v, u)` at quarter resolution,
//! `f_c(d, v, u) = table_sample(features_c, sweep_table_c)` samples camera `c`'s features where
//! it sees the point `rho_d dir(u, v)` (see [`super::sweep_sampling::SweepSampling`]). The views are
//! aggregated independently of their number `N` and order:
//!
//! ```text
//! mean = (1/N) sum_c f_c,   var = (1/N) sum_c f_c^2 - mean^2
//! volume = concat(mean, var)   (CostKind::MeanVariance)   or   var   (CostKind::Variance)
//! ```
//!
//! The variance is zero wherever the views agree, whatever they show, so a variance-only
//! volume holds matching evidence alone; the mean also carries the reference view's look.
//! On rigs whose cameras do not see everything (fisheyes), `N` is per cell the number of
//! cameras that see it, and a cell fewer than two cameras see gets mean and variance 0
//! ([`SweepSampling::view_scale`]).

use candle_core::{Result, Tensor};

use super::config::CostKind;
use super::sweep_sampling::SweepSampling;
use crate::model::ops::{
    append_channels, has_custom_kernels, sweep_variance, sweep_variance_appended,
    sweep_variance_appended_window, sweep_variance_visible, table_sample, OpsError, SampleTable,
};

/// Builds the `(B, D, H, W, C')` cost volume from the cameras' features stacked camera-major,
/// `(M B, H, W, C)` (camera `c`'s batch at rows `c B .. (c + 1) B`), with
/// `C' = kind.channels(C)`.
pub fn cost_volume(features: &Tensor, sampling: &SweepSampling, kind: CostKind) -> Result<Tensor> {
    const OP: &str = "cost_volume";
    let cameras = sampling.camera_count();
    let (stacked, h, w, c) = features.dims4()?;
    if cameras == 0 || stacked == 0 || !stacked.is_multiple_of(cameras) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!("{stacked} stacked feature maps for a sweep of {cameras} cameras"),
        }
        .into());
    }
    let b = stacked / cameras;
    let grid = sampling.geometry().output();
    let spheres = sampling.geometry().hypotheses().count();
    if (h, w) != (grid.height(), grid.width()) {
        return Err(OpsError::Shape {
            op: OP,
            what: format!(
                "features are {w}x{h}, the sweep tables expect {}x{}",
                grid.width(),
                grid.height()
            ),
        }
        .into());
    }
    if kind == CostKind::Variance {
        let tables = sweep_tables(sampling)?;
        // (M B, H, W, C) -> (B, D H W, C) -> (B, D, H, W, C)
        let var = match sampling.view_scale() {
            None => sweep_variance(features, &tables)?,
            Some(scale) => sweep_variance_visible(features, &tables, scale)?,
        };
        return var.reshape((b, spheres, h, w, c));
    }
    let mut sum: Option<Tensor> = None;
    let mut sum_sq: Option<Tensor> = None;
    for cam in 0..cameras {
        let f = &features.narrow(0, cam * b, b)?;
        let table = sampling.sweep_table(cam).ok_or(OpsError::Shape {
            op: OP,
            what: format!("no sweep table for camera {cam}"),
        })?;
        // (B, D H W, C) -> (B, D, H, W, C)
        let warped = table_sample(f, table)?.reshape((b, spheres, h, w, c))?;
        let sq = warped.sqr()?;
        sum = Some(match sum {
            Some(s) => (s + &warped)?,
            None => warped,
        });
        sum_sq = Some(match sum_sq {
            Some(s) => (s + sq)?,
            None => sq,
        });
    }
    let (Some(sum), Some(sum_sq)) = (sum, sum_sq) else {
        return Err(OpsError::Shape {
            op: OP,
            what: "no cameras".to_string(),
        }
        .into());
    };
    // (B, D, H, W, C) each
    let (mean, var) = match sampling.view_scale() {
        None => {
            let n = cameras as f64;
            let mean = (sum / n)?;
            let var = ((sum_sq / n)? - mean.sqr()?)?;
            (mean, var)
        }
        Some(scale) => {
            // (D H W) -> (1, D, H, W, 1)
            let scale = Tensor::from_slice(scale, (1, spheres, h, w, 1), features.device())?;
            let mean = sum.broadcast_mul(&scale)?;
            let var = (sum_sq.broadcast_mul(&scale)? - mean.sqr()?)?;
            (mean, var)
        }
    };
    match kind {
        // (B, D, H, W, 2 C)
        CostKind::MeanVariance => Tensor::cat(&[&mean, &var], 4),
        // (B, D, H, W, C)
        CostKind::Variance => Ok(var),
    }
}

/// [`cost_volume`] with `extra (B, D, H, W, 1)` appended as its last channel,
/// `(B, D, H, W, C' + 1)`; for a variance-only volume written in one pass, so that the volume
/// without the channel never sits beside the result.
pub fn cost_volume_appended(
    features: &Tensor,
    sampling: &SweepSampling,
    kind: CostKind,
    extra: &Tensor,
) -> Result<Tensor> {
    if kind != CostKind::Variance {
        return append_channels(&cost_volume(features, sampling, kind)?, extra);
    }
    let (b, d, h, w, _) = extra.dims5()?;
    let tables = sweep_tables(sampling)?;
    // (B, D H W, 1) -> (B, D H W, C + 1) -> (B, D, H, W, C + 1)
    let flat = extra.reshape((b, d * h * w, 1))?;
    let volume = sweep_variance_appended(features, &tables, sampling.view_scale(), &flat)?;
    let channels = volume.dim(2)?;
    volume.reshape((b, d, h, w, channels))
}

/// Whether [`cost_volume_appended_spheres`] serves `features (M B, H, W, C)` and `kind`: a
/// variance-only volume on the CPU's fused kernel (4, 8 or 16 channels).
pub fn appended_in_slabs(features: &Tensor, kind: CostKind) -> bool {
    kind == CostKind::Variance
        && has_custom_kernels(features.device())
        && features
            .dims()
            .last()
            .is_some_and(|c| matches!(c, 4 | 8 | 16))
}

/// The spheres `spheres` of [`cost_volume_appended`]'s volume, `(B, len, H, W, C' + 1)`, bit for
/// bit, from `extra (B, D, H, W, 1)` of every sphere; inference only, where
/// [`appended_in_slabs`] says so.
pub fn cost_volume_appended_spheres(
    features: &Tensor,
    sampling: &SweepSampling,
    extra: &Tensor,
    spheres: std::ops::Range<usize>,
) -> Result<Tensor> {
    let (b, _, h, w, _) = extra.dims5()?;
    let tables = sweep_tables(sampling)?;
    let count = spheres.len();
    // (B, len, H, W, 1) -> (B, len H W, 1) -> (B, len H W, C + 1) -> (B, len, H, W, C + 1)
    let flat = extra
        .narrow(1, spheres.start, count)?
        .reshape((b, count * h * w, 1))?;
    let window = spheres.start * h * w..spheres.end * h * w;
    let volume =
        sweep_variance_appended_window(features, &tables, sampling.view_scale(), &flat, window)?;
    let channels = volume.dim(2)?;
    volume.reshape((b, count, h, w, channels))
}

/// Every camera's sweep table of `sampling`, in rig order.
fn sweep_tables(sampling: &SweepSampling) -> Result<Vec<SampleTable>> {
    (0..sampling.camera_count())
        .map(|cam| {
            sampling.sweep_table(cam).cloned().ok_or_else(|| {
                OpsError::Shape {
                    op: "cost_volume",
                    what: format!("no sweep table for camera {cam}"),
                }
                .into()
            })
        })
        .collect()
}
