//! Reader for the paper's Deep360 dataset, converted to this crate's conventions.
//!
//! Layout on disk (from the paper's public loader):
//! `ep{1..6}_500frames/{training,validation,testing}/` with `rgb/` (and `rgb_soiled/`) holding
//! twelve RGBA PNGs per frame, `{frame:06d}_{pair}_rgb{cam}.png` for pairs 12 13 14 23 24 34,
//! each a Cassini (GEER) image 512 wide and 1024 tall, and `depth/{frame:06d}_depth.npz`
//! (key `arr_0`), the range in metres of camera 1 as a 1024 x 512 Cassini image.
//!
//! Cassini convention (dataset frame `D`: x left, y up, z forward): row `i`, column `j` of an
//! `H x W` image look along `(sin phi, cos phi sin theta, cos phi cos theta)` with
//! `theta = pi - (i + 0.5) 2 pi / H` and `phi = pi/2 - (j + 0.5) pi / W`. Images `12_rgb1`,
//! `12_rgb2`, `34_rgb3` and `34_rgb4` share that orientation; cameras 1..4 sit at (0,0,0),
//! (-1,0,0), (0,0,-1), (-1,0,-1) m in `D`.
//!
//! REP 103 mapping: `x_rep = z_D` (forward), `y_rep = x_D` (left), `z_rep = y_D` (up). The
//! cameras then sit at (0,0,0), (0,-1,0), (-1,0,0), (-1,-1,0) m relative to camera 1, which is
//! exactly the rig in `launch_configs/rig_deep360.yaml` (embedded here as [`DEEP360_RIG_YAML`]).
//!
//! Conversion to ERP: for each ERP pixel, `dir_rep` (see [`crate::geometry::erp`]) is rotated
//! into `D`, then `phi = asin(x_D)`, `theta = atan2(y_D, z_D)`, and the Cassini image is
//! sampled at `j = (pi/2 - phi) W / pi - 0.5`, `i = (pi - theta) H / (2 pi) - 0.5`, bilinearly
//! for colour (rows wrap around theta = +-pi, columns clamp at the poles phi = +-pi/2) and
//! nearest-neighbour for range (no blending across depth edges).

use crate::frame::{FloatImage, RgbImage, RigFrame};
use crate::geometry::{ErpGrid, GeometryError, PixelCoord, Rig, RigError};
use nalgebra::Vector3;
use std::f64::consts::{FRAC_PI_2, PI};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The Deep360 rig in REP 103 (same as `launch_configs/rig_deep360.yaml`).
pub const DEEP360_RIG_YAML: &str = include_str!("../launch_configs/rig_deep360.yaml");
/// Number of cameras of the Deep360 rig.
pub const DEEP360_CAMERAS: usize = 4;
/// Width (columns) of a Deep360 Cassini image.
pub const CASSINI_WIDTH: usize = 512;
/// Height (rows) of a Deep360 Cassini image.
pub const CASSINI_HEIGHT: usize = 1024;
/// Key of the range array inside the depth `.npz`.
pub const DEPTH_NPZ_KEY: &str = "arr_0";
/// Deep360 frames are 10 Hz apart; see [`Deep360FrameId::stamp_ns`].
pub const FRAME_PERIOD_NS: u64 = 100_000_000;
/// Frame slots per episode in the stamp scheme: frame `k` of episode `e` is stamped
/// `(e * EPISODE_FRAME_SLOTS + k) * FRAME_PERIOD_NS` (episodes hold 500 frames).
pub const EPISODE_FRAME_SLOTS: u64 = 1000;
/// Largest range of the dataset's ground truth (the paper's maximum depth), metres.
pub const DEEP360_MAX_DEPTH_M: f64 = 1000.0;
/// Number of episodes in the dataset.
pub const EPISODES: u32 = 6;
/// Magic bytes at the start of every `.npy` file.
const NPY_MAGIC: &[u8] = b"\x93NUMPY";
/// Fixed part of an `.npy` v1 header: magic (6), version (2), header length (2).
const NPY_V1_PREFIX_BYTES: usize = 10;
/// Fixed part of an `.npy` v2/v3 header: magic (6), version (2), header length (4).
const NPY_V2_PREFIX_BYTES: usize = 12;
/// `.npy` headers are padded so the data starts on this alignment.
const NPY_ALIGN_BYTES: usize = 64;

