//! The synthetic-frame bag layout (design.md, "Data the whole project shares"):
//!
//! - metadata record [`RIG_METADATA`] with key `yaml`: the rig calibration YAML;
//! - metadata record [`SYNTH_METADATA`]: free-form information about how the data was made;
//! - `/tf_static` (`tf2_msgs/TFMessage`): `rig_frame <- camera frame` for every camera, and
//!   `rig_frame <- output frame` when the output frame is not a camera frame;
//! - per frame, one `sensor_msgs/Image` rgb8 per camera on that camera's topic, all stamped
//!   with the frame stamp (also their log time): an ERP panorama (2:1, one size for all
//!   panorama cameras) or, for a fisheye or dual-fisheye camera, the raw image at exactly its
//!   `image_size` (both the writer and the reader refuse other sizes); and optionally the ground-truth range on
//!   [`GROUND_TRUTH_TOPIC`] (32FC1, ERP, frame `rig.output_frame_id`), and with it optionally
//!   the labels of the same pixels: [`GROUND_TRUTH_CLASSES_TOPIC`] (8UC1) and
//!   [`GROUND_TRUTH_INSTANCES_TOPIC`] (16UC1), always both (`crate::msgs::labels`).

use std::collections::BTreeMap;
use std::path::Path;

use super::{BagError, BagMessage, BagReader, BagWriteOptions, BagWriter};
use crate::msgs::{
    float_from_image_msg, image_msg_from_float, image_msg_from_rgb, label_image_msgs,
    labels_from_image_msgs, rgb_from_compressed, rgb_from_image_msg, CompressedImage, Header,
    Image, RosMessage, TFMessage, Transform, TransformStamped,
};
use mode360_core::frame::{FloatImage, RgbImage, RigFrame, SceneLabels};
use mode360_core::geometry::rig::Rig;

/// Metadata record holding the rig YAML under key [`RIG_YAML_KEY`].
pub const RIG_METADATA: &str = "mode360.rig";
/// Key of the rig YAML in [`RIG_METADATA`].
pub const RIG_YAML_KEY: &str = "yaml";
/// Metadata record describing how synthetic data was generated.
pub const SYNTH_METADATA: &str = "mode360.synth";
/// Key in [`SYNTH_METADATA`] (and Deep360 bags' metadata) that marks soiled frames (`true`).
pub const SOILED_KEY: &str = "soiled";
/// Key in [`SYNTH_METADATA`] holding the scene's maximum depth (the sky's range), metres.
pub const MAX_DEPTH_KEY: &str = "max_depth_m";
/// Maximum depth assumed when a bag does not record [`MAX_DEPTH_KEY`], metres.
pub use mode360_core::geometry::DEFAULT_MAX_DEPTH_M;
/// Topic of the ground-truth range image.
pub const GROUND_TRUTH_TOPIC: &str = "/ground_truth/depth";
/// Topic of the ground truth's surface class per pixel (8UC1).
pub const GROUND_TRUTH_CLASSES_TOPIC: &str = "/ground_truth/classes";
/// Topic of the ground truth's object instance id per pixel (16UC1).
pub const GROUND_TRUTH_INSTANCES_TOPIC: &str = "/ground_truth/instances";
pub use super::format::TF_STATIC_TOPIC;
/// Stamp (and log time) of the `/tf_static` message, written before any frame.
const TF_STATIC_STAMP_NS: u64 = 0;

/// Just the header of an image message (its first field), decoded without the pixels.
#[derive(serde::Deserialize, serde::Serialize)]
struct HeaderPrefix {
    header: Header,
}

impl RosMessage for HeaderPrefix {
    const TYPE_NAME: &'static str = "std_msgs/msg/Header";
}

/// Writes synthetic rig frames into a bag.
pub struct RigBagWriter {
    bag: BagWriter,
    rig: Rig,
}

impl RigBagWriter {
    /// Creates the bag, writes the rig and `info` metadata and `/tf_static`.
    pub fn create(
        path: impl AsRef<Path>,
        rig: &Rig,
        info: &BTreeMap<String, String>,
    ) -> Result<Self, BagError> {
        Self::create_with(path, rig, info, BagWriteOptions::default())
    }

