//! Calibration import: a Kalibr camchain or a Basalt `calibration.json` into a [`Rig`].
//!
//! Frames. Both tools calibrate each camera in its optical frame (z along the optical axis,
//! x right, y down in the image), which is the frame a fisheye camera's `rig_from_cam` maps
//! from in the rig YAML ([`super::camera`]). The rig frame is
//!
//! * Kalibr: camera 0. Its `T_cn_cnm1` (`p_cn = T_cn_cnm1 p_cn-1`) chain gives
//!   `cn_from_c0 = T_cn_cnm1 * ... * T_c1_c0` and `rig_from_cn = cn_from_c0^-1`.
//! * Basalt: the IMU. Its `T_imu_cam` (px py pz, qx qy qz qw) is `rig_from_cam` as it is.
//!
//! The depth output frame (`<first camera>_depth`) sits at the first camera's centre in the
//! REP 103 orientation of its optical frame: x along the optical axis, y to the image's left,
//! z to the image's top (`cam_from_output` columns `(0,0,1)`, `(-1,0,0)`, `(0,-1,0)`).
//!
//! Models, converted exactly or refused:
//!
//! | Kalibr `camera_model` / `distortion_model` | Basalt `camera_type` | rig `projection` |
//! |---|---|---|
//! | `ds` / `none` | `ds` | `double_sphere` |
//! | `eucm` / `none` | `eucm` | `eucm` |
//! | `pinhole` / `equidistant` | `kb4` | `kannala_brandt` |
//! | `omni` / `none` (Mei's unified model) | `ucm` | `eucm` with `beta = 1` |
//! | `pinhole` / `none` | `pinhole` | `eucm` with `alpha = 0`, `beta = 1` |
//!
//! Mei's `xi` becomes `alpha = xi / (1 + xi)` with the focal lengths divided by `1 + xi`
//! (`fu x / (xi d + z) = (fu / (1 + xi)) x / (alpha d + (1 - alpha) z)`); Basalt's `ucm` is
//! already written with `alpha`. A radial-tangential or FOV distortion with non-zero
//! coefficients has no exact counterpart and is refused, naming the camera and the model.
//!
//! Strict reading, the same for both formats:
//!
//! * a missing or unknown camera or distortion model is an error naming the camera and the
//!   field; so are distortion coefficients the model would ignore (non-zero ones under Kalibr's
//!   `distortion_model: none`, or a count the model does not take), and Basalt intrinsics the
//!   `camera_type` does not take;
//! * a duplicated key is an error (Kalibr's YAML through serde_yaml; Basalt's JSON through a
//!   reader that names the key and where it is);
//! * a UTF-8 byte-order mark at the start is dropped;
//! * files over [`MAX_CALIBRATION_FILE_BYTES`] are refused before they are read, and text
//!   nested deeper than [`MAX_FLOW_DEPTH`] before it is parsed
//!   ([`crate::geometry::rig_yaml`]'s guards);
//! * values outside the plausible bounds of [`crate::geometry::rig`] are refused with the
//!   bound: focal lengths outside [`MIN_FOCAL_PX`](crate::geometry::rig::MIN_FOCAL_PX) to
//!   [`MAX_FOCAL_PX`](crate::geometry::rig::MAX_FOCAL_PX) (1e-3 to 1e6 px), distortion
//!   parameters beyond [`MAX_DISTORTION_ABS`](crate::geometry::rig::MAX_DISTORTION_ABS)
//!   (1e3), translations beyond [`MAX_TRANSLATION_M`](crate::geometry::rig::MAX_TRANSLATION_M)
//!   (1 km), non-finite numbers anywhere; principal points must lie in the image;
//! * topics and frame ids are ROS 2 names ([`crate::geometry::rig::validate_topic_name`]).

mod basalt;
mod json;
mod kalibr;

pub use basalt::rig_from_basalt_json;
pub use kalibr::rig_from_kalibr_camchain;

use super::camera::{Eucm, FisheyeCamera, FisheyeLens, Focal, ImageSize, IntrinsicsError};
use super::rig::{
    check_lens, check_translation, validate_topic_name, Projection, Rig, RigCamera, RigError,
    RigOutput, DEFAULT_RIG_FRAME,
};
use super::rig_yaml::input::{self, ReadError};
pub use super::rig_yaml::{MAX_CALIBRATION_FILE_BYTES, MAX_FLOW_DEPTH};
use nalgebra::{Isometry3, Matrix3, Rotation3, UnitQuaternion};
use std::path::Path;

