//! SSMODE with a second, finer pass for near obstacles (issue 38).
//!
//! The network trained at 256 resolves a cost-volume cell of 1.4°: poles, posts and people
//! narrower than that melt into what stands behind them. Run at a finer input width (512) the
//! same weights keep many of them, but read the open sky too near (validation seed: 2-5 m
//! obstacles 11 of 19 against 7, 5-10 m 72 % against 54 %, sky δ1 73 % against 99 %). The
//! near pass takes the fine pass's range only where it says "nearer" with some margin and
//! within the range where obstacles matter:
//!
//! ```text
//! r = r_fine   where r_fine < NEAR_PASS_MAX_RANGE_M, NEAR_PASS_RATIO r_fine < r_coarse
//!              and c_fine >= NEAR_PASS_MIN_CONFIDENCE
//! r = r_coarse elsewhere (with its confidence)
//! ```
//!
//! A missing reading (NaN) counts as out of range. It costs one more forward pass at the fine
//! width (about 1.8 s at 512 on the 2-core CPU, docs/benchmarks.md).
//!
//! The second pass may instead be the learning-free photometric sweep
//! ([`NearPassSource::Sweep`]) on a grid of the fine width, read at the nearest pixel of the
//! output: it recovers more thin and near obstacles than the network at 512 (validation seed,
//! cluttered streets: 42 against 39 of 54 at 5 to 10 m) but reads much of the rest wrong, so
//! its gate is tighter in range ([`NEAR_PASS_SWEEP_MAX_RANGE_M`]) and looser in confidence (its
//! confidence is a cost margin, [`NEAR_PASS_SWEEP_MIN_CONFIDENCE`]).

use std::path::Path;

use image::RgbImage;
use mode360_core::geometry::{ErpGrid, Rig};

use super::lens_mask::LensMask;
use super::photometric::{PhotometricConfig, PhotometricSweep};
use super::ssmode::SsmodeEstimator;
use super::{DepthEstimate, DepthEstimator, EstimatorError};
use mode360_model::model::{ComputeDevice, ReadoutOverrides};

/// Farthest fine-pass range that may replace the coarse pass's, metres (chosen on the
/// validation seed among 5, 10, 20 and 30 m: models/README.md, "Obstacles").
pub const NEAR_PASS_MAX_RANGE_M: f32 = 30.0;
/// How much nearer than the coarse pass the fine pass must read (1.25: the obstacle metrics'
/// tolerance; 1.5 kept fewer obstacles).
pub const NEAR_PASS_RATIO: f32 = 1.25;

/// Lowest confidence of the fine pass for its range to count (0.5, 0.7, 0.8 and 0.9 tried on
/// the validation seed: 0.8 gave 0.1 point of δ1 back on three of four rows, soiled ones
/// included, and kept every obstacle 0.5 keeps).
pub const NEAR_PASS_MIN_CONFIDENCE: f32 = 0.8;

/// Farthest sweep range that may replace the network's, metres: on the validation seed
/// (models/README.md, "Resolution, and the near pass") 10, 15 and 30 m kept 41, 42 and 42 of
/// 54 obstacles at 5 to 10 m, for streets δ1 -0.17, -0.26 and -0.72 points.
pub const NEAR_PASS_SWEEP_MAX_RANGE_M: f32 = 15.0;
/// Lowest sweep confidence for its range to count (0.3, 0.5 and 0.8 tried on the validation
/// seed: 0.8 kept 35 of 54 obstacles at 5 to 10 m, 0.5 42 and 0.3 43 for 0.7 more of
/// cluttered δ1).
pub const NEAR_PASS_SWEEP_MIN_CONFIDENCE: f32 = 0.5;

/// What the second pass is.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum NearPassSource {
    /// The same network again at the finer input width.
    #[default]
    Network,
    /// The learning-free photometric sweep on a grid of the finer width (it keeps most thin
    /// obstacles, but reads much of the rest wrong: it is trusted only where it is nearer).
    Sweep,
}

