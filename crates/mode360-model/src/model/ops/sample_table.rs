//! [`SampleTable`]: the precomputed bilinear sampling tables the sweep and the table ops read
//! (flat taps, or the sweep's compact ERP samples expanded on read), with the transposed table
//! their gradients scatter through and their copies on other devices.

use std::borrow::Cow;
use std::sync::{Arc, Mutex, OnceLock};

use candle_core::{Device, Result, Tensor};
use mode360_core::geometry::{BilinearTaps, ErpGrid, ErpSample};

use super::types::OpsError;

/// For every source pixel `p`, the samples that read it: `entries[start[p]..start[p + 1]]`.
#[derive(Clone, Debug)]
pub(super) struct TransposedTable {
    pub(super) pixels: usize,
    /// `pixels + 1` offsets into `sample` and `weight`.
    pub(super) start: Vec<usize>,
    pub(super) sample: Vec<u32>,
    pub(super) weight: Vec<f32>,
}

/// How a table keeps its taps.
#[derive(Debug)]
enum TapStore {
    /// Any taps: `4 N` pixel indices into `H·W` and `4 N` weights, sample-major (32 bytes a
    /// sample).
    Flat { index: Vec<u32>, weight: Vec<f32> },
    /// Bilinear samples of one ERP grid, expanded on read (8 bytes a sample): the sweep's
    /// tables, millions of samples per camera.
    Erp {
        grid: ErpGrid,
        samples: Vec<ErpSample>,
    },
}

#[derive(Debug)]
struct TableData {
    taps: TapStore,
    /// Number of output samples N.
    len: usize,
    /// Largest index + 1 (0 for an empty table): the fewest pixels the features must have.
    min_pixels: usize,
    /// Built on first backward, for the pixel count seen then.
    transposed: OnceLock<TransposedTable>,
    /// The taps as index and weight tensors on the devices the composite ran on, uploaded
    /// once.
    on_device: Mutex<Vec<DeviceTable>>,
}

/// A table's indices `(4 N)` (u32) and weights `(1, N, 4, 1)` on one device.
#[derive(Clone, Debug)]
pub(super) struct DeviceTable {
    pub(super) index: Tensor,
    pub(super) weight: Tensor,
}

/// A precomputed bilinear sampling table: 4 pixel indices and 4 weights per output sample
/// ([`SampleTable::taps`]). Cheap to clone (shared).
#[derive(Clone, Debug)]
pub struct SampleTable {
    data: Arc<TableData>,
}

impl From<Vec<BilinearTaps>> for SampleTable {
    fn from(taps: Vec<BilinearTaps>) -> Self {
        Self::new(&taps)
    }
}

impl SampleTable {
    /// Taps per output sample.
    pub const TAPS: usize = 4;

    /// A table with one output sample per element of `taps`, in order.
    pub fn new(taps: &[BilinearTaps]) -> Self {
        let index: Vec<u32> = taps.iter().flat_map(|t| t.index).collect();
        let weight: Vec<f32> = taps.iter().flat_map(|t| t.weight).collect();
        let min_pixels = index.iter().max().map_or(0, |&m| m as usize + 1);
        Self::with_store(TapStore::Flat { index, weight }, taps.len(), min_pixels)
    }

    /// A table of bilinear samples of `grid`, one output sample per element of `samples`, in
    /// order: the same taps as [`Self::new`] of their [`ErpGrid::taps_of`], in 8 bytes a
    /// sample instead of 32.
    pub fn from_erp(grid: ErpGrid, samples: Vec<ErpSample>) -> Self {
        let min_pixels = samples
            .iter()
            .filter(|s| s.is_seen())
            .flat_map(|&s| grid.taps_of(s).index)
            .max()
            .map_or(0, |m| m as usize + 1);
        let len = samples.len();
        Self::with_store(TapStore::Erp { grid, samples }, len, min_pixels)
    }

    fn with_store(taps: TapStore, len: usize, min_pixels: usize) -> Self {
        Self {
            data: Arc::new(TableData {
                taps,
                len,
                min_pixels,
                transposed: OnceLock::new(),
                on_device: Mutex::new(Vec::new()),
            }),
        }
    }

