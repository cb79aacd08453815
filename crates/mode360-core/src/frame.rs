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

/// One synchronized rig frame: one panorama per camera (rig order), all with the same stamp,
/// and, for synthetic data, the ground-truth range image of the output frame.
#[derive(Clone, Debug)]
pub struct RigFrame {
    /// Header stamp of every image, nanoseconds since the epoch.
    pub stamp_ns: u64,
    pub images: Vec<RgbImage>,
    pub ground_truth: Option<FloatImage>,
}
