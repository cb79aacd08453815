//! Rig calibration: which 360° cameras a rig carries and where ([`Rig`], built and validated
//! by [`Rig::new`]; read from and written to YAML by [`super::rig_yaml`]).
//!
//! `rig_from_cam` maps a point in the camera frame to the rig frame: `p_rig = R p_cam + t`.
//! The camera frame depends on the projection: an equirectangular camera's frame is REP 103
//! (x at the panorama's centre column, y left, z up); a fisheye camera's frame is its lens's
//! optical frame (z along the optical axis, x right, y down in the image), as Kalibr and Basalt
//! calibrate it; a dual-fisheye camera's frame is the body frame its lenses' `cam_from_lens`
//! are given in.

mod bounds;
mod names;

pub(crate) use bounds::num;
pub use bounds::{
    check_distortion, check_focal, check_lens, check_rpy, check_translation, MAX_DISTORTION_ABS,
    MAX_FOCAL_PX, MAX_RPY_ABS_RAD, MAX_TRANSLATION_M, MIN_FOCAL_PX,
};
pub(crate) use names::quoted;
pub use names::{validate_frame_id, validate_topic_name, MAX_FRAME_ID_LEN, MAX_TOPIC_NAME_LEN};

use super::camera::{CameraModel, DualFisheye, FisheyeCamera, ImageSize, IntrinsicsError};
use super::GeometryError;
use nalgebra::{Isometry3, Vector3};
use std::collections::HashSet;

/// A quaternion whose norm differs from one by more than this is rejected.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;
/// A rig needs at least this many cameras.
pub const MIN_CAMERAS: usize = 2;
/// The rig frame when the YAML names none.
pub const DEFAULT_RIG_FRAME: &str = "base_link";
/// The source an error of [`Rig::new`] names until relabelled ([`RigError::in_source`]).
pub const UNNAMED_SOURCE: &str = "<rig>";

/// An invalid rig calibration: names the file, the camera and the field.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error("{file}: cannot read rig calibration: {source}")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: malformed YAML: {message}")]
    Yaml { file: String, message: String },
    /// A file refused before parsing (too large, nested too deep, not UTF-8).
    #[error("{file}: {problem}")]
    Input { file: String, problem: String },
    #[error("{file}: camera '{camera}': field '{field}': {problem}")]
    Camera {
        file: String,
        camera: String,
        field: String,
        problem: String,
    },
    #[error("{file}: field '{field}': {problem}")]
    Rig {
        file: String,
        field: String,
        problem: String,
    },
}

/// How a camera maps rays to pixels.
#[derive(Clone, Debug, PartialEq)]
pub enum Projection {
    /// Full-sphere equirectangular panorama, see [`super::erp`]; its size is the image's own.
    Equirectangular,
    /// One fisheye lens (double sphere, Kannala-Brandt or EUCM) and its image size.
    Fisheye(FisheyeCamera),
    /// Two fisheye lenses back to back in one image.
    DualFisheye(DualFisheye),
}

impl Projection {
    /// The name in the rig YAML (`equirectangular`, `double_sphere`, `kannala_brandt`,
    /// `eucm`, `dual_fisheye`).
    pub fn name(&self) -> &'static str {
        match self {
            Self::Equirectangular => "equirectangular",
            Self::Fisheye(c) => c.lens().name(),
            Self::DualFisheye(_) => DualFisheye::NAME,
        }
    }

    pub fn is_equirectangular(&self) -> bool {
        matches!(self, Self::Equirectangular)
    }

    /// The camera model of a fisheye projection (`None` for equirectangular, whose grid
    /// comes from the image size: see [`super::ErpGrid`]).
    pub fn fisheye_model(&self) -> Option<&(dyn CameraModel + Sync)> {
        match self {
            Self::Equirectangular => None,
            Self::Fisheye(c) => Some(c),
            Self::DualFisheye(d) => Some(d),
        }
    }
}

/// One camera of the rig.
#[derive(Clone, Debug, PartialEq)]
pub struct RigCamera {
    pub name: String,
    pub topic: String,
    pub frame_id: String,
    pub projection: Projection,
    pub rig_from_cam: Isometry3<f64>,
}

/// A validated rig calibration (build it with [`Rig::new`], which checks the invariants the
/// fields document).
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub rig_frame: String,
    pub cameras: Vec<RigCamera>,
    /// Index into `cameras` of the reference camera.
    pub reference: usize,
    /// Frame of the published depth image.
    pub output_frame_id: String,
    pub rig_from_output: Isometry3<f64>,
}