/// How imported cameras are named and where they publish.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportOptions {
    /// The rig frame's name (Kalibr: camera 0; Basalt: the IMU).
    pub rig_frame: String,
    /// Topics become `<prefix>/<camera>/image_raw`; `None` keeps Kalibr's `rostopic` (and
    /// gives `/<camera>/image_raw` where there is none).
    pub topic_prefix: Option<String>,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            rig_frame: DEFAULT_RIG_FRAME.into(),
            topic_prefix: None,
        }
    }
}

/// A calibration file that cannot become a rig: names the file and, where it applies, the
/// camera and the field or model.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("{file}: cannot read calibration: {source}")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: malformed {format}: {message}")]
    Parse {
        file: String,
        format: &'static str,
        message: String,
    },
    #[error("{file}: camera '{camera}': field '{field}': {problem}")]
    Camera {
        file: String,
        camera: String,
        field: String,
        problem: String,
    },
    #[error("{file}: camera '{camera}': field '{field}': unknown {kind} model '{model}' (supported: {supported})")]
    UnknownModel {
        file: String,
        camera: String,
        /// The file's field: `camera_model`, `distortion_model`, `camera_type`.
        field: String,
        kind: ModelKind,
        model: String,
        supported: &'static str,
    },
    #[error("{file}: camera '{camera}': model '{model}' cannot be represented exactly: {reason}")]
    Unrepresentable {
        file: String,
        camera: String,
        model: String,
        reason: String,
    },
    #[error("{file}: {problem}")]
    File { file: String, problem: String },
    #[error(transparent)]
    Rig(#[from] RigError),
}

/// Which model an [`ImportError::UnknownModel`] is: the camera's or its distortion's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelKind {
    Camera,
    Distortion,
}

impl std::fmt::Display for ModelKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Camera => "camera",
            Self::Distortion => "distortion",
        })
    }
}

/// A rotation matrix whose `R^T R` differs from the identity by more than this is refused.
pub const ROTATION_ORTHONORMAL_TOLERANCE: f64 = 1e-6;

/// One camera as read from a calibration file.
pub(crate) struct ImportedCamera {
    pub name: String,
    /// The tool's own topic, if it has one.
    pub topic: Option<String>,
    pub projection: Projection,
    pub rig_from_cam: Isometry3<f64>,
}

/// Errors of one camera of one file.
pub(crate) struct CamCtx<'a> {
    pub file: &'a str,
    pub camera: &'a str,
}

impl CamCtx<'_> {
    pub fn err(&self, field: &str, problem: impl Into<String>) -> ImportError {
        ImportError::Camera {
            file: self.file.into(),
            camera: self.camera.into(),
            field: field.into(),
            problem: problem.into(),
        }
    }

    pub fn unrepresentable(&self, model: &str, reason: impl Into<String>) -> ImportError {
        ImportError::Unrepresentable {
            file: self.file.into(),
            camera: self.camera.into(),
            model: model.into(),
            reason: reason.into(),
        }
    }

    /// An intrinsics error from a model constructor, under the calibration's own field.
    pub fn intrinsics(&self, field: &str, e: IntrinsicsError) -> ImportError {
        self.err(field, format!("{}: {}", e.field, e.problem))
    }

    /// An unknown model in `field`.
    pub fn unknown_model(
        &self,
        field: &str,
        kind: ModelKind,
        model: &str,
        supported: &'static str,
    ) -> ImportError {
        ImportError::UnknownModel {
            file: self.file.into(),
            camera: self.camera.into(),
            field: field.into(),
            kind,
            model: model.into(),
            supported,
        }
    }

    /// `Err` unless the lens's focal lengths and distortion parameters are plausible
    /// ([`check_lens`]); `field_of` gives the file's field for the parameter (`fx`, `k1`).
    pub fn plausible(
        &self,
        lens: &FisheyeLens,
        field_of: impl Fn(&str) -> String,
    ) -> Result<(), ImportError> {
        check_lens(lens).map_err(|e| self.intrinsics(&field_of(&e.field), e))
    }

    /// `[w, h]` from the file's resolution field.
    pub fn image_size(&self, field: &str, v: &[f64]) -> Result<ImageSize, ImportError> {
        let whole = |x: f64| x.is_finite() && x.fract() == 0.0 && x > 0.0 && x <= u32::MAX as f64;
        match v {
            [w, h] if whole(*w) && whole(*h) => {
                ImageSize::new(*w as u32, *h as u32).map_err(|e| self.intrinsics(field, e))
            }
            _ => Err(self.err(
                field,
                format!("expected [width, height] in whole pixels, got {v:?}"),
            )),
        }
    }

    /// A single-lens camera, its principal point checked against the image.
    pub fn fisheye(
        &self,
        field: &str,
        lens: FisheyeLens,
        size: ImageSize,
    ) -> Result<Projection, ImportError> {
        FisheyeCamera::new(lens, size)
            .map(Projection::Fisheye)
            .map_err(|e| self.intrinsics(field, e))
    }

    /// A pinhole camera as EUCM with `alpha = 0`, `beta = 1` (exact: `u = fx x / z + cx`).
    pub fn pinhole(&self, field: &str, focal: Focal) -> Result<FisheyeLens, ImportError> {
        Eucm::new(focal, 0.0, 1.0)
            .map(FisheyeLens::Eucm)
            .map_err(|e| self.intrinsics(field, e))
    }

    /// A 4x4 homogeneous transform as an isometry; refuses a non-rigid one.
    pub fn isometry(&self, field: &str, rows: &[Vec<f64>]) -> Result<Isometry3<f64>, ImportError> {
        let bad = |p: String| self.err(field, p);
        if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
            return Err(bad("expected a 4x4 matrix".into()));
        }
        if rows.iter().flatten().any(|v| !v.is_finite()) {
            return Err(bad("has a value that is not finite".into()));
        }
        if rows[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(bad(format!(
                "last row is {:?}, expected [0, 0, 0, 1]",
                rows[3]
            )));
        }
        let m = Matrix3::from_fn(|r, c| rows[r][c]);
        let err = (m.transpose() * m - Matrix3::identity()).amax();
        if err > ROTATION_ORTHONORMAL_TOLERANCE || m.determinant() <= 0.0 {
            return Err(bad(format!(
                "upper-left 3x3 is not a rotation (|R^T R - I| = {err:.2e}, det {:.6})",
                m.determinant()
            )));
        }
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&m));
        let t = nalgebra::Vector3::new(rows[0][3], rows[1][3], rows[2][3]);
        check_translation(&t).map_err(bad)?;
        Ok(Isometry3::from_parts(t.into(), rotation))
    }
}

