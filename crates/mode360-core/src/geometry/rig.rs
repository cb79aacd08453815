//! Rig calibration: which 360° cameras a rig carries and where, read from YAML.
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
//! `rig_from_cam` maps a point in the camera frame to the rig frame: `p_rig = R p_cam + t`.
//! The camera frame depends on the projection: an equirectangular camera's frame is REP 103
//! (x at the panorama's centre column, y left, z up); a fisheye camera's frame is its lens's
//! optical frame (z along the optical axis, x right, y down in the image), as Kalibr and Basalt
//! calibrate it; a dual-fisheye camera's frame is the body frame its lenses' `cam_from_lens`
//! are given in. The fisheye fields (`image_size`, `intrinsics`, `lenses`) are described in
//! [`super::rig_projection`].

use super::camera::{CameraModel, DualFisheye, FisheyeCamera};
pub use super::rig_projection::ImageSizeError;
use super::rig_projection::{
    parse_projection, projection_to_raw, RawIntrinsics, RawLens, RawProjection,
};
use super::GeometryError;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::Path;

/// A quaternion whose norm differs from one by more than this is rejected.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;
/// A rig needs at least this many cameras.
pub const MIN_CAMERAS: usize = 2;
/// The rig frame when the YAML names none.
pub const DEFAULT_RIG_FRAME: &str = "base_link";

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

/// A validated rig calibration.
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

// ---- raw YAML layout -------------------------------------------------------------------

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

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPose {
    translation: Option<Vec<f64>>,
    rotation_xyzw: Option<Vec<f64>>,
    rotation_rpy: Option<Vec<f64>>,
}

/// Where a problem was found, for error messages.
pub(super) struct Ctx<'a> {
    file: &'a str,
    camera: Option<&'a str>,
}

impl Ctx<'_> {
    pub(super) fn err(&self, field: &str, problem: impl Into<String>) -> RigError {
        match self.camera {
            Some(c) => RigError::Camera {
                file: self.file.to_string(),
                camera: c.to_string(),
                field: field.to_string(),
                problem: problem.into(),
            },
            None => RigError::Rig {
                file: self.file.to_string(),
                field: field.to_string(),
                problem: problem.into(),
            },
        }
    }
}

fn finite_vec<const N: usize>(
    ctx: &Ctx,
    field: &str,
    values: &[f64],
) -> Result<[f64; N], RigError> {
    if values.len() != N {
        return Err(ctx.err(field, format!("expected {N} numbers, got {}", values.len())));
    }
    if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
        return Err(ctx.err(field, format!("value {bad} is not finite")));
    }
    let mut out = [0.0; N];
    out.copy_from_slice(values);
    Ok(out)
}

pub(super) fn parse_pose(
    ctx: &Ctx,
    prefix: &str,
    raw: &RawPose,
) -> Result<Isometry3<f64>, RigError> {
    let field = |f: &str| format!("{prefix}.{f}");
    let t = raw
        .translation
        .as_deref()
        .ok_or_else(|| ctx.err(&field("translation"), "missing"))?;
    let [tx, ty, tz] = finite_vec::<3>(ctx, &field("translation"), t)?;
    let rotation = match (&raw.rotation_xyzw, &raw.rotation_rpy) {
        (Some(_), Some(_)) => {
            return Err(ctx.err(
                prefix,
                "give either rotation_xyzw or rotation_rpy, not both",
            ))
        }
        (None, None) => return Err(ctx.err(&field("rotation_xyzw"), "missing")),
        (Some(q), None) => {
            let [x, y, z, w] = finite_vec::<4>(ctx, &field("rotation_xyzw"), q)?;
            let q = Quaternion::new(w, x, y, z);
            let n = q.norm();
            if (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                return Err(ctx.err(
                    &field("rotation_xyzw"),
                    format!("quaternion norm is {n:.6}, expected 1 (tolerance {QUATERNION_NORM_TOLERANCE})"),
                ));
            }
            UnitQuaternion::from_quaternion(q)
        }
        (None, Some(rpy)) => {
            let [r, p, y] = finite_vec::<3>(ctx, &field("rotation_rpy"), rpy)?;
            UnitQuaternion::from_euler_angles(r, p, y)
        }
    };
    Ok(Isometry3::from_parts(
        Translation3::new(tx, ty, tz),
        rotation,
    ))
}