    /// [`Self::create`] with bag writing options (compression, chunk size).
    pub fn create_with(
        path: impl AsRef<Path>,
        rig: &Rig,
        info: &BTreeMap<String, String>,
        options: BagWriteOptions,
    ) -> Result<Self, BagError> {
        let mut bag = BagWriter::create_with(path, options)?;
        bag.write_metadata(
            RIG_METADATA,
            BTreeMap::from([(RIG_YAML_KEY.to_string(), rig.to_yaml())]),
        )?;
        bag.write_metadata(SYNTH_METADATA, info.clone())?;
        bag.write(TF_STATIC_TOPIC, TF_STATIC_STAMP_NS, &rig_tf_static(rig))?;
        Ok(Self {
            bag,
            rig: rig.clone(),
        })
    }

    /// The underlying bag, e.g. to add other topics.
    pub fn bag_mut(&mut self) -> &mut BagWriter {
        &mut self.bag
    }

    /// Writes one image per camera (rig order) and the ground truth, if any.
    pub fn write_frame(&mut self, frame: &RigFrame) -> Result<(), BagError> {
        let file = self.bag.file().to_string();
        if frame.images.len() != self.rig.cameras.len() {
            return Err(BagError::Frame {
                file,
                topic: self
                    .rig
                    .cameras
                    .get(frame.images.len())
                    .map_or_else(String::new, |c| c.topic.clone()),
                stamp_ns: frame.stamp_ns,
                field: "images".into(),
                problem: format!(
                    "frame has {} images but the rig has {} cameras",
                    frame.images.len(),
                    self.rig.cameras.len()
                ),
            });
        }
        for (camera, image) in self.rig.cameras.iter().zip(&frame.images) {
            if let Err(e) = camera
                .projection
                .check_image_size(image.width(), image.height())
            {
                return Err(BagError::Frame {
                    file,
                    topic: camera.topic.clone(),
                    stamp_ns: frame.stamp_ns,
                    field: "width/height".into(),
                    problem: format!("camera '{}': {e}", camera.name),
                });
            }
        }
        for (camera, image) in self.rig.cameras.iter().zip(&frame.images) {
            let msg = image_msg_from_rgb(Header::new(frame.stamp_ns, &camera.frame_id), image);
            self.bag.write(&camera.topic, frame.stamp_ns, &msg)?;
        }
        if let Some(gt) = &frame.ground_truth {
            if gt.data.len() != gt.width * gt.height {
                return Err(BagError::Frame {
                    file,
                    topic: GROUND_TRUTH_TOPIC.into(),
                    stamp_ns: frame.stamp_ns,
                    field: "ground_truth.data".into(),
                    problem: format!(
                        "{} values for a {}x{} image",
                        gt.data.len(),
                        gt.width,
                        gt.height
                    ),
                });
            }
            let header = Header::new(frame.stamp_ns, &self.rig.output_frame_id);
            let msg = image_msg_from_float(header.clone(), gt);
            self.bag.write(GROUND_TRUTH_TOPIC, frame.stamp_ns, &msg)?;
            if let Some(labels) = &frame.labels {
                if !labels.is_consistent() || (labels.width, labels.height) != (gt.width, gt.height)
                {
                    return Err(BagError::Frame {
                        file,
                        topic: GROUND_TRUTH_INSTANCES_TOPIC.into(),
                        stamp_ns: frame.stamp_ns,
                        field: "labels".into(),
                        problem: format!(
                            "labels of {}x{} ({} classes, {} instances) for a {}x{} ground truth",
                            labels.width,
                            labels.height,
                            labels.class.len(),
                            labels.instance.len(),
                            gt.width,
                            gt.height
                        ),
                    });
                }
                let (classes, instances) = label_image_msgs(&header, labels);
                self.bag
                    .write(GROUND_TRUTH_CLASSES_TOPIC, frame.stamp_ns, &classes)?;
                self.bag
                    .write(GROUND_TRUTH_INSTANCES_TOPIC, frame.stamp_ns, &instances)?;
            }
        }
        Ok(())
    }

    /// Finishes the bag (summary and footer).
    pub fn finish(self) -> Result<(), BagError> {
        self.bag.finish()
    }
}

/// `/tf_static` of `rig`: `rig_frame <- camera` for each camera, plus `rig_frame <- output`
/// when the output frame is not a camera's.
pub fn rig_tf_static(rig: &Rig) -> TFMessage {
    rig_tf_static_at(rig, TF_STATIC_STAMP_NS)
}