/// `cam_from_output` for the REP 103 output frame at a camera's centre: columns are the
/// output's x, y, z in the optical frame: `(0, 0, 1)`, `(-1, 0, 0)`, `(0, -1, 0)`.
pub fn optical_from_body() -> UnitQuaternion<f64> {
    let m = Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
}

/// The rig from imported cameras, validated by [`Rig::new`] as every rig is (the file's own
/// topics first, under the file's field name).
pub(crate) fn assemble(
    file: &str,
    cams: Vec<ImportedCamera>,
    opts: &ImportOptions,
) -> Result<Rig, ImportError> {
    let first = cams.first().ok_or_else(|| ImportError::File {
        file: file.into(),
        problem: "no cameras".into(),
    })?;
    let output_frame_id = format!("{}_depth", first.name);
    let rig_from_output = first.rig_from_cam
        * Isometry3::from_parts(nalgebra::Translation3::identity(), optical_from_body());
    let cameras = cams
        .into_iter()
        .map(|c| {
            let topic = match (&opts.topic_prefix, c.topic) {
                (Some(prefix), _) => {
                    format!("{}/{}/image_raw", prefix.trim_end_matches('/'), c.name)
                }
                (None, Some(t)) => {
                    // The file's own topic: named by the file's field.
                    validate_topic_name(&t).map_err(|p| {
                        CamCtx {
                            file,
                            camera: &c.name,
                        }
                        .err("rostopic", p)
                    })?;
                    t
                }
                (None, None) => format!("/{}/image_raw", c.name),
            };
            Ok(RigCamera {
                frame_id: format!("{}_optical_frame", c.name),
                name: c.name,
                topic,
                projection: c.projection,
                rig_from_cam: c.rig_from_cam,
            })
        })
        .collect::<Result<Vec<_>, ImportError>>()?;
    let output = RigOutput {
        frame_id: output_frame_id,
        rig_from_output,
    };
    Ok(
        Rig::new(opts.rig_frame.clone(), cameras, 0, Some(output))
            .map_err(|e| e.in_source(file))?,
    )
}

/// Reads a calibration file's text through the guards of the module docs: at most
/// [`MAX_CALIBRATION_FILE_BYTES`], without a byte-order mark, nested at most
/// [`MAX_FLOW_DEPTH`] deep and (for YAML, `max_collections`) with at most that many `[`/`{`.
pub(crate) fn read(
    path: &Path,
    max_collections: Option<usize>,
) -> Result<(String, String), ImportError> {
    let file = path.display().to_string();
    let refused = |problem| ImportError::File {
        file: file.clone(),
        problem,
    };
    let text = input::read_calibration(path).map_err(|e| match e {
        ReadError::Io(source) => ImportError::Io {
            file: file.clone(),
            source,
        },
        ReadError::Refused(problem) => refused(problem),
    })?;
    input::check_nesting(&text, max_collections).map_err(refused)?;
    Ok((file, text))
}
