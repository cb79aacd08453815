//! On-the-fly training data: synthetic street frames rendered for randomized rigs.
//!
//! Sample `k` of a stream with seed `s` is a pure function of `(s, k)`: the world seed, the
//! frame index along the street, the rig and the soiling all come from
//! `Rng::new(&[s, k, SAMPLE_TAG])`. The data "RNG position" of a training run is therefore
//! just the index of the next sample, which makes resuming exact.
//!
//! Rigs (flexibility goal): with probability [`StreamOptions::deep360_fraction`] the paper's Deep360 rig,
//! otherwise a random roof rack: `2..=5` cameras placed uniformly in a
//! `RACK_HALF_SIZE_M`-square around the rig origin (at least `MIN_CAMERA_SEPARATION_M`
//! apart), heights in `[MIN_HEIGHT_M, MAX_HEIGHT_M]`, small random roll/pitch/yaw per camera.
//! Camera 1 is the reference and output frame, so the ground truth is camera 1's range.
//! With probability [`SceneMix::fisheye_fraction`] (its own stream) the rig is a random
//! fisheye or dual-fisheye rack instead ([`super::fisheye_rigs`]), whose images enter the
//! network as panoramas of their own frames ([`RigRemap`]) and whose depth is in `rack_center`.
//! With [`SceneMix::rig_layouts`] `any`, a random rig that is neither Deep360 nor fisheye
//! takes a layout family drawn from its own stream `Rng::new(&[s, k, LAYOUT_TAG])` (roof rack,
//! vertical mast, turned cameras at mixed heights, car body corners: [`super::rig_layouts`]);
//! `roof` (the default) keeps every such rig a roof rack, exactly the stream of older runs.
//!
//! Blocked lenses: with probability [`SceneMix::blocked_fraction`] (its own stream
//! `Rng::new(&[s, k, BLOCKER_TAG])`) one random camera of a rendered sample gets a blocker
//! ([`mode360_synth::blockers`]: mud, a mount or a vehicle part, kind uniform) over a fraction
//! of its view drawn in `[MIN_TRAIN_BLOCKED_FRACTION, MAX_TRAIN_BLOCKED_FRACTION]`. The ground
//! truth stays the scene's range: the network learns to range through the other cameras.
//!
//! Deep360 on disk (fine-tuning): with [`DataConfig::deep360_disk`] set, sample `k` is, with
//! probability [`Deep360Mix::fraction`], a frame of the dataset's training split read from
//! disk instead of a rendered one. That choice and the frame (an index into the sorted list of
//! frames and image sets, clean and soiled) come from a separate stream
//! `Rng::new(&[s, k, DEEP360_DISK_TAG])`, so samples stay a pure function of `(s, k)` and the
//! synthetic samples of a stream do not change when a dataset is added.
//!
//! Scenes: with probability [`DataConfig::objects_fraction`] a sample is a random-objects scene
//! (textured primitives at random distances all around the rig, which no single panorama can
//! range: pretraining for matching), otherwise a street in [`DataConfig::street`]'s style. The
//! choice comes from its own stream `Rng::new(&[s, k, SCENE_TAG])`, so a stream's street
//! samples do not depend on it.
//!
//! Training world seeds have the top bit clear, validation world seeds have it set, so the
//! held-out set never shares a world with training.

use super::camera_effects::apply_camera_effects;
use super::fisheye_rigs::random_fisheye_rig;
use super::rack::random_rig;
use super::rig_layouts::{draw_family, layout_rig, LayoutFamily, RigLayouts};
use super::rig_pool::pooled_rig_index;
use candle_core::{Device, Tensor};
use mode360_core::frame::{FloatImage, RgbImage, SceneLabels};
use mode360_core::geometry::panorama::RigRemap;
use mode360_core::geometry::{CameraPair, ErpGrid, PairView, Rig, RigError};
use mode360_io::deep360::{
    clamp_range_to_max, deep360_rig, Deep360Dataset, Deep360Error, Deep360FrameId,
    Deep360FrameVariant, Deep360Split,
};
use mode360_model::model::{input_tensor, ModelError};
use mode360_synth::noise::{hash_words, Rng};
use mode360_synth::{
    BlockedLens, BlockerKind, SceneKind, StreetStyle, SynthConfig, SynthError, SynthRenderer,
};
use std::path::{Path, PathBuf};

mod options;
mod stream;
#[cfg(test)]
mod tests;

pub use options::{
    SceneMix, StreamOptions, DEFAULT_DEEP360_RIG_FRACTION, DEFAULT_SOILED_FRACTION,
    DEFAULT_STREAM_SEED,
};
pub use stream::{IndexedSample, SampleStream};