/// [`rig_tf_static`] with every transform stamped `stamp_ns` (the node stamps its
/// `/tf_static` with the time it starts).
pub fn rig_tf_static_at(rig: &Rig, stamp_ns: u64) -> TFMessage {
    let stamped = |child: &str, rig_from_child| TransformStamped {
        header: Header::new(stamp_ns, &rig.rig_frame),
        child_frame_id: child.to_string(),
        transform: Transform::from_isometry(rig_from_child),
    };
    let mut transforms: Vec<TransformStamped> = rig
        .cameras
        .iter()
        .map(|c| stamped(&c.frame_id, &c.rig_from_cam))
        .collect();
    if !rig
        .cameras
        .iter()
        .any(|c| c.frame_id == rig.output_frame_id)
    {
        transforms.push(stamped(&rig.output_frame_id, &rig.rig_from_output));
    }
    TFMessage { transforms }
}

/// Reads synthetic rig frames back from a bag.
pub struct RigBagReader {
    bag: BagReader,
    rig: Rig,
    info: BTreeMap<String, String>,
}

/// The messages of one stamp.
struct FrameSlots<'a> {
    images: Vec<Option<BagMessage<'a>>>,
    ground_truth: Option<BagMessage<'a>>,
    classes: Option<BagMessage<'a>>,
    instances: Option<BagMessage<'a>>,
}

