//! The geometry check as a bag rewrite (design.md, "The geometry check"): a copy of a rig bag
//! in which every camera topic carries the reference camera's image of the same stamp. Each
//! message keeps its own camera's topic and header (stamp, frame_id); ground truth, the rig,
//! `/tf_static` and the metadata records are copied unchanged. Evaluating or replaying the
//! copy with the node's pipeline shows what an estimator makes of a rig without parallax.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{BagError, RigBagReader, RigBagWriter, RIG_METADATA, SYNTH_METADATA};
use mode360_core::frame::RigFrame;

/// Metadata record the rewrite adds: `source` (input bag) and `reference_camera` (name).
pub const SAME_IMAGE_METADATA: &str = "mode360.same_image";

/// What [`write_same_image_bag`] wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SameImageSummary {
    pub frames: usize,
    /// Name of the camera whose image every camera now carries.
    pub reference_camera: String,
    pub output: PathBuf,
}

/// Writes the same-image copy of the rig bag `input` to `output`. Camera images are written
/// as rgb8 (the reference camera's pixels, whatever its encoding was); topics other than the
/// rig's cameras, ground truth and `/tf_static` are not copied.
pub fn write_same_image_bag(
    input: impl AsRef<Path>,
    output: impl AsRef<Path>,
) -> Result<SameImageSummary, BagError> {
    let (input, output) = (input.as_ref(), output.as_ref());
    let same_file = match (input.canonicalize(), output.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if same_file {
        return Err(BagError::Io {
            file: output.display().to_string(),
            action: "is the input bag",
            source: std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "choose another output file",
            ),
        });
    }
    let reader = RigBagReader::open(input)?;
    let rig = reader.rig().clone();
    let reference = rig.reference;
    let reference_camera = rig.cameras[reference].name.clone();
    let mut writer = RigBagWriter::create(output, &rig, &reader.info())?;
    for name in reader.bag().metadata_names() {
        if name != RIG_METADATA && name != SYNTH_METADATA {
            let entries = reader.bag().metadata(&name).unwrap_or_default();
            writer.bag_mut().write_metadata(&name, entries)?;
        }
    }
    writer.bag_mut().write_metadata(
        SAME_IMAGE_METADATA,
        BTreeMap::from([
            ("source".to_string(), input.display().to_string()),
            ("reference_camera".to_string(), reference_camera.clone()),
        ]),
    )?;
    let mut frames = 0;
    for frame in reader.frames() {
        let frame = frame?;
        let image = frame.images[reference].clone();
        writer.write_frame(&RigFrame {
            stamp_ns: frame.stamp_ns,
            images: vec![image; frame.images.len()],
            ground_truth: frame.ground_truth,
            labels: frame.labels,
        })?;
        frames += 1;
    }
    writer.finish()?;
    Ok(SameImageSummary {
        frames,
        reference_camera,
        output: output.to_path_buf(),
    })
}
