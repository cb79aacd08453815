//! Lens masks: the part of each camera's own view that the lens check found blocked
//! (`mode360_health::lens_window`), so that the estimators treat it as unseen (issue 21, item 2).
//!
//! Where a mask is set, the photometric sweep drops the pairs of that camera (as it does where
//! a fisheye lens does not see), and SSMODE's cost volume counts the camera as not seeing those
//! samples (as for fisheye blind regions).

use mode360_core::geometry::{ErpGrid, PixelCoord};

/// Width of the analysis grid (height half of it): coarse enough that a few pixels of depth
/// error or calibration do not matter, fine enough for regions of a few degrees.
pub const ANALYSIS_WIDTH: usize = 128;

/// The analysis grid.
pub fn analysis_grid() -> ErpGrid {
    // ANALYSIS_WIDTH is even and large enough: the constructor cannot fail on it.
    ErpGrid::new(ANALYSIS_WIDTH).unwrap_or_else(|_| unreachable!("ANALYSIS_WIDTH is valid"))
}

/// Solid-angle weight `cos(lat)` of cell `k` of `grid`.
pub fn cell_weight(grid: ErpGrid, k: usize) -> f64 {
    grid.lonlat_from_pixel(PixelCoord {
        u: (k % grid.width()) as f64,
        v: (k / grid.width()) as f64,
    })
    .lat_rad
    .cos()
}

/// The blocked part of one camera's view, on the analysis grid of the camera's panorama (its
/// own ERP frame, as the estimators sweep it).
#[derive(Clone, Debug, PartialEq)]
pub struct LensMask {
    /// Row-major over [`analysis_grid`]: `true` where the lens is blocked.
    blocked: Vec<bool>,
}

impl LensMask {
    /// A mask from cells of the analysis grid; `None` unless it has one cell per grid cell.
    pub fn from_cells(blocked: Vec<bool>) -> Option<Self> {
        (blocked.len() == analysis_grid().len()).then_some(Self { blocked })
    }

    /// The blocked cells, row-major over the analysis grid.
    pub fn cells(&self) -> &[bool] {
        &self.blocked
    }

    /// Share of the sphere (solid angle) that is blocked.
    pub fn fraction(&self) -> f64 {
        let grid = analysis_grid();
        let (mut blocked, mut all) = (0.0, 0.0);
        for (k, &b) in self.blocked.iter().enumerate() {
            let w = cell_weight(grid, k);
            all += w;
            if b {
                blocked += w;
            }
        }
        if all > 0.0 {
            blocked / all
        } else {
            0.0
        }
    }

    /// The mask on another ERP grid of the same frame (nearest cell): `true` where blocked.
    pub fn blocked_on(&self, grid: ErpGrid) -> Vec<bool> {
        let mask = analysis_grid();
        (0..grid.len())
            .map(|k| {
                let (u, v) = (k % grid.width(), k / grid.width());
                let mu = ((u * mask.width()) / grid.width()).min(mask.width() - 1);
                let mv = ((v * mask.height()) / grid.height()).min(mask.height() - 1);
                self.blocked[mv * mask.width() + mu]
            })
            .collect()
    }
}

/// `mask` grown by `r` cells in rows and columns (columns wrap, rows clamp).
pub fn dilate(grid: ErpGrid, mask: &[bool], r: usize) -> Vec<bool> {
    let (w, h) = (grid.width(), grid.height());
    let mut rows = vec![false; mask.len()];
    for v in 0..h {
        for u in 0..w {
            if mask[v * w + u] {
                for du in 0..=2 * r {
                    rows[v * w + (u + w + du - r) % w] = true;
                }
            }
        }
    }
    let mut out = vec![false; mask.len()];
    for v in 0..h {
        for u in 0..w {
            if rows[v * w + u] {
                for vv in v.saturating_sub(r)..=(v + r).min(h - 1) {
                    out[vv * w + u] = true;
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masks_resample_onto_other_grids() -> Result<(), Box<dyn std::error::Error>> {
        let grid = analysis_grid();
        let mut cells = vec![false; grid.len()];
        // The left half of the panorama.
        for (k, c) in cells.iter_mut().enumerate() {
            *c = k % grid.width() < grid.width() / 2;
        }
        let mask = LensMask::from_cells(cells).ok_or("mask size")?;
        assert!((mask.fraction() - 0.5).abs() < 1e-9);
        let fine = ErpGrid::new(512)?;
        let on_fine = mask.blocked_on(fine);
        assert_eq!(on_fine.iter().filter(|&&b| b).count(), fine.len() / 2);
        assert!(on_fine[0] && !on_fine[511]);
        assert!(LensMask::from_cells(vec![true; 3]).is_none());
        Ok(())
    }
}