impl RigBagReader {
    /// Opens the bag and takes the rig from its [`RIG_METADATA`] record.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let bag = BagReader::open(path)?;
        let file = bag.file().to_string();
        let yaml = bag
            .metadata(RIG_METADATA)
            .and_then(|m| m.get(RIG_YAML_KEY).cloned())
            .ok_or_else(|| match bag.damage() {
                Some(damage) => damage,
                None => BagError::MissingMetadata {
                    file: file.clone(),
                    name: RIG_METADATA.into(),
                    key: RIG_YAML_KEY.into(),
                },
            })?;
        let source_name = format!("{file} (metadata '{RIG_METADATA}')");
        let rig = Rig::from_yaml_str(&yaml, &source_name)
            .map_err(|source| BagError::Rig { file, source })?;
        Ok(Self::with_rig(bag, rig))
    }

    /// Opens the bag but uses `rig` instead of the one stored in it.
    pub fn open_with_rig(path: impl AsRef<Path>, rig: Rig) -> Result<Self, BagError> {
        Ok(Self::with_rig(BagReader::open(path)?, rig))
    }

    fn with_rig(bag: BagReader, rig: Rig) -> Self {
        let info = bag.metadata(SYNTH_METADATA).unwrap_or_default();
        Self { bag, rig, info }
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The [`SYNTH_METADATA`] record (empty if the bag has none).
    pub fn info(&self) -> BTreeMap<String, String> {
        self.info.clone()
    }

    /// The ground truth's sky / clamp range from the [`MAX_DEPTH_KEY`] metadata:
    /// [`DEFAULT_MAX_DEPTH_M`] when the bag does not say, an error naming the value when it is
    /// not a positive number.
    pub fn max_depth_m(&self) -> Result<f64, BagError> {
        let Some(text) = self.info.get(MAX_DEPTH_KEY) else {
            return Ok(DEFAULT_MAX_DEPTH_M);
        };
        text.parse::<f64>()
            .ok()
            .filter(|m| m.is_finite() && *m > 0.0)
            .ok_or_else(|| BagError::BadMetadata {
                file: self.bag.file().to_string(),
                key: MAX_DEPTH_KEY.to_string(),
                value: text.clone(),
                expected: "positive number",
            })
    }

    /// The underlying bag.
    pub fn bag(&self) -> &BagReader {
        &self.bag
    }

    fn frame_err(&self, topic: &str, stamp_ns: u64, field: &str, problem: String) -> BagError {
        BagError::Frame {
            file: self.bag.file().to_string(),
            topic: topic.to_string(),
            stamp_ns,
            field: field.to_string(),
            problem,
        }
    }

    /// Groups camera images and ground truth by header stamp. A message whose header cannot
    /// be read, or a second message of a topic at the same stamp, is dropped and returned
    /// with the groups; a camera topic without any message is an error (no frame can be
    /// built).
    fn group<'a>(&'a self) -> Result<(BTreeMap<u64, FrameSlots<'a>>, Vec<BagError>), BagError> {
        let n_cameras = self.rig.cameras.len();
        let mut frames: BTreeMap<u64, FrameSlots<'a>> = BTreeMap::new();
        let mut dropped = Vec::new();
        for (index, camera) in self.rig.cameras.iter().enumerate() {
            let mut any = false;
            for msg in self.bag.messages_on(&camera.topic) {
                any = true;
                let stamp_ns = match message_stamp(&msg) {
                    Ok(stamp_ns) => stamp_ns,
                    Err(err) => {
                        dropped.push(err);
                        continue;
                    }
                };
                let slots = frames.entry(stamp_ns).or_insert_with(|| FrameSlots {
                    images: vec![None; n_cameras],
                    ground_truth: None,
                    classes: None,
                    instances: None,
                });
                if slots.images[index].is_some() {
                    dropped.push(self.frame_err(
                        &camera.topic,
                        stamp_ns,
                        "header.stamp",
                        "two images with the same stamp (the second is dropped)".into(),
                    ));
                } else {
                    slots.images[index] = Some(msg);
                }
            }
            if !any {
                // In a damaged bag the topic may just be lost after the damage: say both.
                return Err(match self.bag.damage_detail() {
                    Some(detail) => BagError::Damaged {
                        file: self.bag.file().to_string(),
                        detail: format!(
                            "{detail}; topic '{}' has no messages before the damage",
                            camera.topic
                        ),
                        good_messages: self.bag.message_count(),
                    },
                    None => BagError::MissingTopic {
                        file: self.bag.file().to_string(),
                        topic: camera.topic.clone(),
                    },
                });
            }
        }
        type Slot<'a> = for<'s> fn(&'s mut FrameSlots<'a>) -> &'s mut Option<BagMessage<'a>>;
        let ground_truth_slots: [(&str, Slot<'a>); 3] = [
            (GROUND_TRUTH_TOPIC, |s| &mut s.ground_truth),
            (GROUND_TRUTH_CLASSES_TOPIC, |s| &mut s.classes),
            (GROUND_TRUTH_INSTANCES_TOPIC, |s| &mut s.instances),
        ];
        for (topic, slot) in ground_truth_slots {
            for msg in self.bag.messages_on(topic) {
                let stamp_ns = match message_stamp(&msg) {
                    Ok(stamp_ns) => stamp_ns,
                    Err(err) => {
                        dropped.push(err);
                        continue;
                    }
                };
                let Some(slots) = frames.get_mut(&stamp_ns) else {
                    continue;
                };
                let slot = slot(slots);
                if slot.is_some() {
                    dropped.push(
                        self.frame_err(
                            topic,
                            stamp_ns,
                            "header.stamp",
                            "two ground-truth images with the same stamp (the second is dropped)"
                                .into(),
                        ),
                    );
                } else {
                    *slot = Some(msg);
                }
            }
        }
        Ok((frames, dropped))
    }

    /// Builds the frame of one stamp, checking encodings and sizes.
    fn build_frame(&self, stamp_ns: u64, slots: &FrameSlots<'_>) -> Result<RigFrame, BagError> {
        let mut images: Vec<RgbImage> = Vec::with_capacity(slots.images.len());
        for (camera, slot) in self.rig.cameras.iter().zip(&slots.images) {
            let Some(msg) = slot else {
                return Err(self.frame_err(
                    &camera.topic,
                    stamp_ns,
                    "header.stamp",
                    format!("no image from camera '{}' at this stamp", camera.name),
                ));
            };
            let image = decode_camera_image(msg, stamp_ns)?;
            if let Err(e) = camera
                .projection
                .check_image_size(image.width(), image.height())
            {
                return Err(self.frame_err(
                    &camera.topic,
                    stamp_ns,
                    "width/height",
                    format!("camera '{}': {e}", camera.name),
                ));
            }
            // Panoramas of one frame share a size (fisheye images were checked above).
            let first_erp = self
                .rig
                .cameras
                .iter()
                .zip(&images)
                .find(|(c, _)| c.projection.is_equirectangular());
            if let (true, Some((first_cam, first))) =
                (camera.projection.is_equirectangular(), first_erp)
            {
                if first.dimensions() != image.dimensions() {
                    return Err(self.frame_err(
                        &camera.topic,
                        stamp_ns,
                        "width/height",
                        format!(
                            "{}x{} differs from camera '{}' ({}x{}): the panoramas of a frame share one size",
                            image.width(),
                            image.height(),
                            first_cam.name,
                            first.width(),
                            first.height()
                        ),
                    ));
                }
            }
            images.push(image);
        }
        let ground_truth = match &slots.ground_truth {
            Some(msg) => Some(decode_ground_truth(msg, stamp_ns)?),
            None => None,
        };
        if let Some(gt) = &ground_truth {
            if gt.width != 2 * gt.height {
                return Err(self.frame_err(
                    GROUND_TRUTH_TOPIC,
                    stamp_ns,
                    "width",
                    format!(
                        "{}x{} is not an equirectangular image (width must be 2 x height)",
                        gt.width, gt.height
                    ),
                ));
            }
        }
        let labels = self.build_labels(stamp_ns, slots, ground_truth.as_ref())?;
        Ok(RigFrame {
            stamp_ns,
            images,
            ground_truth,
            labels,
        })
    }

    /// The labels of one stamp: both label images or neither, the ground truth's size.
    fn build_labels(
        &self,
        stamp_ns: u64,
        slots: &FrameSlots<'_>,
        ground_truth: Option<&FloatImage>,
    ) -> Result<Option<SceneLabels>, BagError> {
        let (classes, instances) = match (&slots.classes, &slots.instances) {
            (None, None) => return Ok(None),
            (Some(c), Some(i)) => (c, i),
            (Some(_), None) | (None, Some(_)) => {
                let missing = if slots.classes.is_none() {
                    GROUND_TRUTH_CLASSES_TOPIC
                } else {
                    GROUND_TRUTH_INSTANCES_TOPIC
                };
                return Err(self.frame_err(
                    missing,
                    stamp_ns,
                    "header.stamp",
                    "labels need both the classes and the instances image at a stamp".into(),
                ));
            }
        };
        let labels =
            labels_from_image_msgs(&classes.decode()?, &instances.decode()?).map_err(|e| {
                self.frame_err(
                    GROUND_TRUTH_INSTANCES_TOPIC,
                    stamp_ns,
                    "data",
                    e.to_string(),
                )
            })?;
        if let Some(gt) = ground_truth {
            if (labels.width, labels.height) != (gt.width, gt.height) {
                return Err(self.frame_err(
                    GROUND_TRUTH_INSTANCES_TOPIC,
                    stamp_ns,
                    "width/height",
                    format!(
                        "labels are {}x{} but the ground truth is {}x{}",
                        labels.width, labels.height, gt.width, gt.height
                    ),
                ));
            }
        }
        Ok(Some(labels))
    }

    /// The frames in stamp order. Each item is a frame, or an error naming the file, topic
    /// and field of something dropped: a message whose header cannot be read or that repeats
    /// a stamp (these come first), an image of the wrong encoding or size, a stamp missing a
    /// camera. Every good frame is still returned, so a reader that counts the errors and
    /// goes on loses nothing else. A camera topic without messages is a single error and no
    /// frames; a damaged bag ends with the damage error after the frames that were readable.
    pub fn frames(&self) -> impl Iterator<Item = Result<RigFrame, BagError>> + '_ {
        let (grouped, dropped, fatal) = match self.group() {
            Ok((grouped, dropped)) => (grouped, dropped, None),
            Err(err) => (BTreeMap::new(), Vec::new(), Some(err)),
        };
        let damage = if fatal.is_none() {
            self.bag.damage()
        } else {
            None
        };
        fatal
            .into_iter()
            .chain(dropped)
            .map(Err)
            .chain(
                grouped
                    .into_iter()
                    .map(move |(stamp_ns, slots)| self.build_frame(stamp_ns, &slots)),
            )
            .chain(damage.map(Err))
    }
}

