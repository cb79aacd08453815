//! The geometry check (design.md): the same estimator on the same frames, once with every
//! camera's own image and once with the reference camera's image for every camera. The
//! geometry share of a condition is δ1(true views) − δ1(same image), in percentage points:
//! how much of the estimator's accuracy comes from parallax rather than from what one
//! panorama shows.

use super::{evaluate, EvalOptions, EvalReport, ViewMode};
use anyhow::Result;
use mode360_estimator::DepthEstimator;
use serde::{Deserialize, Serialize};

/// One condition (clean, soiled) of the geometry check.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeometryShareRow {
    pub condition: String,
    pub frames: usize,
    /// δ1 with true views, %.
    pub delta1_true_pct: f64,
    /// δ1 with the reference camera's image for every camera, %.
    pub delta1_same_image_pct: f64,
    /// `delta1_true_pct - delta1_same_image_pct`, percentage points.
    pub share_pts: f64,
}

/// Both reports and the share per condition.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GeometryShareReport {
    pub estimator: String,
    pub true_views: EvalReport,
    pub same_image: EvalReport,
    pub geometry_share: Vec<GeometryShareRow>,
}

/// Runs [`evaluate`] with [`ViewMode::True`], then with [`ViewMode::SameImage`], on the same
/// bags, cameras and frames (`opts.views` is ignored), and pairs the rows by condition.
pub fn geometry_share(
    opts: &EvalOptions,
    estimator: &mut dyn DepthEstimator,
) -> Result<GeometryShareReport> {
    let pass = |views| EvalOptions {
        views,
        ..opts.clone()
    };
    let true_views = evaluate(&pass(ViewMode::True), estimator)?;
    let same_image = evaluate(&pass(ViewMode::SameImage), estimator)?;
    let geometry_share = true_views
        .rows
        .iter()
        .filter_map(|t| {
            let s = same_image
                .rows
                .iter()
                .find(|s| s.condition == t.condition)?;
            Some(GeometryShareRow {
                condition: t.condition.clone(),
                frames: t.frames,
                delta1_true_pct: t.depth.delta1_pct,
                delta1_same_image_pct: s.depth.delta1_pct,
                share_pts: t.depth.delta1_pct - s.depth.delta1_pct,
            })
        })
        .collect();
    Ok(GeometryShareReport {
        estimator: true_views.estimator.clone(),
        true_views,
        same_image,
        geometry_share,
    })
}

impl GeometryShareReport {
    /// Both tables, then one line per condition: δ1 true, δ1 same image, the share.
    pub fn to_table(&self) -> String {
        let mut s = self.true_views.to_table();
        s.push('\n');
        s.push_str(&self.same_image.to_table());
        s.push_str(&format!(
            "\ngeometry share ({}): δ1 true views − δ1 same-image views\n\
             | condition | frames | δ1 true % | δ1 same image % | geometry share (points) |\n\
             |---|---|---|---|---|\n",
            self.estimator
        ));
        for r in &self.geometry_share {
            s.push_str(&format!(
                "| {} | {} | {:.2} | {:.2} | {:.2} |\n",
                r.condition, r.frames, r.delta1_true_pct, r.delta1_same_image_pct, r.share_pts
            ));
        }
        s
    }
}