impl NearPassSource {
    pub const ALL: [Self; 2] = [Self::Network, Self::Sweep];

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Network => "network",
            Self::Sweep => "sweep",
        }
    }

    /// The rule that lets this source's range replace the coarse pass's.
    pub fn gate(self) -> NearPassGate {
        match self {
            Self::Network => NearPassGate {
                max_range_m: NEAR_PASS_MAX_RANGE_M,
                ratio: NEAR_PASS_RATIO,
                min_confidence: NEAR_PASS_MIN_CONFIDENCE,
            },
            Self::Sweep => NearPassGate {
                max_range_m: NEAR_PASS_SWEEP_MAX_RANGE_M,
                ratio: NEAR_PASS_RATIO,
                min_confidence: NEAR_PASS_SWEEP_MIN_CONFIDENCE,
            },
        }
    }
}

impl std::fmt::Display for NearPassSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for NearPassSource {
    type Err = EstimatorError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|s| s.as_str() == text.trim())
            .ok_or_else(|| EstimatorError::BadConfig {
                field: "near_pass_source".to_string(),
                problem: format!("'{text}' is not one of network, sweep"),
            })
    }
}

/// Where the fine pass's range replaces the coarse one's: `r_fine < max_range_m`,
/// `ratio · r_fine < r_coarse` and `c_fine >= min_confidence` (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearPassGate {
    pub max_range_m: f32,
    pub ratio: f32,
    pub min_confidence: f32,
}

/// The coarse range `coarse` with the fine pass's `fine` where `gate` lets it read an
/// obstacle nearer (see the module doc); confidences follow the range they belong to. Both on
/// one grid.
pub fn combine(coarse: &DepthEstimate, fine: &DepthEstimate, gate: &NearPassGate) -> DepthEstimate {
    let mut out = coarse.clone();
    let rows = out
        .range_m
        .data
        .iter_mut()
        .zip(out.confidence.data.iter_mut())
        .zip(fine.range_m.data.iter().zip(&fine.confidence.data));
    for ((r, c), (&rf, &cf)) in rows {
        let coarse_m = if r.is_finite() { *r } else { f32::INFINITY };
        if rf.is_finite()
            && rf < gate.max_range_m
            && gate.ratio * rf < coarse_m
            && cf >= gate.min_confidence
        {
            *r = rf;
            *c = cf;
        }
    }
    out
}

/// SSMODE at its trained width, and a second pass at a finer one for near obstacles: the
/// network again, or the photometric sweep.
pub struct NearPassEstimator {
    coarse: SsmodeEstimator,
    fine: Box<dyn DepthEstimator>,
    /// The fine pass's grid (the sweep's; the network resamples to the output itself).
    fine_width: usize,
    source: NearPassSource,
    gate: NearPassGate,
}

impl NearPassEstimator {
    /// The weights at `path` on `device`, run at their trained width and, as the second pass,
    /// `source` at `fine_width` (both network passes read with `readout`:
    /// [`SsmodeEstimator::load_configured`]).
    pub fn load_on(
        path: impl AsRef<Path>,
        device: ComputeDevice,
        fine_width: usize,
        source: NearPassSource,
        readout: &ReadoutOverrides,
    ) -> Result<Self, EstimatorError> {
        let path = path.as_ref();
        let coarse = SsmodeEstimator::load_configured(path, device, None, readout)?;
        let fine: Box<dyn DepthEstimator> = match source {
            NearPassSource::Network => Box::new(SsmodeEstimator::load_configured(
                path,
                device,
                Some(fine_width),
                readout,
            )?),
            NearPassSource::Sweep => {
                // the grid is checked here, before the first frame
                ErpGrid::new(fine_width).map_err(|e| EstimatorError::BadConfig {
                    field: "near_pass_width".to_string(),
                    problem: e.to_string(),
                })?;
                Box::new(PhotometricSweep::new(PhotometricConfig::default())?)
            }
        };
        Ok(Self {
            coarse,
            fine,
            fine_width,
            source,
            gate: source.gate(),
        })
    }

    /// The width of the fine pass (the network's input, or the sweep's grid).
    pub fn fine_width(&self) -> usize {
        self.fine_width
    }

    /// What the fine pass is.
    pub fn source(&self) -> NearPassSource {
        self.source
    }
}

impl DepthEstimator for NearPassEstimator {
    fn name(&self) -> &str {
        self.coarse.name()
    }