/// Frames along the street a sample may be taken from.
pub const STREET_FRAMES: usize = 400;
/// Domain-separation words for the sample and world seeds.
const SAMPLE_TAG: u64 = 0x7A41_0001;
const VALIDATION_TAG: u64 = 0x7A41_0002;
const DEEP360_DISK_TAG: u64 = 0x7A41_0003;
const SCENE_TAG: u64 = 0x7A41_0004;
const FISHEYE_TAG: u64 = 0x7A41_0005;
const BLOCKER_TAG: u64 = 0x7A41_0007;
/// The random rig seed of a pooled rig index.
const RIG_SEED_TAG: u64 = 0x7A41_0008;
/// The camera pair of a pooled rig index (PSMODE stage 1).
const PAIR_TAG: u64 = 0x7A41_0009;
/// Range of the view fraction a training blocker covers.
pub const MIN_TRAIN_BLOCKED_FRACTION: f64 = 0.05;
pub const MAX_TRAIN_BLOCKED_FRACTION: f64 = 0.40;
/// Set in validation world seeds, clear in training world seeds.
const VALIDATION_SEED_BIT: u64 = 1 << 63;

/// Errors producing training data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("training data: renderer: {0}")]
    Synth(#[from] SynthError),
    #[error("training data: rig: {0}")]
    Rig(#[from] RigError),
    #[error("training data: tensor: {0}")]
    Tensor(#[from] candle_core::Error),
    #[error("training data: network input: {0}")]
    Input(#[from] ModelError),
    #[error("training data: {0}")]
    Config(String),
    #[error("training data: {0}")]
    Deep360(#[from] Deep360Error),
}

/// How samples are drawn: the stream's options ([`StreamOptions`], which `mode360 train`
/// takes as they are) and the size and range the network trains at.
#[derive(Clone, Debug, PartialEq)]
pub struct DataConfig {
    /// Seed, soiling, rigs and scene mix of the stream.
    pub stream: StreamOptions,
    /// ERP width of the images and ground truth; height is `width / 2`.
    pub width: usize,
    /// Sky / clamp range of the ground truth, metres.
    pub max_depth_m: f64,
    /// Deep360 training frames from disk mixed into the stream (fine-tuning).
    pub deep360_disk: Option<Deep360Mix>,
}

/// The paper's Deep360 dataset on disk as a source of training samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Deep360Mix {
    /// Directory holding the `ep*_500frames` folders.
    pub root: PathBuf,
    /// Probability that a training sample is a Deep360 frame.
    pub fraction: f64,
    /// The training split's frames with each image set on disk (clean, soiled), sorted,
    /// listed once so that a sample picks by index.
    pub frames: Vec<Deep360FrameVariant>,
}

impl Deep360Mix {
    /// Lists the training split under `root`; an error if it holds no frames.
    pub fn open(root: impl AsRef<Path>, fraction: f64) -> Result<Self, DataError> {
        let ds = Deep360Dataset::open(root.as_ref())?;
        let frames = ds.frame_variants(Deep360Split::Training)?;
        let mix = Self {
            root: ds.root().to_path_buf(),
            fraction,
            frames,
        };
        mix.validate()?;
        Ok(mix)
    }

    fn validate(&self) -> Result<(), DataError> {
        if !(0.0..=1.0).contains(&self.fraction) {
            return Err(DataError::Config(format!(
                "Deep360 fraction must be in [0, 1], got {}",
                self.fraction
            )));
        }
        if self.frames.is_empty() {
            return Err(DataError::Config(format!(
                "no Deep360 training frames under {} (looked for \
                 ep*_500frames/training/depth/*_depth.npz with rgb/ or rgb_soiled/)",
                self.root.display()
            )));
        }
        Ok(())
    }

    /// The frame training sample `index` of stream `seed` reads, or `None` for a rendered one.
    pub fn pick(&self, seed: u64, index: u64) -> Option<Deep360FrameVariant> {
        let mut rng = Rng::new(&[seed, index, DEEP360_DISK_TAG]);
        if self.frames.is_empty() || !rng.chance(self.fraction) {
            return None;
        }
        Some(self.frames[rng.index(self.frames.len())])
    }
}

impl DataConfig {
    fn validate(&self) -> Result<(), DataError> {
        for (name, v) in [
            ("soiled_fraction", self.stream.soiled_fraction),
            ("deep360_fraction", self.stream.deep360_fraction),
            ("objects_fraction", self.stream.mix.objects_fraction),
            ("fisheye_fraction", self.stream.mix.fisheye_fraction),
            ("blocked_fraction", self.stream.mix.blocked_fraction),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(DataError::Config(format!(
                    "field '{name}' must be in [0, 1], got {v}"
                )));
            }
        }
        self.deep360_disk
            .as_ref()
            .map_or(Ok(()), Deep360Mix::validate)
    }
}

/// Which rig a sample uses.
#[derive(Clone, Debug, PartialEq)]
pub enum RigChoice {
    Deep360,
    /// A random roof rack ([`random_rig`]), a function of this seed.
    Random(u64),
    /// A random rig of this layout family ([`layout_rig`]; never the roof rack, which stays
    /// [`RigChoice::Random`]), a function of the family and this seed.
    Layout(LayoutFamily, u64),
    /// A random fisheye or dual-fisheye rig ([`random_fisheye_rig`]), a function of this seed
    /// and the ERP width.
    Fisheye(u64),
}

/// Everything that determines one sample.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleSpec {
    pub world_seed: u64,
    pub frame_index: usize,
    pub soiled: bool,
    pub rig: RigChoice,
    /// `Some`: the sample is this Deep360 training frame read from disk (rig Deep360,
    /// `soiled` picks `rgb_soiled/`); `world_seed` and `frame_index` are then unused.
    pub deep360_frame: Option<Deep360FrameId>,
    /// What is rendered (ignored for Deep360 frames from disk).
    pub scene: SceneKind,
    /// Street layout variation (street scenes).
    pub street: StreetStyle,
    /// A blocked lens (rendered samples).
    pub blocker: Option<SampleBlocker>,
    /// `Some`: the sample is pair `pick % pairs` of [`CameraPair::all`] of its rig, in the
    /// pair's GEER frame ([`SceneMix::camera_pairs`]; rendered samples).
    pub pair_pick: Option<u64>,
}

/// A training sample's blocked lens; the camera is picked once the rig is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleBlocker {
    /// The camera is `camera_pick % cameras`.
    pub camera_pick: u64,
    pub fraction: f64,
    pub kind: BlockerKind,
}