    /// Number of output samples N.
    pub fn len(&self) -> usize {
        self.data.len
    }

    pub fn is_empty(&self) -> bool {
        self.data.len == 0
    }

    /// The taps of sample `n` (`n < len`).
    #[inline(always)]
    pub fn taps(&self, n: usize) -> BilinearTaps {
        match &self.data.taps {
            TapStore::Flat { index, weight } => {
                let s = n * Self::TAPS;
                BilinearTaps {
                    index: [index[s], index[s + 1], index[s + 2], index[s + 3]],
                    weight: [weight[s], weight[s + 1], weight[s + 2], weight[s + 3]],
                }
            }
            TapStore::Erp { grid, samples } => grid.taps_of(samples[n]),
        }
    }

    /// Every sample's taps, in order.
    pub fn iter(&self) -> impl Iterator<Item = BilinearTaps> + '_ {
        (0..self.len()).map(|n| self.taps(n))
    }

    /// The grid and samples of a table built by [`Self::from_erp`].
    pub fn erp_samples(&self) -> Option<(ErpGrid, &[ErpSample])> {
        match &self.data.taps {
            TapStore::Erp { grid, samples } => Some((*grid, samples)),
            TapStore::Flat { .. } => None,
        }
    }

    /// Bytes the taps take in memory.
    pub fn tap_bytes(&self) -> usize {
        match &self.data.taps {
            TapStore::Flat { index, weight } => {
                std::mem::size_of_val(index.as_slice()) + std::mem::size_of_val(weight.as_slice())
            }
            TapStore::Erp { samples, .. } => std::mem::size_of_val(samples.as_slice()),
        }
    }

    /// The table as tensors on `device`, uploaded on first use and kept (the rig's tables are
    /// reused every frame; on a GPU they would otherwise cross the bus each time).
    pub(super) fn on_device(&self, device: &Device) -> Result<DeviceTable> {
        let mut cache = self
            .data
            .on_device
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(t) = cache.iter().find(|t| t.index.device().same_device(device)) {
            return Ok(t.clone());
        }
        let n = self.len();
        let index: Vec<u32> = self.iter().flat_map(|t| t.index).collect();
        let weight: Vec<f32> = self.iter().flat_map(|t| t.weight).collect();
        let table = DeviceTable {
            index: Tensor::from_vec(index, n * Self::TAPS, device)?,
            weight: Tensor::from_vec(weight, (1, n, Self::TAPS, 1), device)?,
        };
        cache.push(table.clone());
        Ok(table)
    }

    /// Errors unless every index is below `pixels`.
    pub(super) fn check_pixels(&self, pixels: usize, op: &'static str) -> Result<()> {
        if self.data.min_pixels > pixels {
            return Err(OpsError::TableIndex {
                op,
                index: (self.data.min_pixels - 1) as u32,
                pixels,
            }
            .into());
        }
        Ok(())
    }

    /// The transposed table for features of `pixels` pixels; cached for the first size seen.
    pub(super) fn transposed(&self, pixels: usize) -> Cow<'_, TransposedTable> {
        let cached = self
            .data
            .transposed
            .get_or_init(|| build_transposed(self, pixels));
        if cached.pixels == pixels {
            Cow::Borrowed(cached)
        } else {
            Cow::Owned(build_transposed(self, pixels))
        }
    }
}

/// Counting sort of the table's `(sample, weight)` pairs by pixel.
fn build_transposed(table: &SampleTable, pixels: usize) -> TransposedTable {
    let mut start = vec![0usize; pixels + 1];
    for t in table.iter() {
        for p in t.index {
            start[p as usize + 1] += 1;
        }
    }
    for p in 0..pixels {
        start[p + 1] += start[p];
    }
    let mut fill = start.clone();
    let entries = table.len() * SampleTable::TAPS;
    let mut sample = vec![0u32; entries];
    let mut w = vec![0f32; entries];
    for (n, t) in table.iter().enumerate() {
        for (&p, &wk) in t.index.iter().zip(&t.weight) {
            let slot = &mut fill[p as usize];
            sample[*slot] = n as u32;
            w[*slot] = wk;
            *slot += 1;
        }
    }
    TransposedTable {
        pixels,
        start,
        sample,
        weight: w,
    }
}