impl RigError {
    /// The same error, naming `source` (a file, or a description such as
    /// `<random rig 7>`) as where it was found.
    pub fn in_source(self, source: &str) -> Self {
        let file = source.to_string();
        match self {
            Self::Io { source, .. } => Self::Io { file, source },
            Self::Yaml { message, .. } => Self::Yaml { file, message },
            Self::Input { problem, .. } => Self::Input { file, problem },
            Self::Camera {
                camera,
                field,
                problem,
                ..
            } => Self::Camera {
                file,
                camera,
                field,
                problem,
            },
            Self::Rig { field, problem, .. } => Self::Rig {
                file,
                field,
                problem,
            },
        }
    }
}

/// Where a rig publishes depth: its frame and pose ([`Rig::new`] defaults both to the
/// reference camera's).
#[derive(Clone, Debug, PartialEq)]
pub struct RigOutput {
    pub frame_id: String,
    pub rig_from_output: Isometry3<f64>,
}

/// A pose is usable when every translation component and quaternion coefficient is finite
/// and the translation is within [`MAX_TRANSLATION_M`]; the problem otherwise.
fn check_pose(pose: &Isometry3<f64>) -> Result<(), String> {
    if !(pose.translation.vector.iter().all(|v| v.is_finite())
        && pose.rotation.coords.iter().all(|v| v.is_finite()))
    {
        return Err("pose is not finite".into());
    }
    check_translation(&pose.translation.vector)
}

/// A projection's intrinsics within the plausible bounds ([`check_lens`]), and a dual-fisheye
/// camera's lens offsets within [`MAX_TRANSLATION_M`]; the error's field is the rig YAML's
/// (`intrinsics.fx`, `lenses[1].intrinsics.k2`, `lenses[0].cam_from_lens`).
fn check_projection(p: &Projection) -> Result<(), IntrinsicsError> {
    match p {
        Projection::Equirectangular => Ok(()),
        Projection::Fisheye(c) => check_lens(c.lens()).map_err(|e| e.prefixed("intrinsics.")),
        Projection::DualFisheye(d) => {
            for (i, lens) in d.lenses().iter().enumerate() {
                check_lens(&lens.model)
                    .map_err(|e| e.prefixed(&format!("lenses[{i}].intrinsics.")))?;
                check_translation(&lens.cam_from_lens.translation.vector).map_err(|problem| {
                    IntrinsicsError::new(format!("lenses[{i}].cam_from_lens"), problem)
                })?;
            }
            Ok(())
        }
    }
}

impl Rig {
    /// A validated rig: at least [`MIN_CAMERAS`] cameras with non-empty, unique names, valid
    /// and unique ROS 2 topics ([`validate_topic_name`]) and frame ids
    /// ([`validate_frame_id`]), finite poses within [`MAX_TRANSLATION_M`] and plausible
    /// intrinsics ([`check_lens`]); `reference` indexes `cameras`; the rig frame and the
    /// output frame are valid frame ids and the output pose is finite and within bounds.
    /// `output` defaults to the reference camera's frame and pose. Errors name the camera and
    /// the field, with the source [`UNNAMED_SOURCE`] (relabel with [`RigError::in_source`]).
    pub fn new(
        rig_frame: impl Into<String>,
        cameras: Vec<RigCamera>,
        reference: usize,
        output: Option<RigOutput>,
    ) -> Result<Self, RigError> {
        let rig_err = |field: &str, problem: String| RigError::Rig {
            file: UNNAMED_SOURCE.into(),
            field: field.into(),
            problem,
        };
        let cam_err = |camera: &str, field: &str, problem: String| RigError::Camera {
            file: UNNAMED_SOURCE.into(),
            camera: camera.into(),
            field: field.into(),
            problem,
        };
        if cameras.len() < MIN_CAMERAS {
            return Err(rig_err(
                "cameras",
                format!(
                    "a rig needs at least {MIN_CAMERAS} cameras, found {}",
                    cameras.len()
                ),
            ));
        }
        let mut names = HashSet::new();
        let mut topics = HashSet::new();
        let mut frames = HashSet::new();
        for (i, cam) in cameras.iter().enumerate() {
            let label = if cam.name.trim().is_empty() {
                format!("#{}", i + 1)
            } else {
                cam.name.clone()
            };
            for (field, value) in [
                ("name", &cam.name),
                ("topic", &cam.topic),
                ("frame_id", &cam.frame_id),
            ] {
                if value.trim().is_empty() {
                    return Err(cam_err(&label, field, "empty".into()));
                }
            }
            validate_topic_name(&cam.topic).map_err(|p| cam_err(&label, "topic", p))?;
            validate_frame_id(&cam.frame_id).map_err(|p| cam_err(&label, "frame_id", p))?;
            if !names.insert(cam.name.as_str()) {
                return Err(cam_err(&label, "name", "duplicate camera name".into()));
            }
            if !topics.insert(cam.topic.as_str()) {
                let problem = format!("topic '{}' is used by another camera", cam.topic);
                return Err(cam_err(&label, "topic", problem));
            }
            if !frames.insert(cam.frame_id.as_str()) {
                let problem = format!("frame_id '{}' is used by another camera", cam.frame_id);
                return Err(cam_err(&label, "frame_id", problem));
            }
            check_pose(&cam.rig_from_cam).map_err(|p| cam_err(&label, "rig_from_cam", p))?;
            check_projection(&cam.projection).map_err(|e| cam_err(&label, &e.field, e.problem))?;
        }
        if reference >= cameras.len() {
            return Err(rig_err(
                "reference_camera",
                format!(
                    "camera {} does not exist (rig has {})",
                    reference + 1,
                    cameras.len()
                ),
            ));
        }
        let rig_frame = rig_frame.into();
        validate_frame_id(&rig_frame).map_err(|p| rig_err("rig_frame", p))?;
        let output = output.unwrap_or_else(|| RigOutput {
            frame_id: cameras[reference].frame_id.clone(),
            rig_from_output: cameras[reference].rig_from_cam,
        });
        validate_frame_id(&output.frame_id).map_err(|p| rig_err("output.frame_id", p))?;
        check_pose(&output.rig_from_output).map_err(|p| rig_err("output.rig_from_output", p))?;
        Ok(Self {
            rig_frame,
            cameras,
            reference,
            output_frame_id: output.frame_id,
            rig_from_output: output.rig_from_output,
        })
    }

