//! The rig YAML: read into a [`Rig`] (validated by [`Rig::new`]) and written back, with errors
//! that name the file, the camera and the field.
//!
//! ```yaml
//! rig_frame: base_link            # optional, default base_link
//! reference_camera: cam1          # optional, default: the first camera
//! output:                         # optional: the frame depth is published in
//!   frame_id: cam1_link           #   default: the reference camera's frame_id
//!   rig_from_output: {...}        #   default: the reference camera's pose
//! cameras:
//!   - name: cam1
//!     topic: /cam1/image_raw
//!     frame_id: cam1_link
//!     projection: equirectangular     # or double_sphere, kannala_brandt, eucm, dual_fisheye
//!     rig_from_cam:
//!       translation: [0.5, 0.5, 1.8]     # metres
//!       rotation_xyzw: [0, 0, 0, 1]      # or rotation_rpy: [roll, pitch, yaw] in radians
//! ```
//!
//! The frames are described in [`crate::geometry::rig`]; the fisheye fields (`image_size`,
//! `intrinsics`, `lenses`) in `projection.rs`. Before parsing, a file over
//! [`MAX_CALIBRATION_FILE_BYTES`] or nested deeper than [`MAX_FLOW_DEPTH`] is refused and a
//! byte-order mark is dropped (`input.rs`, shared with the calibration importers).

mod fields;
pub(crate) mod input;
mod projection;

pub use input::{MAX_CALIBRATION_FILE_BYTES, MAX_FLOW_COLLECTIONS, MAX_FLOW_DEPTH};
pub use projection::PROJECTION_NAMES;

use crate::geometry::rig::{Rig, RigCamera, RigError, RigOutput, DEFAULT_RIG_FRAME, MIN_CAMERAS};
use crate::shipped;
use fields::{non_empty, parse_pose, pose_to_raw, Ctx, RawPose};
use projection::{parse_projection, projection_to_raw, RawIntrinsics, RawLens, RawProjection};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Deserialize, Serialize, Default)]
#[serde(deny_unknown_fields)]
struct RawRig {
    rig_frame: Option<String>,
    reference_camera: Option<String>,
    output: Option<RawOutput>,
    cameras: Option<Vec<RawCamera>>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RawOutput {
    frame_id: Option<String>,
    rig_from_output: Option<RawPose>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    name: Option<String>,
    topic: Option<String>,
    frame_id: Option<String>,
    projection: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    image_size: Option<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    intrinsics: Option<RawIntrinsics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    lenses: Option<Vec<RawLens>>,
    rig_from_cam: Option<RawPose>,
}

impl Rig {
    /// Reads and validates a rig YAML file.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, RigError> {
        let path = path.as_ref();
        let file = path.display().to_string();
        let text = input::read_calibration(path).map_err(|e| match e {
            input::ReadError::Io(source) => RigError::Io {
                file: file.clone(),
                source,
            },
            input::ReadError::Refused(problem) => RigError::Input {
                file: file.clone(),
                problem,
            },
        })?;
        Self::from_yaml_str(&text, &file)
    }

    /// [`Self::from_file`] of `path` located as [`crate::shipped`] says: a shipped rig such as
    /// `launch_configs/rig_deep360.yaml` is found from any folder, also by a binary installed
    /// or copied without its source tree.
    pub fn from_file_or_shipped(path: impl AsRef<Path>) -> Result<Self, RigError> {
        Self::from_file(shipped::locate_path(path.as_ref(), shipped::LAUNCH_CONFIGS))
    }

