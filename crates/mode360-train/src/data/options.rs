//! The options of a sample stream: [`StreamOptions`] (seed, soiling, Deep360 rig share,
//! camera effects) and the scene mix it carries ([`SceneMix`]), both `mode360 train`'s
//! command-line options under the `cli` feature.

use super::super::rig_layouts::RigLayouts;
use mode360_synth::StreetStyle;

/// Default of [`StreamOptions::seed`].
pub const DEFAULT_STREAM_SEED: u64 = 1;
/// Default of [`StreamOptions::soiled_fraction`].
pub const DEFAULT_SOILED_FRACTION: f64 = 0.3;
/// Default of [`StreamOptions::deep360_fraction`].
pub const DEFAULT_DEEP360_RIG_FRACTION: f64 = 0.25;

/// The options of a sample stream, shared by both of `mode360 train`'s stages (they are its
/// command-line options under the `cli` feature) and carried by [`DataConfig`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct StreamOptions {
    /// Data seed.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_STREAM_SEED))]
    pub seed: u64,
    /// Fraction of samples with lens soiling.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = DEFAULT_SOILED_FRACTION))]
    pub soiled_fraction: f64,
    /// Fraction of rendered street and object samples on the Deep360 rig (the rest on random
    /// roof racks of 2 to 5 cameras).
    #[cfg_attr(
        feature = "cli",
        arg(long = "deep360-rig-fraction", value_name = "FRACTION", default_value_t = DEFAULT_DEEP360_RIG_FRACTION)
    )]
    pub deep360_fraction: f64,
    /// Give every rendered camera image a real camera's effects: exposure, white balance,
    /// vignetting, blur, sensor noise and JPEG compression, drawn per camera from the sample's
    /// world seed and frame.
    #[cfg_attr(feature = "cli", arg(long))]
    pub camera_effects: bool,
    /// What the rendered samples hold.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub mix: SceneMix,
}

impl Default for StreamOptions {
    fn default() -> Self {
        Self {
            seed: DEFAULT_STREAM_SEED,
            soiled_fraction: DEFAULT_SOILED_FRACTION,
            deep360_fraction: DEFAULT_DEEP360_RIG_FRACTION,
            camera_effects: false,
            mix: SceneMix::default(),
        }
    }
}

/// What the rendered samples of a stream hold beyond their seed and size. Part of
/// [`StreamOptions`] (so of [`super::options::TrainOptions`] and `mode360 train`'s options,
/// which are these fields), carried by [`DataConfig`], saved in every checkpoint
/// ([`super::checkpoint::CheckpointState`]) and compared on resume; a field missing from an
/// older checkpoint reads as its default (none, regular streets, roof racks, a new rig every
/// sample).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct SceneMix {
    /// Fraction of rendered samples that are random-objects scenes (1: pretraining for
    /// matching; the rest are streets).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub objects_fraction: f64,
    /// Layout variation of the training streets.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = StreetStyle::Regular))]
    pub street: StreetStyle,
    /// Fraction of rendered samples on random fisheye and dual-fisheye rigs (drawn from its own
    /// stream, so a stream without them is unchanged).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub fisheye_fraction: f64,
    /// Layouts of the random rigs: roof (horizontal roof racks, the stream of older runs) or
    /// any (also vertical masts, turned cameras at mixed heights, cameras on the car body's
    /// corners; 2 to 5 cameras), drawn from its own stream.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = RigLayouts::Roof))]
    pub rig_layouts: RigLayouts,
    /// Fraction of rendered samples where one random camera's lens is 5 to 40 % blocked (mud,
    /// a mount or a vehicle part; drawn from its own stream, so a stream without them is
    /// unchanged).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub blocked_fraction: f64,
    /// Draw random rigs from a pool of this many, renewed every 25 samples per rig, so that
    /// their sweep tables are reused (0: a new rig every sample, the stream of older runs).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub rig_pool: usize,
    /// PSMODE's stage 1: train on one camera pair of each sample's rig, seen in the pair's GEER
    /// frame (two cameras turned into the pair frame, range from the left camera), drawn at
    /// the pooled rig's index so that a pooled rig is always the same pair.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub camera_pairs: bool,
}