    /// The rig's output frame and pose.
    pub fn output(&self) -> RigOutput {
        RigOutput {
            frame_id: self.output_frame_id.clone(),
            rig_from_output: self.rig_from_output,
        }
    }

    /// The rig restricted to the cameras at `indices` (0-based, in that order). The output
    /// frame stays where it was.
    pub fn subset(&self, indices: &[usize]) -> Result<Self, RigError> {
        let err = |problem: String| RigError::Rig {
            file: "<subset>".into(),
            field: "cameras".into(),
            problem,
        };
        if indices.len() < MIN_CAMERAS {
            return Err(err(format!(
                "a rig needs at least {MIN_CAMERAS} cameras, {} selected",
                indices.len()
            )));
        }
        let mut cameras = Vec::with_capacity(indices.len());
        for &i in indices {
            let cam = self.cameras.get(i).ok_or_else(|| {
                err(format!(
                    "camera {} does not exist (rig has {})",
                    i + 1,
                    self.cameras.len()
                ))
            })?;
            if cameras.iter().any(|c: &RigCamera| c.name == cam.name) {
                return Err(err(format!("camera {} selected twice", i + 1)));
            }
            cameras.push(cam.clone());
        }
        let reference = indices
            .iter()
            .position(|&i| i == self.reference)
            .unwrap_or(0);
        Self::new(
            self.rig_frame.clone(),
            cameras,
            reference,
            Some(self.output()),
        )
        .map_err(|e| e.in_source("<subset>"))
    }

    /// The rig with every fisheye and dual-fisheye camera at `factor` times its resolution
    /// (0.5: half the width and height; intrinsics scaled to match, see
    /// [`FisheyeCamera::scaled`]); equirectangular cameras, poses and the output frame stay.
    /// For rendering and training at a lower resolution than the calibration's.
    pub fn scaled(&self, factor: f64) -> Result<Self, RigError> {
        let mut rig = self.clone();
        for cam in &mut rig.cameras {
            let scaled = match &cam.projection {
                Projection::Equirectangular => continue,
                Projection::Fisheye(c) => c.scaled(factor).map(Projection::Fisheye),
                Projection::DualFisheye(d) => d.scaled(factor).map(Projection::DualFisheye),
            };
            cam.projection = scaled.map_err(|e| RigError::Camera {
                file: format!("<rig scaled by {factor}>"),
                camera: cam.name.clone(),
                field: e.field,
                problem: e.problem,
            })?;
        }
        Ok(rig)
    }

    /// `Ok` when every camera is equirectangular; otherwise an error naming the first camera
    /// that is not and `consumer`, the part of the project that handles only panoramas.
    pub fn require_equirectangular(&self, consumer: &'static str) -> Result<(), GeometryError> {
        match self
            .cameras
            .iter()
            .find(|c| !c.projection.is_equirectangular())
        {
            None => Ok(()),
            Some(c) => Err(GeometryError::UnsupportedProjection {
                camera: c.name.clone(),
                projection: c.projection.name(),
                consumer,
            }),
        }
    }