/// Errors reading Deep360: each names the file and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum Deep360Error {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot decode image: {message}")]
    Image { path: String, message: String },
    #[error("{path}: image is {width}x{height}, expected {expected_width}x{expected_height}")]
    ImageSize {
        path: String,
        width: u32,
        height: u32,
        expected_width: usize,
        expected_height: usize,
    },
    #[error("{path}: not a valid .npz archive: {message}")]
    Npz { path: String, message: String },
    #[error("{path}: array '{key}': {message}")]
    Npy {
        path: String,
        key: String,
        message: String,
    },
    #[error("Deep360 rig: {0}")]
    Rig(#[from] RigError),
    #[error("Deep360 output grid: {0}")]
    Grid(#[from] GeometryError),
}

/// The dataset's three splits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Deep360Split {
    Training,
    Validation,
    Testing,
}

impl std::str::FromStr for Deep360Split {
    type Err = String;

    /// `train`/`training`, `val`/`validation`, `test`/`testing`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "train" | "training" => Ok(Self::Training),
            "val" | "validation" => Ok(Self::Validation),
            "test" | "testing" => Ok(Self::Testing),
            other => Err(format!(
                "unknown Deep360 split '{other}' (expected train, val or test)"
            )),
        }
    }
}

impl Deep360Split {
    /// Directory name of the split.
    pub fn dir_name(self) -> &'static str {
        match self {
            Self::Training => "training",
            Self::Validation => "validation",
            Self::Testing => "testing",
        }
    }
}

/// One frame of the dataset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Deep360FrameId {
    /// Episode 1..=6.
    pub episode: u32,
    /// Frame number within the split directory.
    pub frame: u32,
}

impl Deep360FrameId {
    /// Header stamp of the frame in a bag: `(episode * EPISODE_FRAME_SLOTS + frame) * 100 ms`,
    /// unique across episodes as long as `frame < EPISODE_FRAME_SLOTS`.
    pub fn stamp_ns(self) -> u64 {
        (u64::from(self.episode) * EPISODE_FRAME_SLOTS + u64::from(self.frame)) * FRAME_PERIOD_NS
    }
}

impl std::fmt::Display for Deep360FrameId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "episode {} frame {:06}", self.episode, self.frame)
    }
}

/// A frame with one of its image sets: `rgb/` (clean) or `rgb_soiled/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Deep360FrameVariant {
    pub id: Deep360FrameId,
    pub soiled: bool,
}

/// A dense row-major `f32` array read from `.npy`.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// The dataset rooted at a directory holding `ep{1..6}_500frames/`.
#[derive(Clone, Debug)]
pub struct Deep360Dataset {
    root: PathBuf,
    rig: Rig,
}

/// The Deep360 rig (camera 1 is the reference and output frame).
pub fn deep360_rig() -> Result<Rig, RigError> {
    Rig::from_yaml_str(DEEP360_RIG_YAML, "rig_deep360.yaml (embedded)")
}

