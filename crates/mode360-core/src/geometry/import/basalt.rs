//! Basalt's `calibration.json` (cereal's JSON, everything under `value0`):
//!
//! ```json
//! {"value0": {
//!   "T_imu_cam": [{"px": 0.04, "py": -0.07, "pz": -0.05, "qx": 0.0, "qy": 0.0, "qz": 0.0, "qw": 1.0}, ...],
//!   "intrinsics": [{"camera_type": "ds",
//!                   "intrinsics": {"fx": 158.3, "fy": 158.3, "cx": 255.0, "cy": 256.9,
//!                                  "xi": -0.17, "alpha": 0.59}}, ...],
//!   "resolution": [[512, 512], ...],
//!   ...                               (IMU noise, biases, vignette: not used here)
//! }}
//! ```
//!
//! Intrinsics per `camera_type`: `ds` fx fy cx cy xi alpha, `eucm` fx fy cx cy alpha beta,
//! `kb4` fx fy cx cy k1 k2 k3 k4, `ucm` fx fy cx cy alpha, `pinhole` fx fy cx cy. `T_imu_cam`
//! maps camera points into the IMU frame, which becomes the rig frame. Cameras are named
//! `cam0`, `cam1`, ... in file order. The module docs of [`super`] give the conversions.

use super::{assemble, read, CamCtx, ImportError, ImportOptions, ImportedCamera};
use crate::geometry::camera::{DoubleSphere, Eucm, FisheyeLens, Focal, KannalaBrandt};
use crate::geometry::rig::QUATERNION_NORM_TOLERANCE;
use crate::geometry::Rig;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

const SUPPORTED: &str = "ds, eucm, kb4, ucm, pinhole";
/// Basalt models with no exact counterpart in the rig.
const UNREPRESENTABLE: [&str; 3] = ["fov", "pinhole-radtan8", "bal"];

#[derive(Debug, Deserialize)]
struct File {
    value0: Calibration,
}

#[derive(Debug, Deserialize)]
struct Calibration {
    #[serde(rename = "T_imu_cam")]
    t_imu_cam: Vec<Pose>,
    intrinsics: Vec<Intrinsics>,
    resolution: Vec<Vec<f64>>,
}

#[derive(Debug, Deserialize)]
struct Pose {
    px: f64,
    py: f64,
    pz: f64,
    qx: f64,
    qy: f64,
    qz: f64,
    qw: f64,
}

#[derive(Debug, Deserialize)]
struct Intrinsics {
    camera_type: String,
    intrinsics: BTreeMap<String, f64>,
}

/// Reads a Basalt calibration into a rig (the IMU is the rig frame).
pub fn rig_from_basalt_json(
    path: impl AsRef<Path>,
    opts: &ImportOptions,
) -> Result<Rig, ImportError> {
    let (file, text) = read(path.as_ref())?;
    let calib = serde_json::from_str::<File>(&text)
        .map_err(|e| ImportError::Parse {
            file: file.clone(),
            format: "Basalt calibration JSON",
            message: e.to_string(),
        })?
        .value0;
    let n = calib.intrinsics.len();
    if calib.t_imu_cam.len() != n || calib.resolution.len() != n {
        return Err(ImportError::File {
            file,
            problem: format!(
                "{n} intrinsics, {} T_imu_cam and {} resolution entries: one each per camera",
                calib.t_imu_cam.len(),
                calib.resolution.len()
            ),
        });
    }
    let mut cams = Vec::with_capacity(n);
    for (i, ((intr, pose), res)) in calib
        .intrinsics
        .iter()
        .zip(&calib.t_imu_cam)
        .zip(&calib.resolution)
        .enumerate()
    {
        let name = format!("cam{i}");
        let ctx = CamCtx {
            file: &file,
            camera: &name,
        };
        let size = ctx.image_size("resolution", res)?;
        let lens = lens(&ctx, intr)?;
        cams.push(ImportedCamera {
            topic: None,
            projection: ctx.fisheye("intrinsics", lens, size)?,
            rig_from_cam: isometry(&ctx, pose)?,
            name,
        });
    }
    assemble(&file, cams, opts)
}

fn isometry(ctx: &CamCtx, p: &Pose) -> Result<Isometry3<f64>, ImportError> {
    let values = [p.px, p.py, p.pz, p.qx, p.qy, p.qz, p.qw];
    if values.iter().any(|v| !v.is_finite()) {
        return Err(ctx.err("T_imu_cam", "has a value that is not finite"));
    }
    let q = Quaternion::new(p.qw, p.qx, p.qy, p.qz);
    if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(ctx.err(
            "T_imu_cam",
            format!("quaternion norm is {:.6}, expected 1", q.norm()),
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(p.px, p.py, p.pz),
        UnitQuaternion::from_quaternion(q),
    ))
}

fn lens(ctx: &CamCtx, intr: &Intrinsics) -> Result<FisheyeLens, ImportError> {
    let model = intr.camera_type.as_str();
    let wanted: &[&str] = match model {
        "ds" => &["fx", "fy", "cx", "cy", "xi", "alpha"],
        "eucm" => &["fx", "fy", "cx", "cy", "alpha", "beta"],
        "kb4" => &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"],
        "ucm" => &["fx", "fy", "cx", "cy", "alpha"],
        "pinhole" => &["fx", "fy", "cx", "cy"],
        m if UNREPRESENTABLE.contains(&m) => {
            return Err(ctx.unrepresentable(
                m,
                format!(
                    "the rig's models are {SUPPORTED} (as double_sphere, eucm, kannala_brandt)"
                ),
            ))
        }
        other => {
            return Err(ImportError::UnknownModel {
                file: ctx.file.into(),
                camera: ctx.camera.into(),
                model: other.into(),
                supported: SUPPORTED,
            })
        }
    };
    let get = |k: &str| -> Result<f64, ImportError> {
        intr.intrinsics.get(k).copied().ok_or_else(|| {
            ctx.err(
                &format!("intrinsics.{k}"),
                format!("missing ({model} needs {})", wanted.join(" ")),
            )
        })
    };
    let ie = |e| ctx.intrinsics("intrinsics", e);
    let focal = Focal::new(get("fx")?, get("fy")?, get("cx")?, get("cy")?).map_err(ie)?;
    Ok(match model {
        "ds" => FisheyeLens::DoubleSphere(
            DoubleSphere::new(focal, get("xi")?, get("alpha")?).map_err(ie)?,
        ),
        "eucm" => FisheyeLens::Eucm(Eucm::new(focal, get("alpha")?, get("beta")?).map_err(ie)?),
        "kb4" => FisheyeLens::KannalaBrandt(
            KannalaBrandt::new(focal, [get("k1")?, get("k2")?, get("k3")?, get("k4")?])
                .map_err(ie)?,
        ),
        "ucm" => FisheyeLens::Eucm(Eucm::new(focal, get("alpha")?, 1.0).map_err(ie)?),
        _ => ctx.pinhole("intrinsics", focal)?,
    })
}
