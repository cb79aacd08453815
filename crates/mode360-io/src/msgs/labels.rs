//! Ground-truth labels ([`SceneLabels`]) as two `sensor_msgs/Image` messages of the output
//! frame (docs/ground_truth.md):
//!
//! - classes, `8UC1`: one byte per pixel, the [`SurfaceClass`] value (0 sky, 1 ground,
//!   2 structure, 3 object);
//! - instances, `16UC1` little endian: the object instance id, 0 where the pixel is not an
//!   object.

use super::image::{check_layout, dim_u32, encodings, ImageMsgError};
use super::types::{Header, Image};
use mode360_core::frame::{SceneLabels, SurfaceClass, NO_INSTANCE};

/// Bytes of one instance id.
const INSTANCE_BYTES: usize = std::mem::size_of::<u16>();

/// Labels that cannot be read from their messages.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LabelMsgError {
    #[error("{plane}: {source}")]
    Image {
        plane: &'static str,
        source: ImageMsgError,
    },
    #[error("classes are {classes_w}x{classes_h} but instances are {instances_w}x{instances_h}")]
    SizeMismatch {
        classes_w: u32,
        classes_h: u32,
        instances_w: u32,
        instances_h: u32,
    },
    #[error("classes: pixel ({u}, {v}) holds {value}, which is no class (0 sky, 1 ground, 2 structure, 3 object)")]
    UnknownClass { u: usize, v: usize, value: u8 },
    #[error("instances: pixel ({u}, {v}) has instance {id} but class {class} (only objects have instances)")]
    InstanceOutsideObject {
        u: usize,
        v: usize,
        id: u16,
        class: &'static str,
    },
}

/// The classes (`8UC1`) and instances (`16UC1`, little endian) messages of `labels`.
pub fn label_image_msgs(header: &Header, labels: &SceneLabels) -> (Image, Image) {
    let classes = Image {
        header: header.clone(),
        height: dim_u32(labels.height),
        width: dim_u32(labels.width),
        encoding: encodings::TYPE_8UC1.to_string(),
        is_bigendian: 0,
        step: dim_u32(labels.width),
        data: labels.class.iter().map(|c| *c as u8).collect(),
    };
    let instances = Image {
        header: header.clone(),
        height: dim_u32(labels.height),
        width: dim_u32(labels.width),
        encoding: encodings::TYPE_16UC1.to_string(),
        is_bigendian: 0,
        step: dim_u32(labels.width.saturating_mul(INSTANCE_BYTES)),
        data: labels
            .instance
            .iter()
            .flat_map(|i| i.to_le_bytes())
            .collect(),
    };
    (classes, instances)
}

fn expect_encoding(
    msg: &Image,
    plane: &'static str,
    expected: &'static str,
) -> Result<(), LabelMsgError> {
    if msg.encoding == expected {
        return Ok(());
    }
    Err(LabelMsgError::Image {
        plane,
        source: ImageMsgError::UnsupportedEncoding {
            encoding: msg.encoding.clone(),
            expected,
        },
    })
}