    /// Camera centre in the rig frame, metres.
    pub fn camera_origin(&self, i: usize) -> Vector3<f64> {
        self.cameras[i].rig_from_cam.translation.vector
    }

    /// `cam_from_output = cam_from_rig * rig_from_output`.
    pub fn cam_from_output(&self, i: usize) -> Isometry3<f64> {
        self.cameras[i].rig_from_cam.inverse() * self.rig_from_output
    }
}

/// An image whose size does not fit its camera's projection.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ImageSizeError {
    #[error("expected a 2:1 equirectangular panorama (width = 2 x height), got {width}x{height}")]
    NotPanorama { width: u32, height: u32 },
    #[error("expected {expected_width}x{expected_height} (its {projection} image_size), got {width}x{height}")]
    NotImageSize {
        projection: &'static str,
        expected_width: u32,
        expected_height: u32,
        width: u32,
        height: u32,
    },
}

impl Projection {
    /// The image size the projection is calibrated for; `None` for equirectangular (any 2:1
    /// size).
    pub fn image_size(&self) -> Option<ImageSize> {
        match self {
            Projection::Equirectangular => None,
            Projection::Fisheye(c) => Some(c.image_size()),
            Projection::DualFisheye(d) => Some(d.image_size()),
        }
    }

    /// Whether a `width x height` image can be this camera's: an equirectangular camera's must
    /// be 2:1 (and not empty), a fisheye or dual-fisheye camera's exactly its `image_size`.
    pub fn check_image_size(&self, width: u32, height: u32) -> Result<(), ImageSizeError> {
        match self.image_size() {
            None if width == 0 || width != 2 * height => {
                Err(ImageSizeError::NotPanorama { width, height })
            }
            None => Ok(()),
            Some(s) if (s.width, s.height) != (width, height) => {
                Err(ImageSizeError::NotImageSize {
                    projection: self.name(),
                    expected_width: s.width,
                    expected_height: s.height,
                    width,
                    height,
                })
            }
            Some(_) => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    const GOOD: &str = r#"
cameras:
  - name: a
    topic: /a/image
    frame_id: a_link
    rig_from_cam: {translation: [0, 0, 1], rotation_xyzw: [0, 0, 0, 1]}
  - name: b
    topic: /b/image
    frame_id: b_link
    rig_from_cam: {translation: [0, -1, 1], rotation_rpy: [0, 0, 1.5707963]}
"#;

    #[test]
    fn parses_and_defaults() {
        let rig = Rig::from_yaml_str(GOOD, "good.yaml").unwrap();
        assert_eq!(rig.rig_frame, "base_link");
        assert_eq!(rig.cameras.len(), 2);
        assert_eq!(rig.output_frame_id, "a_link");
        let p = rig.cameras[1].rig_from_cam * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((p.coords - Vector3::new(0.0, 0.0, 1.0)).norm() < 1e-6);
        let back = Rig::from_yaml_str(&rig.to_yaml(), "round").unwrap();
        assert!(
            (back.cameras[1]
                .rig_from_cam
                .rotation
                .angle_to(&rig.cameras[1].rig_from_cam.rotation))
                < 1e-9
        );
    }

    fn expect_err(text: &str, needles: &[&str]) {
        let e = Rig::from_yaml_str(text, "bad.yaml")
            .unwrap_err()
            .to_string();
        for n in needles {
            assert!(e.contains(n), "error '{e}' should mention '{n}'");
        }
    }

    #[test]
    fn errors_name_file_camera_and_field() {
        expect_err(
            &GOOD.replace("[0, 0, 0, 1]", "[0, 0, 0, 2]"),
            &["bad.yaml", "'a'", "rotation_xyzw", "norm"],
        );
        expect_err(
            &GOOD.replace("[0, -1, 1]", "[0, .nan, 1]"),
            &["'b'", "translation", "not finite"],
        );
        expect_err(&GOOD.replace("name: b", "name: a"), &["duplicate"]);
        expect_err(
            &GOOD.replace("    topic: /b/image\n", ""),
            &["'b'", "topic", "missing"],
        );
        expect_err("cameras: [", &["bad.yaml", "malformed YAML"]);
        expect_err("cameras: []", &["at least 2"]);
        expect_err(
            &GOOD.replace("rotation_rpy: [0, 0, 1.5707963]", "rotation_rpy: [0, 0]"),
            &["expected 3 numbers"],
        );
        expect_err(
            &GOOD.replace(
                "frame_id: b_link",
                "frame_id: b_link\n    projection: fisheye",
            ),
            &["unsupported projection"],
        );
    }
}