impl Deep360Dataset {
    /// Opens the dataset at `root` (the directory with the `ep*_500frames` folders).
    pub fn open(root: impl AsRef<Path>) -> Result<Self, Deep360Error> {
        let root = root.as_ref().to_path_buf();
        if !root.is_dir() {
            return Err(Deep360Error::Io {
                path: root.display().to_string(),
                source: std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "Deep360 root directory does not exist",
                ),
            });
        }
        Ok(Self {
            root,
            rig: deep360_rig()?,
        })
    }

    /// The rig every frame was recorded with, in REP 103.
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// Directory of one episode's split.
    pub fn split_dir(&self, episode: u32, split: Deep360Split) -> PathBuf {
        self.root
            .join(format!("ep{episode}_500frames"))
            .join(split.dir_name())
    }

    /// Path of a camera's Cassini PNG (`cam` is 1-based).
    pub fn image_path(
        &self,
        id: Deep360FrameId,
        split: Deep360Split,
        cam: usize,
        soiled: bool,
    ) -> PathBuf {
        let pair = if cam <= 2 { "12" } else { "34" };
        self.split_dir(id.episode, split)
            .join(if soiled { "rgb_soiled" } else { "rgb" })
            .join(format!("{:06}_{pair}_rgb{cam}.png", id.frame))
    }

    /// Path of a frame's ground-truth range `.npz`.
    pub fn depth_path(&self, id: Deep360FrameId, split: Deep360Split) -> PathBuf {
        self.split_dir(id.episode, split)
            .join("depth")
            .join(format!("{:06}_depth.npz", id.frame))
    }

    /// All frames of `split` present on disk (found through their depth files), sorted.
    /// Episodes whose directory is missing are skipped.
    pub fn frame_ids(&self, split: Deep360Split) -> Result<Vec<Deep360FrameId>, Deep360Error> {
        let mut ids = Vec::new();
        for episode in 1..=EPISODES {
            let dir = self.split_dir(episode, split).join("depth");
            if !dir.is_dir() {
                continue;
            }
            let entries = std::fs::read_dir(&dir).map_err(|source| Deep360Error::Io {
                path: dir.display().to_string(),
                source,
            })?;
            for entry in entries {
                let entry = entry.map_err(|source| Deep360Error::Io {
                    path: dir.display().to_string(),
                    source,
                })?;
                let name = entry.file_name().to_string_lossy().into_owned();
                if let Some(frame) = name
                    .strip_suffix("_depth.npz")
                    .and_then(|s| s.parse::<u32>().ok())
                {
                    ids.push(Deep360FrameId { episode, frame });
                }
            }
        }
        ids.sort();
        Ok(ids)
    }

    /// The root directory (the one holding the `ep*_500frames` folders).
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Every frame of `split` (see [`Self::frame_ids`]) once per image directory its episode
    /// has (`rgb/` clean, `rgb_soiled/` soiled), sorted.
    pub fn frame_variants(
        &self,
        split: Deep360Split,
    ) -> Result<Vec<Deep360FrameVariant>, Deep360Error> {
        let mut out = Vec::new();
        for id in self.frame_ids(split)? {
            let dir = self.split_dir(id.episode, split);
            for (soiled, sub) in [(false, "rgb"), (true, "rgb_soiled")] {
                if dir.join(sub).is_dir() {
                    out.push(Deep360FrameVariant { id, soiled });
                }
            }
        }
        Ok(out)
    }

    /// The first of a frame's five files (four camera PNGs, the depth `.npz`) that is not on
    /// disk, if any: a cheap check before a long conversion.
    pub fn missing_file(
        &self,
        id: Deep360FrameId,
        split: Deep360Split,
        soiled: bool,
    ) -> Option<PathBuf> {
        (1..=DEEP360_CAMERAS)
            .map(|cam| self.image_path(id, split, cam, soiled))
            .chain(std::iter::once(self.depth_path(id, split)))
            .find(|p| !p.is_file())
    }

    /// Loads one frame as ERP images of `erp_width` columns in the rig's camera order, with
    /// the ground-truth range of camera 1 as stored (nearest-neighbour resampled; infinite or
    /// out-of-range values are kept: [`clamp_range_to_max`] applies the project's convention).
    /// The stamp is [`Deep360FrameId::stamp_ns`].
    pub fn load_frame(
        &self,
        id: Deep360FrameId,
        split: Deep360Split,
        soiled: bool,
        erp_width: usize,
    ) -> Result<RigFrame, Deep360Error> {
        let grid = ErpGrid::new(erp_width)?;
        let mut images = Vec::with_capacity(DEEP360_CAMERAS);
        for cam in 1..=DEEP360_CAMERAS {
            let path = self.image_path(id, split, cam, soiled);
            let cassini = read_cassini_png(&path)?;
            images.push(cassini_to_erp_rgb(&cassini, grid));
        }
        let depth_path = self.depth_path(id, split);
        let range = read_npz_array(&depth_path, DEPTH_NPZ_KEY)?;
        if range.shape != [CASSINI_HEIGHT, CASSINI_WIDTH] {
            return Err(Deep360Error::Npy {
                path: depth_path.display().to_string(),
                key: DEPTH_NPZ_KEY.into(),
                message: format!(
                    "shape {:?}, expected [{CASSINI_HEIGHT}, {CASSINI_WIDTH}]",
                    range.shape
                ),
            });
        }
        let cassini_range = FloatImage {
            width: CASSINI_WIDTH,
            height: CASSINI_HEIGHT,
            data: range.data,
        };
        Ok(RigFrame {
            stamp_ns: id.stamp_ns(),
            images,
            ground_truth: Some(cassini_to_erp_range(&cassini_range, grid)),
        })
    }
}