impl SampleBlocker {
    /// The blocker on a rig of `cameras` cameras.
    pub fn on_rig(&self, cameras: usize) -> BlockedLens {
        BlockedLens {
            camera: (self.camera_pick % cameras.max(1) as u64) as usize,
            fraction: self.fraction,
            kind: self.kind,
        }
    }
}

/// One rendered sample.
#[derive(Clone, Debug)]
pub struct TrainSample {
    pub spec: SampleSpec,
    pub rig: Rig,
    /// Per camera (rig order): `(1, H, W, 3)` f32 in `[0, 1]` on the CPU.
    pub images: Vec<Tensor>,
    /// Ground-truth range of the output frame (camera 1), metres; sky = `max_depth_m`.
    pub range_m: FloatImage,
    /// What each ground-truth pixel shows (rendered samples; `None` for Deep360).
    pub labels: Option<SceneLabels>,
}

/// The spec of training sample `index` of the stream `cfg.stream.seed`.
pub fn training_spec(cfg: &DataConfig, index: u64) -> SampleSpec {
    let mut rng = Rng::new(&[cfg.stream.seed, index, SAMPLE_TAG]);
    let world_seed = rng.next_u64() & !VALIDATION_SEED_BIT;
    let frame_index = rng.index(STREET_FRAMES);
    let soiled = rng.chance(cfg.stream.soiled_fraction);
    // With a rig pool, every rig draw is taken at the pooled rig's index (super::rig_pool).
    let rig_index = match cfg.stream.mix.rig_pool {
        0 => index,
        rigs => pooled_rig_index(cfg.stream.seed, index, rigs),
    };
    let rig = if rng.chance(cfg.stream.deep360_fraction) {
        RigChoice::Deep360
    } else {
        let own = rng.next_u64();
        RigChoice::Random(match cfg.stream.mix.rig_pool {
            0 => own,
            _ => Rng::new(&[cfg.stream.seed, rig_index, RIG_SEED_TAG]).next_u64(),
        })
    };
    let rig = match (cfg.stream.mix.rig_layouts, rig) {
        (RigLayouts::Any, RigChoice::Random(seed)) => match draw_family(cfg.stream.seed, rig_index)
        {
            LayoutFamily::RoofRack => RigChoice::Random(seed),
            family => RigChoice::Layout(family, seed),
        },
        (_, rig) => rig,
    };
    let mut fisheye = Rng::new(&[cfg.stream.seed, rig_index, FISHEYE_TAG]);
    let rig = if cfg.stream.mix.fisheye_fraction > 0.0
        && fisheye.chance(cfg.stream.mix.fisheye_fraction)
    {
        RigChoice::Fisheye(fisheye.next_u64())
    } else {
        rig
    };
    let scene =
        if Rng::new(&[cfg.stream.seed, index, SCENE_TAG]).chance(cfg.stream.mix.objects_fraction) {
            SceneKind::Objects
        } else {
            SceneKind::Street
        };
    let mut blocker = Rng::new(&[cfg.stream.seed, index, BLOCKER_TAG]);
    let blocker = (cfg.stream.mix.blocked_fraction > 0.0
        && blocker.chance(cfg.stream.mix.blocked_fraction))
    .then(|| SampleBlocker {
        camera_pick: blocker.next_u64(),
        fraction: blocker.range(MIN_TRAIN_BLOCKED_FRACTION, MAX_TRAIN_BLOCKED_FRACTION),
        kind: BlockerKind::ALL[blocker.index(BlockerKind::ALL.len())],
    });
    let pair_pick = cfg
        .stream
        .mix
        .camera_pairs
        .then(|| Rng::new(&[cfg.stream.seed, rig_index, PAIR_TAG]).next_u64());
    let spec = SampleSpec {
        world_seed,
        frame_index,
        soiled,
        rig,
        deep360_frame: None,
        scene,
        street: cfg.stream.mix.street,
        blocker,
        pair_pick,
    };
    match cfg
        .deep360_disk
        .as_ref()
        .and_then(|m| m.pick(cfg.stream.seed, index))
    {
        Some(v) => SampleSpec {
            soiled: v.soiled,
            rig: RigChoice::Deep360,
            deep360_frame: Some(v.id),
            blocker: None,
            pair_pick: None,
            ..spec
        },
        None => spec,
    }
}