    fn estimate(
        &mut self,
        rig: &Rig,
        images: &[RgbImage],
        output: ErpGrid,
    ) -> Result<DepthEstimate, EstimatorError> {
        let coarse = self.coarse.estimate(rig, images, output)?;
        let fine = match self.source {
            NearPassSource::Network => self.fine.estimate(rig, images, output)?,
            NearPassSource::Sweep => {
                let grid =
                    ErpGrid::new(self.fine_width).map_err(|e| EstimatorError::BadConfig {
                        field: "near_pass_width".to_string(),
                        problem: e.to_string(),
                    })?;
                let est = self.fine.estimate(rig, images, grid)?;
                if grid == output {
                    est
                } else {
                    DepthEstimate::on_grid(
                        output,
                        resample_nearest(&est.range_m.data, grid, output),
                        resample_nearest(&est.confidence.data, grid, output),
                    )
                }
            }
        };
        Ok(combine(&coarse, &fine, &self.gate))
    }

    fn set_lens_masks(&mut self, masks: &[Option<LensMask>]) {
        self.coarse.set_lens_masks(masks);
        self.fine.set_lens_masks(masks);
    }
}

/// `data` on `src` read at the nearest pixel of each pixel of `dst` (a range is not averaged
/// across an obstacle's edge).
fn resample_nearest(data: &[f32], src: ErpGrid, dst: ErpGrid) -> Vec<f32> {
    let (sw, sh) = (src.width(), src.height());
    let (dw, dh) = (dst.width(), dst.height());
    (0..dh)
        .flat_map(|y| {
            let sy = (((2 * y + 1) * sh) / (2 * dh)).min(sh - 1);
            (0..dw).map(move |x| data[sy * sw + (((2 * x + 1) * sw) / (2 * dw)).min(sw - 1)])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(range: &[f32], conf: &[f32]) -> DepthEstimate {
        let grid = ErpGrid::new(4).expect("grid");
        DepthEstimate::on_grid(grid, range.to_vec(), conf.to_vec())
    }

    #[test]
    fn the_fine_pass_wins_only_where_it_sees_something_nearer() {
        let coarse = estimate(
            &[10.0, 10.0, 10.0, f32::NAN, 1000.0, 50.0, 2.0, 5.0],
            &[0.9; 8],
        );
        let fine = estimate(
            // 7.9 < 10 / 1.25: nearer; 8.1 not enough; 12 farther; 20 under the missing
            // coarse reading; 29 under the sky but not confident; 35 beyond the near range;
            // NaN; 1.0
            &[7.9, 8.1, 12.0, 20.0, 29.0, 35.0, f32::NAN, 1.0],
            &[0.85, 0.85, 0.85, 0.85, 0.7, 0.85, 0.85, 0.8],
        );
        let out = combine(&coarse, &fine, &NearPassSource::Network.gate());
        assert_eq!(
            out.range_m.data,
            vec![7.9, 10.0, 10.0, 20.0, 1000.0, 50.0, 2.0, 1.0]
        );
        assert_eq!(
            out.confidence.data,
            vec![0.85, 0.9, 0.9, 0.85, 0.9, 0.9, 0.9, 0.8]
        );
    }

    #[test]
    fn the_sweep_is_resampled_to_the_nearest_pixel_and_sources_parse_by_name() {
        // a 8x4 grid read on a 4x2 one: each output pixel takes the source pixel its centre
        // falls in, here the odd rows and columns
        let src = ErpGrid::new(8).expect("grid");
        let dst = ErpGrid::new(4).expect("grid");
        let data: Vec<f32> = (0..src.len()).map(|k| k as f32).collect();
        assert_eq!(
            resample_nearest(&data, src, dst),
            vec![9.0, 11.0, 13.0, 15.0, 25.0, 27.0, 29.0, 31.0]
        );
        // and back up: each source pixel twice in each direction
        let up = resample_nearest(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0], dst, src);
        assert_eq!(&up[..8], &[1.0, 1.0, 2.0, 2.0, 3.0, 3.0, 4.0, 4.0]);
        assert_eq!(&up[8..16], &up[..8]);
        for source in NearPassSource::ALL {
            assert_eq!(
                source.to_string().parse::<NearPassSource>().ok(),
                Some(source)
            );
        }
        let e = "sgm".parse::<NearPassSource>().unwrap_err().to_string();
        assert!(e.contains("near_pass_source") && e.contains("sgm"), "{e}");
    }
}