fn read_cassini_png(path: &Path) -> Result<RgbImage, Deep360Error> {
    let p = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| Deep360Error::Io {
        path: p.clone(),
        source,
    })?;
    let img = image::load_from_memory(&bytes)
        .map_err(|e| Deep360Error::Image {
            path: p.clone(),
            message: e.to_string(),
        })?
        .to_rgb8();
    if img.width() as usize != CASSINI_WIDTH || img.height() as usize != CASSINI_HEIGHT {
        return Err(Deep360Error::ImageSize {
            path: p,
            width: img.width(),
            height: img.height(),
            expected_width: CASSINI_WIDTH,
            expected_height: CASSINI_HEIGHT,
        });
    }
    Ok(img)
}

/// Makes a range image follow the project's convention (design.md): values beyond
/// `max_depth_m`, infinity included (sky), become `max_depth_m`; NaN, non-positive and
/// negative-infinite values become NaN (invalid).
pub fn clamp_range_to_max(range: &mut FloatImage, max_depth_m: f64) {
    let max = max_depth_m as f32;
    for v in &mut range.data {
        if v.is_nan() || *v <= 0.0 {
            *v = f32::NAN;
        } else if *v > max {
            *v = max;
        }
    }
}

// ---- Cassini <-> ERP ------------------------------------------------------------------

/// A continuous position in a Cassini image (`col` = j, `row` = i, pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CassiniCoord {
    pub col: f64,
    pub row: f64,
}

/// REP 103 direction from a dataset-frame (x left, y up, z forward) direction.
pub fn rep_from_dataset(d: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(d.z, d.x, d.y)
}

/// Dataset-frame direction from a REP 103 direction.
pub fn dataset_from_rep(r: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(r.y, r.z, r.x)
}

/// REP 103 unit direction of Cassini pixel `(row i, col j)` of a `width x height` image:
/// `dir_D = (sin phi, cos phi sin theta, cos phi cos theta)`.
pub fn cassini_dir(c: CassiniCoord, width: usize, height: usize) -> Vector3<f64> {
    let theta = PI - (c.row + 0.5) * 2.0 * PI / height as f64;
    let phi = FRAC_PI_2 - (c.col + 0.5) * PI / width as f64;
    let (sp, cp) = phi.sin_cos();
    let (st, ct) = theta.sin_cos();
    rep_from_dataset(&Vector3::new(sp, cp * st, cp * ct))
}

/// Cassini position that looks along the REP 103 direction `dir` (any non-zero length).
pub fn cassini_from_dir(dir: &Vector3<f64>, width: usize, height: usize) -> CassiniCoord {
    let d = dataset_from_rep(dir);
    let norm = d.norm().max(f64::MIN_POSITIVE);
    let phi = (d.x / norm).clamp(-1.0, 1.0).asin();
    let theta = d.y.atan2(d.z);
    CassiniCoord {
        col: (FRAC_PI_2 - phi) * width as f64 / PI - 0.5,
        row: (PI - theta) * height as f64 / (2.0 * PI) - 0.5,
    }
}

/// Bilinear taps in a Cassini image: rows wrap (theta is periodic), columns clamp.
fn cassini_taps(c: CassiniCoord, width: usize, height: usize) -> ([usize; 4], [f32; 4]) {
    let (w, h) = (width as i64, height as i64);
    let col = c.col.clamp(0.0, (w - 1) as f64);
    let j0 = col.floor();
    let fj = (col - j0) as f32;
    let j0 = j0 as i64;
    let j1 = (j0 + 1).min(w - 1);
    let i0f = c.row.floor();
    let fi = (c.row - i0f) as f32;
    let i0 = (i0f as i64).rem_euclid(h);
    let i1 = (i0 + 1) % h;
    let idx = |i: i64, j: i64| (i * w + j) as usize;
    (
        [idx(i0, j0), idx(i0, j1), idx(i1, j0), idx(i1, j1)],
        [
            (1.0 - fj) * (1.0 - fi),
            fj * (1.0 - fi),
            (1.0 - fj) * fi,
            fj * fi,
        ],
    )
}

