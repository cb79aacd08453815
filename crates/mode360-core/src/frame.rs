//! In-memory frames shared by the renderer, the bags and the estimators.

/// An 8-bit RGB panorama (row-major, 3 bytes a pixel).
pub type RgbImage = image::RgbImage;

/// A single-channel float image, row-major: range in metres (NaN where invalid), or a
/// confidence in [0, 1].
#[derive(Clone, Debug, PartialEq)]
pub struct FloatImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl FloatImage {
    /// An image filled with `value`.
    pub fn filled(width: usize, height: usize, value: f32) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    pub fn get(&self, u: usize, v: usize) -> f32 {
        self.data[v * self.width + u]
    }
}

/// What a ground-truth pixel of the output frame shows (the renderer's classes; the byte
/// values are those of the `/ground_truth/classes` image, docs/ground_truth.md).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[repr(u8)]
pub enum SurfaceClass {
    /// Nothing within the maximum range.
    #[default]
    Sky = 0,
    /// The ground surface (road, sidewalk, grass, floor).
    Ground = 1,
    /// Buildings and other large fixed structure behind the obstacles.
    Structure = 2,
    /// One object of the scene (a pole, a car, a person, a random object): an obstacle.
    Object = 3,
}

impl SurfaceClass {
    /// The class of byte `value`, `None` for a value no class has.
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Sky),
            1 => Some(Self::Ground),
            2 => Some(Self::Structure),
            3 => Some(Self::Object),
            _ => None,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Sky => "sky",
            Self::Ground => "ground",
            Self::Structure => "structure",
            Self::Object => "object",
        }
    }
}

/// Instance id of every pixel that is not an object.
pub const NO_INSTANCE: u16 = 0;

/// Per-pixel ground-truth labels of the output frame (row-major, the size of the
/// ground-truth range image): each pixel's [`SurfaceClass`] and, for objects, the id of the
/// object instance it belongs to ([`NO_INSTANCE`] elsewhere). An instance's class is the
/// class of its pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneLabels {
    pub width: usize,
    pub height: usize,
    pub class: Vec<SurfaceClass>,
    pub instance: Vec<u16>,
}

impl SceneLabels {
    /// Labels of a `width` x `height` image that is all sky.
    pub fn sky(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            class: vec![SurfaceClass::Sky; width * height],
            instance: vec![NO_INSTANCE; width * height],
        }
    }

    /// Whether both planes hold `width * height` values.
    pub fn is_consistent(&self) -> bool {
        let n = self.width * self.height;
        self.class.len() == n && self.instance.len() == n
    }
}

/// One synchronized rig frame: one panorama per camera (rig order), all with the same stamp,
/// and, for synthetic data, the ground-truth range image of the output frame.
#[derive(Clone, Debug)]
pub struct RigFrame {
    /// Header stamp of every image, nanoseconds since the epoch.
    pub stamp_ns: u64,
    pub images: Vec<RgbImage>,
    pub ground_truth: Option<FloatImage>,
    /// Synthetic data only: what each ground-truth pixel shows (`None` when the source has no
    /// labels; the obstacle metrics are then not available).
    pub labels: Option<SceneLabels>,
}