/// The held-out validation set: `count` frames on the Deep360 rig from worlds training never
/// uses, alternating clean and soiled. Independent of the training seed.
pub fn validation_specs(count: usize) -> Vec<SampleSpec> {
    (0..count as u64)
        .map(|k| {
            let mut rng = Rng::new(&[k, VALIDATION_TAG]);
            SampleSpec {
                world_seed: rng.next_u64() | VALIDATION_SEED_BIT,
                frame_index: rng.index(STREET_FRAMES),
                soiled: k % 2 == 1,
                rig: RigChoice::Deep360,
                deep360_frame: None,
                scene: SceneKind::Street,
                street: StreetStyle::Regular,
                blocker: None,
                pair_pick: None,
            }
        })
        .collect()
}

/// `(1, H, W, 3)` f32 tensor in `[0, 1]` from an 8-bit image at its own width (see
/// [`input_tensor`], which every path into the network shares).
pub fn image_tensor(img: &RgbImage) -> Result<Tensor, ModelError> {
    input_tensor(img, img.width() as usize, &Device::Cpu)
}

/// A rendered sample before it becomes tensors: the cameras' images as panoramas of their own
/// frames (fisheye images resampled, as at inference).
#[derive(Clone, Debug)]
pub struct RenderedSample {
    pub rig: Rig,
    /// Per camera (rig order), at `cfg.width`.
    pub panoramas: Vec<RgbImage>,
    /// Ground-truth range of the output frame, metres; sky = `max_depth_m`.
    pub range_m: FloatImage,
    pub labels: Option<SceneLabels>,
}

/// Renders the sample `spec` at `cfg.width` (or reads it from disk, see
/// [`SampleSpec::deep360_frame`]).
pub fn render_sample(cfg: &DataConfig, spec: &SampleSpec) -> Result<TrainSample, DataError> {
    if let Some(id) = spec.deep360_frame {
        return load_deep360_sample(cfg, spec, id);
    }
    let r = render_panoramas(cfg, spec)?;
    let images = r
        .panoramas
        .iter()
        .map(image_tensor)
        .collect::<Result<Vec<_>, _>>()?;
    Ok(TrainSample {
        spec: spec.clone(),
        rig: r.rig,
        images,
        range_m: r.range_m,
        labels: r.labels,
    })
}