/// Resamples a Cassini colour image to ERP on `grid` (bilinear).
pub fn cassini_to_erp_rgb(cassini: &RgbImage, grid: ErpGrid) -> RgbImage {
    let (cw, ch) = (cassini.width() as usize, cassini.height() as usize);
    let src = cassini.as_raw();
    let mut out = RgbImage::new(grid.width() as u32, grid.height() as u32);
    for (v, row) in out.chunks_mut(grid.width() * 3).enumerate() {
        for (u, px) in row.chunks_mut(3).enumerate() {
            let dir = grid.dir_from_pixel(PixelCoord {
                u: u as f64,
                v: v as f64,
            });
            let (idx, wt) = cassini_taps(cassini_from_dir(&dir, cw, ch), cw, ch);
            for (c, out_c) in px.iter_mut().enumerate() {
                let s: f32 = idx
                    .iter()
                    .zip(wt)
                    .map(|(&i, w)| f32::from(src[i * 3 + c]) * w)
                    .sum();
                *out_c = s.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// Nearest Cassini pixel index for a continuous position (rows wrap, columns clamp).
fn cassini_nearest(c: CassiniCoord, width: usize, height: usize) -> usize {
    let j = (c.col.round() as i64).clamp(0, width as i64 - 1);
    let i = (c.row.round() as i64).rem_euclid(height as i64);
    (i * width as i64 + j) as usize
}

/// Resamples a Cassini range image to ERP on `grid` (nearest neighbour). The ray directions
/// are the same, so range values carry over unchanged.
pub fn cassini_to_erp_range(cassini: &FloatImage, grid: ErpGrid) -> FloatImage {
    let mut out = FloatImage::filled(grid.width(), grid.height(), f32::NAN);
    for v in 0..grid.height() {
        for u in 0..grid.width() {
            let dir = grid.dir_from_pixel(PixelCoord {
                u: u as f64,
                v: v as f64,
            });
            let c = cassini_from_dir(&dir, cassini.width, cassini.height);
            out.data[v * grid.width() + u] =
                cassini.data[cassini_nearest(c, cassini.width, cassini.height)];
        }
    }
    out
}

/// Resamples an ERP colour image to a `width x height` Cassini image (bilinear, ERP seam
/// wraps). Used to write Deep360-style fixtures.
pub fn erp_to_cassini_rgb(erp: &RgbImage, width: usize, height: usize) -> RgbImage {
    let grid_w = erp.width() as usize;
    let grid = match ErpGrid::new(grid_w) {
        Ok(g) => g,
        Err(_) => return RgbImage::new(width as u32, height as u32),
    };
    let src = erp.as_raw();
    let mut out = RgbImage::new(width as u32, height as u32);
    for (i, row) in out.chunks_mut(width * 3).enumerate() {
        for (j, px) in row.chunks_mut(3).enumerate() {
            let dir = cassini_dir(
                CassiniCoord {
                    col: j as f64,
                    row: i as f64,
                },
                width,
                height,
            );
            let taps = grid.bilinear_taps(grid.pixel_from_dir(&dir));
            for (c, out_c) in px.iter_mut().enumerate() {
                let s: f32 = taps
                    .index
                    .iter()
                    .zip(taps.weight)
                    .map(|(&k, w)| f32::from(src[k as usize * 3 + c]) * w)
                    .sum();
                *out_c = s.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// Resamples an ERP range image to a `width x height` Cassini image (nearest neighbour).
pub fn erp_to_cassini_range(erp: &FloatImage, width: usize, height: usize) -> FloatImage {
    let mut out = FloatImage::filled(width, height, f32::NAN);
    let Ok(grid) = ErpGrid::new(erp.width) else {
        return out;
    };
    for i in 0..height {
        for j in 0..width {
            let dir = cassini_dir(
                CassiniCoord {
                    col: j as f64,
                    row: i as f64,
                },
                width,
                height,
            );
            let p = grid.pixel_from_dir(&dir);
            let u = (p.u.round() as i64).rem_euclid(erp.width as i64) as usize;
            let v = (p.v.round() as i64).clamp(0, erp.height as i64 - 1) as usize;
            out.data[i * width + j] = erp.get(u, v);
        }
    }
    out
}

// ---- .npy / .npz ----------------------------------------------------------------------

/// Parses an `.npy` file (versions 1-3) holding little-endian `f4` or `f8` in C order.
/// `f8` values are narrowed to `f32`.
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, String> {
    if bytes.len() < NPY_V1_PREFIX_BYTES || &bytes[..NPY_MAGIC.len()] != NPY_MAGIC {
        return Err("missing .npy magic".into());
    }
    let major = bytes[NPY_MAGIC.len()];
    let (header_len, prefix) = match major {
        1 => (
            u16::from_le_bytes([bytes[8], bytes[9]]) as usize,
            NPY_V1_PREFIX_BYTES,
        ),
        2 | 3 => {
            if bytes.len() < NPY_V2_PREFIX_BYTES {
                return Err("truncated .npy header".into());
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                NPY_V2_PREFIX_BYTES,
            )
        }
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let header_end = prefix + header_len;
    let header = bytes
        .get(prefix..header_end)
        .ok_or_else(|| "truncated .npy header".to_string())?;
    let header = std::str::from_utf8(header).map_err(|_| "header is not text".to_string())?;
    let descr = header_value(header, "descr")?;
    let descr = descr.trim().trim_matches(|c| c == '\'' || c == '"');
    let fortran = header_value(header, "fortran_order")?;
    if fortran.trim().starts_with("True") {
        return Err("Fortran-order arrays are not supported (expected C order)".into());
    }
    let shape_text = header_value(header, "shape")?;
    let shape_inner = shape_text
        .trim()
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| format!("malformed shape '{shape_text}'"))?;
    let shape = shape_inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("bad dimension '{s}'"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let count: usize = shape.iter().product();
    let payload = &bytes[header_end..];
    let data = match descr {
        "<f4" | "f4" => {
            check_payload(payload, count, 4)?;
            payload[..count * 4]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        }
        "<f8" | "f8" => {
            check_payload(payload, count, 8)?;
            payload[..count * 8]
                .chunks_exact(8)
                .map(|c| {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(c);
                    f64::from_le_bytes(b) as f32
                })
                .collect()
        }
        other => return Err(format!("unsupported dtype '{other}' (need <f4 or <f8)")),
    };
    Ok(NpyArray { shape, data })
}

fn check_payload(payload: &[u8], count: usize, elem_bytes: usize) -> Result<(), String> {
    if payload.len() < count * elem_bytes {
        return Err(format!(
            "data truncated: {} bytes for {count} values of {elem_bytes} bytes",
            payload.len()
        ));
    }
    Ok(())
}

/// The text after `'key':` in a `.npy` header dict, up to the next top-level comma.
fn header_value<'a>(header: &'a str, key: &str) -> Result<&'a str, String> {
    let pat = format!("'{key}':");
    let start = header
        .find(&pat)
        .ok_or_else(|| format!("header has no '{key}'"))?
        + pat.len();
    let rest = &header[start..];
    let mut depth = 0i32;
    for (k, ch) in rest.char_indices() {
        match ch {
            '(' => depth += 1,
            ')' => depth -= 1,
            ',' | '}' if depth == 0 => return Ok(&rest[..k]),
            _ => {}
        }
    }
    Ok(rest)
}

/// Serializes a little-endian `f4` C-order `.npy` (version 1).
pub fn write_npy(shape: &[usize], data: &[f32]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_text}, }}");
    let unpadded = NPY_V1_PREFIX_BYTES + header.len() + 1;
    let pad = (NPY_ALIGN_BYTES - unpadded % NPY_ALIGN_BYTES) % NPY_ALIGN_BYTES;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut out = Vec::with_capacity(NPY_V1_PREFIX_BYTES + header.len() + data.len() * 4);
    out.extend_from_slice(NPY_MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Reads array `key` (file `key.npy` inside the archive) from an `.npz`.
pub fn read_npz_array(path: &Path, key: &str) -> Result<NpyArray, Deep360Error> {
    let p = path.display().to_string();
    let file = std::fs::File::open(path).map_err(|source| Deep360Error::Io {
        path: p.clone(),
        source,
    })?;
    let mut archive = zip::ZipArchive::new(file).map_err(|e| Deep360Error::Npz {
        path: p.clone(),
        message: e.to_string(),
    })?;
    let mut entry = archive
        .by_name(&format!("{key}.npy"))
        .map_err(|e| Deep360Error::Npz {
            path: p.clone(),
            message: format!("no array '{key}': {e}"),
        })?;
    let mut bytes = Vec::new();
    entry
        .read_to_end(&mut bytes)
        .map_err(|source| Deep360Error::Io {
            path: p.clone(),
            source,
        })?;
    parse_npy(&bytes).map_err(|message| Deep360Error::Npy {
        path: p,
        key: key.into(),
        message,
    })
}

/// Writes a single-array `.npz` (deflate-compressed, like `numpy.savez_compressed`).
pub fn write_npz(
    path: &Path,
    key: &str,
    shape: &[usize],
    data: &[f32],
) -> Result<(), Deep360Error> {
    let p = path.display().to_string();
    let io = |source: std::io::Error| Deep360Error::Io {
        path: p.clone(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut zw = zip::ZipWriter::new(file);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    let zerr = |e: zip::result::ZipError| Deep360Error::Npz {
        path: p.clone(),
        message: e.to_string(),
    };
    zw.start_file(format!("{key}.npy"), opts).map_err(zerr)?;
    zw.write_all(&write_npy(shape, data)).map_err(io)?;
    zw.finish().map_err(zerr)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cassini_direction_round_trip() {
        for &(col, row) in &[(0.0, 0.0), (100.3, 700.2), (511.0, 1023.0), (256.0, 512.0)] {
            let c = CassiniCoord { col, row };
            let d = cassini_dir(c, CASSINI_WIDTH, CASSINI_HEIGHT);
            let back = cassini_from_dir(&d, CASSINI_WIDTH, CASSINI_HEIGHT);
            assert!((back.col - col).abs() < 1e-6, "{back:?} vs {c:?}");
            let drow = (back.row - row).rem_euclid(CASSINI_HEIGHT as f64);
            assert!(drow < 1e-6 || CASSINI_HEIGHT as f64 - drow < 1e-6);
        }
        // Centre row (theta = 0) centre column (phi = 0) looks forward (+x in REP 103).
        let fwd = cassini_from_dir(&Vector3::new(1.0, 0.0, 0.0), CASSINI_WIDTH, CASSINI_HEIGHT);
        assert!((fwd.col - (CASSINI_WIDTH as f64 / 2.0 - 0.5)).abs() < 1e-9);
        assert!((fwd.row - (CASSINI_HEIGHT as f64 / 2.0 - 0.5)).abs() < 1e-9);
        // Column 0 edge (phi = pi/2) looks left (+y).
        let left = cassini_from_dir(&Vector3::new(0.0, 1.0, 0.0), CASSINI_WIDTH, CASSINI_HEIGHT);
        assert!((left.col + 0.5).abs() < 1e-9);
    }

    #[test]
    fn npy_round_trip_and_errors() {
        let data: Vec<f32> = (0..12).map(|k| k as f32 * 0.5 - 1.0).collect();
        let bytes = write_npy(&[3, 4], &data);
        assert_eq!((bytes.len() - data.len() * 4) % NPY_ALIGN_BYTES, 0);
        let arr = parse_npy(&bytes).unwrap();
        assert_eq!(arr.shape, vec![3, 4]);
        assert_eq!(arr.data, data);
        assert!(parse_npy(b"not an npy file").is_err());
        let truncated = &bytes[..bytes.len() - 4];
        assert!(parse_npy(truncated).unwrap_err().contains("truncated"));
    }

    #[test]
    fn splits_stamps_and_range_convention() {
        for (text, split) in [
            ("train", Deep360Split::Training),
            ("validation", Deep360Split::Validation),
            ("test", Deep360Split::Testing),
        ] {
            assert_eq!(text.parse::<Deep360Split>().unwrap(), split);
        }
        assert!("bogus"
            .parse::<Deep360Split>()
            .unwrap_err()
            .contains("train, val or test"));
        let id = |episode, frame| Deep360FrameId { episode, frame };
        assert_eq!(id(2, 42).stamp_ns(), 204_200_000_000);
        assert!(id(1, 499).stamp_ns() < id(2, 0).stamp_ns());
        assert_eq!(id(3, 7).to_string(), "episode 3 frame 000007");
        let mut r = FloatImage {
            width: 6,
            height: 1,
            data: vec![5.0, 1e6, f32::INFINITY, f32::NAN, 0.0, -2.0],
        };
        clamp_range_to_max(&mut r, DEEP360_MAX_DEPTH_M);
        assert_eq!(&r.data[..3], &[5.0, 1000.0, 1000.0]);
        assert!(r.data[3..].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn deep360_rig_matches_dataset_positions() {
        let rig = deep360_rig().unwrap();
        let o1 = rig.camera_origin(0);
        let expected_d = [
            [0.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0],
            [-1.0, 0.0, -1.0],
        ];
        for (k, e) in expected_d.iter().enumerate() {
            let rep = rep_from_dataset(&Vector3::new(e[0], e[1], e[2]));
            assert!(
                (rig.camera_origin(k) - o1 - rep).norm() < 1e-9,
                "camera {}",
                k + 1
            );
        }
    }
}