/// The labels of a classes and an instances message (row padding honoured, either byte
/// order for the instances). Every class byte must name a class and only object pixels may
/// carry an instance.
pub fn labels_from_image_msgs(
    classes: &Image,
    instances: &Image,
) -> Result<SceneLabels, LabelMsgError> {
    expect_encoding(classes, "classes", encodings::TYPE_8UC1)?;
    expect_encoding(instances, "instances", encodings::TYPE_16UC1)?;
    check_layout(classes, 1).map_err(|source| LabelMsgError::Image {
        plane: "classes",
        source,
    })?;
    check_layout(instances, INSTANCE_BYTES).map_err(|source| LabelMsgError::Image {
        plane: "instances",
        source,
    })?;
    if (classes.width, classes.height) != (instances.width, instances.height) {
        return Err(LabelMsgError::SizeMismatch {
            classes_w: classes.width,
            classes_h: classes.height,
            instances_w: instances.width,
            instances_h: instances.height,
        });
    }
    let (width, height) = (classes.width as usize, classes.height as usize);
    let mut labels = SceneLabels {
        width,
        height,
        class: Vec::with_capacity(width * height),
        instance: Vec::with_capacity(width * height),
    };
    let big_endian = instances.is_bigendian != 0;
    let class_rows = classes.data.chunks(classes.step.max(1) as usize);
    let instance_rows = instances.data.chunks(instances.step.max(1) as usize);
    for (v, (class_row, instance_row)) in class_rows.zip(instance_rows).take(height).enumerate() {
        let ids = instance_row[..width * INSTANCE_BYTES].chunks_exact(INSTANCE_BYTES);
        for (u, (&value, id)) in class_row[..width].iter().zip(ids).enumerate() {
            let class =
                SurfaceClass::from_u8(value).ok_or(LabelMsgError::UnknownClass { u, v, value })?;
            let raw = [id[0], id[1]];
            let id = if big_endian {
                u16::from_be_bytes(raw)
            } else {
                u16::from_le_bytes(raw)
            };
            if id != NO_INSTANCE && class != SurfaceClass::Object {
                return Err(LabelMsgError::InstanceOutsideObject {
                    u,
                    v,
                    id,
                    class: class.as_str(),
                });
            }
            labels.class.push(class);
            labels.instance.push(id);
        }
    }
    Ok(labels)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels() -> SceneLabels {
        let mut l = SceneLabels::sky(4, 2);
        l.class = [0u8, 1, 2, 3, 3, 3, 1, 0]
            .iter()
            .map(|&c| SurfaceClass::from_u8(c).unwrap())
            .collect();
        l.instance = vec![0, 0, 0, 7, 300, 7, 0, 0];
        l
    }

    #[test]
    fn bytes_are_as_documented() {
        let (classes, instances) = label_image_msgs(&Header::new(5, "base_link"), &labels());
        assert_eq!(classes.encoding, "8UC1");
        assert_eq!(classes.step, 4);
        assert_eq!(classes.data, vec![0, 1, 2, 3, 3, 3, 1, 0]);
        assert_eq!(instances.encoding, "16UC1");
        assert_eq!(instances.step, 8);
        // 300 = 0x012c, little endian.
        assert_eq!(&instances.data[6..10], &[7, 0, 0x2c, 0x01]);
        assert_eq!(
            labels_from_image_msgs(&classes, &instances).unwrap(),
            labels()
        );
    }

    #[test]
    fn padded_big_endian_rows_read_back() {
        let (mut classes, _) = label_image_msgs(&Header::new(5, "base_link"), &labels());
        classes.step = 6;
        classes.data = vec![0, 1, 2, 3, 9, 9, 3, 3, 1, 0, 9, 9];
        let instances = Image {
            encoding: "16UC1".into(),
            is_bigendian: 1,
            step: 8,
            data: vec![0, 0, 0, 0, 0, 0, 0, 7, 0x01, 0x2c, 0, 7, 0, 0, 0, 0],
            ..classes.clone()
        };
        assert_eq!(
            labels_from_image_msgs(&classes, &instances).unwrap(),
            labels()
        );
    }

    #[test]
    fn bad_labels_name_the_plane_and_pixel() {
        let (mut classes, mut instances) =
            label_image_msgs(&Header::new(5, "base_link"), &labels());
        instances.data[0] = 1;
        let err = labels_from_image_msgs(&classes, &instances).unwrap_err();
        assert!(
            err.to_string()
                .contains("pixel (0, 0) has instance 1 but class sky"),
            "{err}"
        );
        instances.data[0] = 0;
        classes.data[7] = 4;
        let err = labels_from_image_msgs(&classes, &instances).unwrap_err();
        assert!(err.to_string().contains("pixel (3, 1) holds 4"), "{err}");
        classes.encoding = "mono16".into();
        let err = labels_from_image_msgs(&classes, &instances).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("classes: unsupported encoding 'mono16'"),
            "{err}"
        );
        classes.encoding = "8UC1".into();
        classes.data.pop();
        let err = labels_from_image_msgs(&classes, &instances).unwrap_err();
        assert!(err.to_string().contains("truncated"), "{err}");
    }
}