/// The YAML form of a pose: translation and quaternion xyzw.
pub(super) fn pose_to_raw(iso: &Isometry3<f64>) -> RawPose {
    let q = iso.rotation.quaternion();
    RawPose {
        translation: Some(iso.translation.vector.iter().copied().collect()),
        rotation_xyzw: Some(vec![q.i, q.j, q.k, q.w]),
        rotation_rpy: None,
    }
}

fn non_empty(ctx: &Ctx, field: &str, v: &Option<String>) -> Result<String, RigError> {
    match v.as_deref().map(str::trim) {
        None => Err(ctx.err(field, "missing")),
        Some("") => Err(ctx.err(field, "empty")),
        Some(s) => Ok(s.to_string()),
    }
}

impl Rig {
    /// Reads and validates a rig YAML file.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, RigError> {
        let path = path.as_ref();
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| RigError::Io {
            file: file.clone(),
            source,
        })?;
        Self::from_yaml_str(&text, &file)
    }

    /// Parses and validates rig YAML; `source_name` names the text in errors.
    pub fn from_yaml_str(text: &str, source_name: &str) -> Result<Self, RigError> {
        let raw: RawRig = serde_yaml::from_str(text).map_err(|e| RigError::Yaml {
            file: source_name.to_string(),
            message: e.to_string(),
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
        let mut cameras = Vec::with_capacity(raw_cams.len());
        let mut names = HashSet::new();
        let mut topics = HashSet::new();
        let mut frames = HashSet::new();
        for (i, rc) in raw_cams.iter().enumerate() {
            let label = rc.name.clone().unwrap_or_else(|| format!("#{}", i + 1));
            let ctx = Ctx {
                file: source_name,
                camera: Some(&label),
            };
            let name = non_empty(&ctx, "name", &rc.name)?;
            if !names.insert(name.clone()) {
                return Err(ctx.err("name", "duplicate camera name"));
            }
            let topic = non_empty(&ctx, "topic", &rc.topic)?;
            if !topics.insert(topic.clone()) {
                return Err(ctx.err(
                    "topic",
                    format!("topic '{topic}' is used by another camera"),
                ));
            }
            let frame_id = non_empty(&ctx, "frame_id", &rc.frame_id)?;
            if !frames.insert(frame_id.clone()) {
                return Err(ctx.err(
                    "frame_id",
                    format!("frame_id '{frame_id}' is used by another camera"),
                ));
            }
            let projection = parse_projection(
                &ctx,
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
            let rig_from_cam = parse_pose(&ctx, "rig_from_cam", pose)?;
            cameras.push(RigCamera {
                name,
                topic,
                frame_id,
                projection,
                rig_from_cam,
            });
        }
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
        let (output_frame_id, rig_from_output) = match &raw.output {
            None => (
                cameras[reference].frame_id.clone(),
                cameras[reference].rig_from_cam,
            ),
            Some(o) => {
                let frame = match &o.frame_id {
                    None => cameras[reference].frame_id.clone(),
                    some => non_empty(&top, "output.frame_id", some)?,
                };
                let pose = match &o.rig_from_output {
                    None => cameras[reference].rig_from_cam,
                    Some(p) => parse_pose(&top, "output.rig_from_output", p)?,
                };
                (frame, pose)
            }
        };
        Ok(Self {
            rig_frame,
            cameras,
            reference,
            output_frame_id,
            rig_from_output,
        })
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
        Ok(Self {
            rig_frame: self.rig_frame.clone(),
            cameras,
            reference,
            output_frame_id: self.output_frame_id.clone(),
            rig_from_output: self.rig_from_output,
        })
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

#[cfg(test)]
mod tests {
    use super::*;

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
