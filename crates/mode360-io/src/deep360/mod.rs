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
//! Conversion to ERP: for each ERP pixel, `dir_rep` (see [`mode360_core::geometry::erp`]) is rotated
//! into `D`, then `phi = asin(x_D)`, `theta = atan2(y_D, z_D)`, and the Cassini image is
//! sampled at `j = (pi/2 - phi) W / pi - 0.5`, `i = (pi - theta) H / (2 pi) - 0.5`, bilinearly
//! for colour (rows wrap around theta = +-pi, columns clamp at the poles phi = +-pi/2) and
//! nearest-neighbour for range (no blending across depth edges).
//!
//! Files: this one holds the dataset (splits, frame ids, loading); [`cassini`] the projection
//! and the resampling both ways; `npy` the `.npy`/`.npz` reader and writer; `error` the errors.

pub mod cassini;
mod error;
mod npy;

pub use cassini::{
    cassini_dir, cassini_from_dir, cassini_to_erp_range, cassini_to_erp_rgb, dataset_from_rep,
    erp_to_cassini_range, erp_to_cassini_rgb, rep_from_dataset, CassiniCoord, CASSINI_HEIGHT,
    CASSINI_WIDTH,
};
pub use error::Deep360Error;
pub use npy::{parse_npy, read_npz_array, write_npy, write_npz, NpyArray};

use mode360_core::frame::{FloatImage, RgbImage, RigFrame};
use mode360_core::geometry::{ErpGrid, Rig, RigError};
use std::path::{Path, PathBuf};

/// The Deep360 rig in REP 103 (same as `launch_configs/rig_deep360.yaml`).
pub const DEEP360_RIG_YAML: &str = include_str!("../../../../launch_configs/rig_deep360.yaml");
/// Number of cameras of the Deep360 rig.
pub const DEEP360_CAMERAS: usize = 4;
/// Key of the range array inside the depth `.npz`.
pub const DEPTH_NPZ_KEY: &str = "arr_0";
/// Deep360 frames are 10 Hz apart; see [`Deep360FrameId::stamp_ns`].
pub const FRAME_PERIOD_NS: u64 = 100_000_000;
/// Frame slots per episode in the stamp scheme: frame `k` of episode `e` is stamped
/// `(e * EPISODE_FRAME_SLOTS + k) * FRAME_PERIOD_NS` (episodes hold 500 frames).
pub const EPISODE_FRAME_SLOTS: u64 = 1000;
/// Largest range of the dataset's ground truth (the paper's maximum depth), metres.
pub const DEEP360_MAX_DEPTH_M: f64 = mode360_core::geometry::DEFAULT_MAX_DEPTH_M;
/// Number of episodes in the dataset.
pub const EPISODES: u32 = 6;

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
            labels: None,
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

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
