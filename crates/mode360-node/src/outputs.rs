//! The node's outputs in one table: each output's topic (relative to the namespace) and message
//! type. The worker publishes, `replay` writes and the live view logs a group's outputs by
//! walking [`Output::ALL`], so a new output is one entry here, its message built in the
//! pipeline ([`crate::pipeline::PipelineOutput::message`]) and its line in the README's
//! topic table.

use mode360_io::msgs::{CompressedImage, Image, PointCloud2};
use std::ops::{Index, IndexMut};

/// Relative topic of the range image.
pub const DEPTH_TOPIC: &str = "depth";
/// Relative topic of the range image in image_transport's compressedDepth format.
pub const COMPRESSED_DEPTH_TOPIC: &str = "depth/compressedDepth";
/// Relative topic of the point cloud.
pub const POINTS_TOPIC: &str = "points";
/// Relative topic of the confidence image.
pub const CONFIDENCE_TOPIC: &str = "confidence";

/// One of the node's outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Output {
    /// The ERP range image, 32FC1 metres.
    Depth,
    /// The range image in image_transport's compressedDepth format (only while subscribed).
    CompressedDepth,
    /// Valid, non-sky pixels as coloured points (only while subscribed).
    Points,
    /// Per-pixel confidence, 32FC1 in [0, 1] (the `publish_confidence` parameter).
    Confidence,
}

/// The ROS 2 message type an output is sent as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputType {
    /// `sensor_msgs/msg/Image`.
    Image,
    /// `sensor_msgs/msg/CompressedImage`.
    CompressedImage,
    /// `sensor_msgs/msg/PointCloud2`.
    PointCloud,
}

/// Number of outputs.
const OUTPUT_COUNT: usize = 4;

impl Output {
    /// Every output, in the order a group's messages go out.
    pub const ALL: [Output; OUTPUT_COUNT] = [
        Output::Depth,
        Output::CompressedDepth,
        Output::Points,
        Output::Confidence,
    ];

    /// The topic, relative to the node's namespace (before remapping).
    pub fn topic(self) -> &'static str {
        match self {
            Output::Depth => DEPTH_TOPIC,
            Output::CompressedDepth => COMPRESSED_DEPTH_TOPIC,
            Output::Points => POINTS_TOPIC,
            Output::Confidence => CONFIDENCE_TOPIC,
        }
    }

    /// The message type it is sent as.
    pub fn message_type(self) -> OutputType {
        match self {
            Output::Depth | Output::Confidence => OutputType::Image,
            Output::CompressedDepth => OutputType::CompressedImage,
            Output::Points => OutputType::PointCloud,
        }
    }

    /// Position in [`Self::ALL`].
    fn index(self) -> usize {
        self as usize
    }
}

/// One output's message of a group.
#[derive(Clone, Copy)]
pub enum OutputMessage<'a> {
    Image(&'a Image),
    CompressedImage(&'a CompressedImage),
    PointCloud(&'a PointCloud2),
}

/// One output's message of a group, owned: what a publisher sends.
pub enum OutputData {
    Image(Image),
    CompressedImage(CompressedImage),
    PointCloud(PointCloud2),
}

/// One value per output (its publisher, channel or topic name), indexed by [`Output`].
#[derive(Clone, Debug, PartialEq)]
pub struct PerOutput<T>([T; OUTPUT_COUNT]);

impl<T> PerOutput<T> {
    /// `f(output)` for every output.
    pub fn new(mut f: impl FnMut(Output) -> T) -> Self {
        Self(Output::ALL.map(&mut f))
    }

    /// The same, for a fallible `f`: the first error.
    pub fn try_new<E>(mut f: impl FnMut(Output) -> Result<T, E>) -> Result<Self, E> {
        let mut values = Vec::with_capacity(OUTPUT_COUNT);
        for o in Output::ALL {
            values.push(f(o)?);
        }
        match values.try_into() {
            Ok(array) => Ok(Self(array)),
            Err(_) => unreachable!("one value per output"),
        }
    }

    /// Every output with its value.
    pub fn iter(&self) -> impl Iterator<Item = (Output, &T)> {
        Output::ALL.into_iter().zip(self.0.iter())
    }
}

impl<T> Index<Output> for PerOutput<T> {
    type Output = T;
    fn index(&self, o: Output) -> &T {
        &self.0[o.index()]
    }
}

impl<T> IndexMut<Output> for PerOutput<T> {
    fn index_mut(&mut self, o: Output) -> &mut T {
        &mut self.0[o.index()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_indexes_each_output_once() {
        let topics = PerOutput::new(Output::topic);
        for (k, o) in Output::ALL.into_iter().enumerate() {
            assert_eq!(o.index(), k);
            assert_eq!(topics[o], o.topic());
        }
        let names: std::collections::BTreeSet<_> = Output::ALL.map(Output::topic).into();
        assert_eq!(names.len(), Output::ALL.len());
        let failed: Result<PerOutput<()>, &str> = PerOutput::try_new(|o| {
            if o == Output::Points {
                Err("points")
            } else {
                Ok(())
            }
        });
        assert_eq!(failed, Err("points"));
    }
}