/// Header stamp of an Image or CompressedImage message, in ns.
fn message_stamp(msg: &BagMessage<'_>) -> Result<u64, BagError> {
    let prefix: HeaderPrefix = if msg.schema_name == CompressedImage::TYPE_NAME {
        msg.decode_prefix::<CompressedImage, HeaderPrefix>()?
    } else {
        msg.decode_prefix::<Image, HeaderPrefix>()?
    };
    Ok(prefix.header.stamp.to_nanos())
}

fn image_err(
    msg: &BagMessage<'_>,
    stamp_ns: u64,
) -> impl FnOnce(crate::msgs::ImageMsgError) -> BagError {
    let (file, topic) = (msg.file.to_string(), msg.topic.to_string());
    move |source| BagError::Image {
        file,
        topic,
        stamp_ns,
        source,
    }
}

/// A camera image from an Image (rgb8, bgr8, rgba8, bgra8, mono8) or CompressedImage.
fn decode_camera_image(msg: &BagMessage<'_>, stamp_ns: u64) -> Result<RgbImage, BagError> {
    if msg.schema_name == CompressedImage::TYPE_NAME {
        let compressed: CompressedImage = msg.decode()?;
        rgb_from_compressed(&compressed).map_err(image_err(msg, stamp_ns))
    } else {
        let image: Image = msg.decode()?;
        rgb_from_image_msg(&image).map_err(image_err(msg, stamp_ns))
    }
}

fn decode_ground_truth(msg: &BagMessage<'_>, stamp_ns: u64) -> Result<FloatImage, BagError> {
    let image: Image = msg.decode()?;
    float_from_image_msg(&image).map_err(image_err(msg, stamp_ns))
}