    /// Parses and validates rig YAML; `source_name` names the text in errors. A leading
    /// byte-order mark is dropped; text over the size limit or nested too deep is refused
    /// before parsing.
    pub fn from_yaml_str(text: &str, source_name: &str) -> Result<Self, RigError> {
        let text = input::strip_bom(text);
        input::check_yaml(text).map_err(|problem| RigError::Input {
            file: source_name.to_string(),
            problem,
        })?;
        let raw: RawRig = serde_yaml::from_str(text).map_err(|e| RigError::Yaml {
            file: source_name.to_string(),
            message: input::yaml_error(text, &e),
        })?;
        let top = Ctx {
            file: source_name,
            camera: None,
        };
        let raw_cams = raw
            .cameras
            .as_ref()
            .ok_or_else(|| top.err("cameras", "missing"))?;
        if raw_cams.len() < MIN_CAMERAS {
            return Err(top.err(
                "cameras",
                format!(
                    "a rig needs at least {MIN_CAMERAS} cameras, found {}",
                    raw_cams.len()
                ),
            ));
        }
        let cameras = raw_cams
            .iter()
            .enumerate()
            .map(|(i, rc)| {
                let label = rc.name.clone().unwrap_or_else(|| format!("#{}", i + 1));
                parse_camera(
                    &Ctx {
                        file: source_name,
                        camera: Some(&label),
                    },
                    rc,
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        let reference = match &raw.reference_camera {
            None => 0,
            Some(r) => cameras
                .iter()
                .position(|c| &c.name == r)
                .ok_or_else(|| top.err("reference_camera", format!("no camera named '{r}'")))?,
        };
        let rig_frame = match &raw.rig_frame {
            None => DEFAULT_RIG_FRAME.to_string(),
            some => non_empty(&top, "rig_frame", some)?,
        };
        let output = match &raw.output {
            None => None,
            Some(o) => Some(RigOutput {
                frame_id: match &o.frame_id {
                    None => cameras[reference].frame_id.clone(),
                    some => non_empty(&top, "output.frame_id", some)?,
                },
                rig_from_output: match &o.rig_from_output {
                    None => cameras[reference].rig_from_cam,
                    Some(p) => parse_pose(&top, "output.rig_from_output", p)?,
                },
            }),
        };
        Rig::new(rig_frame, cameras, reference, output).map_err(|e| e.in_source(source_name))
    }

    /// Serializes the rig back to YAML (the form [`Self::from_yaml_str`] reads).
    pub fn to_yaml(&self) -> String {
        let pose = pose_to_raw;
        let raw = RawRig {
            rig_frame: Some(self.rig_frame.clone()),
            reference_camera: Some(self.cameras[self.reference].name.clone()),
            output: Some(RawOutput {
                frame_id: Some(self.output_frame_id.clone()),
                rig_from_output: Some(pose(&self.rig_from_output)),
            }),
            cameras: Some(
                self.cameras
                    .iter()
                    .map(|c| {
                        let p = projection_to_raw(&c.projection);
                        RawCamera {
                            name: Some(c.name.clone()),
                            topic: Some(c.topic.clone()),
                            frame_id: Some(c.frame_id.clone()),
                            projection: Some(p.projection),
                            image_size: p.image_size,
                            intrinsics: p.intrinsics,
                            lenses: p.lenses,
                            rig_from_cam: Some(pose(&c.rig_from_cam)),
                        }
                    })
                    .collect(),
            ),
        };
        serde_yaml::to_string(&raw).unwrap_or_default()
    }
}

/// One camera's fields: present, non-empty, its projection and pose parsed (uniqueness is
/// [`Rig::new`]'s check).
fn parse_camera(ctx: &Ctx, rc: &RawCamera) -> Result<RigCamera, RigError> {
    let name = non_empty(ctx, "name", &rc.name)?;
    let topic = non_empty(ctx, "topic", &rc.topic)?;
    let frame_id = non_empty(ctx, "frame_id", &rc.frame_id)?;
    let projection = parse_projection(
        ctx,
        &RawProjection {
            projection: rc.projection.as_deref(),
            image_size: rc.image_size.as_deref(),
            intrinsics: rc.intrinsics.as_ref(),
            lenses: rc.lenses.as_deref(),
        },
    )?;
    let pose = rc
        .rig_from_cam
        .as_ref()
        .ok_or_else(|| ctx.err("rig_from_cam", "missing"))?;
    let rig_from_cam = parse_pose(ctx, "rig_from_cam", pose)?;
    Ok(RigCamera {
        name,
        topic,
        frame_id,
        projection,
        rig_from_cam,
    })
}