/// Renders the sample `spec` (a rendered one: not a Deep360 frame from disk) at `cfg.width`,
/// its images as panoramas.
pub fn render_panoramas(cfg: &DataConfig, spec: &SampleSpec) -> Result<RenderedSample, DataError> {
    let rig = sample_rig(cfg, spec)?;
    let renderer = SynthRenderer::new(SynthConfig {
        seed: spec.world_seed,
        width: cfg.width,
        soiled: spec.soiled,
        max_depth_m: cfg.max_depth_m,
        scene: spec.scene,
        street: spec.street,
        blockers: spec
            .blocker
            .map(|b| b.on_rig(rig.cameras.len()))
            .into_iter()
            .collect(),
        ..SynthConfig::default()
    })?;
    let mut frame = renderer.render_frame(&rig, spec.frame_index);
    if cfg.stream.camera_effects {
        apply_camera_effects(&mut frame.images, spec.world_seed, spec.frame_index as u64);
    }
    // Fisheye images enter the network as panoramas of their own frame, as at inference.
    let remap = RigRemap::new(
        &rig,
        ErpGrid::new(cfg.width).map_err(|e| DataError::Config(e.to_string()))?,
    );
    let panoramas = remap
        .panoramas(&frame.images)
        .map_err(|(camera, e)| DataError::Config(format!("camera {camera}: {e}")))?
        .into_iter()
        .map(std::borrow::Cow::into_owned)
        .collect();
    let range_m = frame.ground_truth.ok_or_else(|| {
        DataError::Config("renderer returned no ground truth for the output frame".into())
    })?;
    Ok(RenderedSample {
        rig,
        panoramas,
        range_m,
        labels: frame.labels,
    })
}

/// The rig a rendered sample is taken on (its pair rig for a camera-pair sample).
pub fn sample_rig(cfg: &DataConfig, spec: &SampleSpec) -> Result<Rig, DataError> {
    let rig = match spec.rig {
        RigChoice::Deep360 => deep360_rig()?,
        RigChoice::Random(seed) => random_rig(seed)?,
        RigChoice::Layout(family, seed) => layout_rig(family, seed)?,
        RigChoice::Fisheye(seed) => random_fisheye_rig(seed, cfg.width)?,
    };
    match spec.pair_pick {
        Some(pick) => pair_rig(&rig, pick),
        None => Ok(rig),
    }
}

/// Pair `pick % pairs` of `rig` ([`CameraPair::all`]) as a two-camera rig in its GEER frame.
pub fn pair_rig(rig: &Rig, pick: u64) -> Result<Rig, DataError> {
    let pairs = CameraPair::all(rig.cameras.len());
    let pair = pairs
        .get((pick % pairs.len().max(1) as u64) as usize)
        .copied()
        .ok_or_else(|| DataError::Config("a camera pair needs a rig of two cameras".into()))?;
    let view = PairView::new(rig, pair).map_err(|e| DataError::Config(e.to_string()))?;
    Ok(view.pair_rig().clone())
}

/// Reads Deep360 training frame `id` at `cfg.width`, sky and far range clamped to
/// `cfg.max_depth_m` like rendered ground truth.
fn load_deep360_sample(
    cfg: &DataConfig,
    spec: &SampleSpec,
    id: Deep360FrameId,
) -> Result<TrainSample, DataError> {
    let mix = cfg.deep360_disk.as_ref().ok_or_else(|| {
        DataError::Config(format!(
            "sample names Deep360 {id} but no Deep360 root is configured"
        ))
    })?;
    let ds = Deep360Dataset::open(&mix.root)?;
    let frame = ds.load_frame(id, Deep360Split::Training, spec.soiled, cfg.width)?;
    let mut range_m = frame
        .ground_truth
        .ok_or_else(|| DataError::Config(format!("Deep360 {id} has no ground-truth range")))?;
    clamp_range_to_max(&mut range_m, cfg.max_depth_m);
    let images = frame
        .images
        .iter()
        .map(image_tensor)
        .collect::<Result<Vec<_>, _>>()?;
    Ok(TrainSample {
        spec: spec.clone(),
        rig: ds.rig().clone(),
        images,
        range_m,
        labels: None,
    })
}

/// Training sample `index` of the stream.
pub fn training_sample(cfg: &DataConfig, index: u64) -> Result<TrainSample, DataError> {
    cfg.validate()?;
    render_sample(cfg, &training_spec(cfg, index))
}

/// A stable 64-bit fingerprint of a sample's content (images and ground truth), for tests
/// and logs.
pub fn sample_fingerprint(sample: &TrainSample) -> Result<u64, candle_core::Error> {
    let mut words = vec![sample.images.len() as u64];
    for t in &sample.images {
        let v: Vec<f32> = t.flatten_all()?.to_vec1()?;
        words.push(hash_words(
            &v.iter().map(|x| u64::from(x.to_bits())).collect::<Vec<_>>(),
        ));
    }
    words.push(hash_words(
        &sample
            .range_m
            .data
            .iter()
            .map(|x| u64::from(x.to_bits()))
            .collect::<Vec<_>>(),
    ));
    Ok(hash_words(&words))
}
