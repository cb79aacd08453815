//! Depth metrics and obstacle measures accumulated over the frames of a run, as `eval` and
//! `replay` report them: the paper's depth metrics per frame (with disparity metrics where the
//! caller computes them) and, where the frame has labels, obstacle recall, near δ1 and phantom
//! free space ([`mode360_core::obstacles`]).

use anyhow::Result;
use mode360_core::frame::{FloatImage, RigFrame};
use mode360_core::metrics::{depth_metrics, DisparityMetrics, FrameAverage};
use mode360_core::obstacles::{frame_obstacles, ObstacleSummary};

#[derive(Default)]
pub struct FrameScores {
    pub average: FrameAverage,
    pub obstacles: ObstacleSummary,
}

impl FrameScores {
    /// Scores `range_m` against the frame's ground truth `gt` and its labels, where it has
    /// them; `source` names the frame's bag in the list of worst misses.
    pub fn add(
        &mut self,
        range_m: &FloatImage,
        gt: &FloatImage,
        frame: &RigFrame,
        max_depth_m: f64,
        source: &str,
        disparity: Option<DisparityMetrics>,
    ) -> Result<()> {
        self.average.push(
            depth_metrics(&range_m.data, &gt.data, max_depth_m)?,
            disparity,
        );
        if let Some(labels) = &frame.labels {
            let scores = frame_obstacles(&range_m.data, &gt.data, labels, max_depth_m)?;
            self.obstacles.add_frame(source, frame.stamp_ns, &scores);
        }
        Ok(())
    }
}
