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
//! `cam0`, `cam1`, ... in file order. The module docs of [`super`] give the conversions and
//! what is refused.
//!
//! The JSON is read through [`super::json`] (duplicated keys refused, errors naming the
//! field), then field by field: errors name the camera and the field's path in the file
//! (`value0.intrinsics[1].camera_type`). Other fields of `value0` (IMU noise, vignette, ...)
//! are not read; the entries of `T_imu_cam` and `intrinsics` take only the keys above.

use super::json::parse_strict;
use super::{assemble, read, CamCtx, ImportError, ImportOptions, ImportedCamera, ModelKind};
use crate::geometry::camera::{
    DoubleSphere, Eucm, FisheyeLens, Focal, IntrinsicsError, KannalaBrandt,
};
use crate::geometry::rig::{check_translation, num, quoted, QUATERNION_NORM_TOLERANCE};
use crate::geometry::Rig;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde_json::{Map, Value};
use std::path::Path;

const FORMAT: &str = "Basalt calibration JSON";
const SUPPORTED: &str = "ds, eucm, kb4, ucm, pinhole";
/// Basalt models with no exact counterpart in the rig.
const UNREPRESENTABLE: [&str; 3] = ["fov", "pinhole-radtan8", "bal"];
/// The keys of a `T_imu_cam` entry.
const POSE_KEYS: [&str; 7] = ["px", "py", "pz", "qx", "qy", "qz", "qw"];

/// Reads a Basalt calibration into a rig (the IMU is the rig frame).
pub fn rig_from_basalt_json(
    path: impl AsRef<Path>,
    opts: &ImportOptions,
) -> Result<Rig, ImportError> {
    let (file, text) = read(path.as_ref(), None)?;
    let parse_err = |message: String| ImportError::Parse {
        file: file.clone(),
        format: FORMAT,
        message,
    };
    let root = parse_strict(&text).map_err(|e| parse_err(e.to_string()))?;
    // The file's structure, outside any one camera.
    let structure = |field: &str, what: &str, v: Option<&Value>| {
        parse_err(format!("field '{field}': expected {what}, {}", kind(v)))
    };
    let calib = root
        .get("value0")
        .and_then(Value::as_object)
        .ok_or_else(|| structure("value0", "an object", root.get("value0")))?;
    let list = |key: &str| {
        calib
            .get(key)
            .and_then(Value::as_array)
            .ok_or_else(|| structure(&format!("value0.{key}"), "an array", calib.get(key)))
    };
    let (intrinsics, poses, resolution) =
        (list("intrinsics")?, list("T_imu_cam")?, list("resolution")?);
    let n = intrinsics.len();
    if poses.len() != n || resolution.len() != n {
        return Err(ImportError::File {
            file,
            problem: format!(
                "{n} intrinsics, {} T_imu_cam and {} resolution entries: one each per camera",
                poses.len(),
                resolution.len()
            ),
        });
    }
    let mut cams = Vec::with_capacity(n);
    for (i, ((intr, pose), res)) in intrinsics.iter().zip(poses).zip(resolution).enumerate() {
        let name = format!("cam{i}");
        let ctx = CamCtx {
            file: &file,
            camera: &name,
        };
        let res_field = format!("value0.resolution[{i}]");
        let res = match res.as_array() {
            Some(a) => a
                .iter()
                .enumerate()
                .map(|(j, v)| number(&ctx, &format!("{res_field}[{j}]"), Some(v)))
                .collect::<Result<Vec<_>, _>>()?,
            None => {
                return Err(ctx.err(
                    &res_field,
                    format!("expected [width, height], {}", kind(Some(res))),
                ))
            }
        };
        let size = ctx.image_size(&res_field, &res)?;
        let at = format!("value0.intrinsics[{i}]");
        let lens = lens(&ctx, &at, intr)?;
        cams.push(ImportedCamera {
            topic: None,
            projection: ctx.fisheye(&format!("{at}.intrinsics"), lens, size)?,
            rig_from_cam: isometry(&ctx, &format!("value0.T_imu_cam[{i}]"), pose)?,
            name,
        });
    }
    assemble(&file, cams, opts)
}

/// What a value is, for "expected ..., got ..." messages.
fn kind(v: Option<&Value>) -> String {
    match v {
        None => "but it is missing".into(),
        Some(Value::Null) => "got null".into(),
        Some(Value::Bool(b)) => format!("got {b}"),
        Some(Value::Number(n)) => format!("got the number {n}"),
        Some(Value::String(s)) => format!("got the string {}", quoted(s)),
        Some(Value::Array(_)) => "got an array".into(),
        Some(Value::Object(_)) => "got an object".into(),
    }
}

/// A finite number at `field`.
fn number(ctx: &CamCtx, field: &str, v: Option<&Value>) -> Result<f64, ImportError> {
    match v {
        None => Err(ctx.err(field, "missing")),
        Some(Value::Number(n)) => match n.as_f64() {
            Some(x) if x.is_finite() => Ok(x),
            _ => Err(ctx.err(field, format!("{n} is not a finite number"))),
        },
        other => Err(ctx.err(field, format!("expected a number, {}", kind(other)))),
    }
}

/// The object at `field`.
fn object<'v>(
    ctx: &CamCtx,
    field: &str,
    v: Option<&'v Value>,
) -> Result<&'v Map<String, Value>, ImportError> {
    match v {
        None => Err(ctx.err(field, "missing")),
        Some(Value::Object(m)) => Ok(m),
        other => Err(ctx.err(field, format!("expected an object, {}", kind(other)))),
    }
}

/// `Err` naming the first key of the object at `field` that is not in `allowed` (`what` says
/// what the allowed keys are).
fn only_keys(
    ctx: &CamCtx,
    field: &str,
    map: &Map<String, Value>,
    allowed: &[&str],
    what: &str,
) -> Result<(), ImportError> {
    match map.keys().find(|k| !allowed.contains(&k.as_str())) {
        None => Ok(()),
        Some(k) => Err(ctx.err(
            &format!("{field}.{k}"),
            format!("not {what} (it takes {})", allowed.join(" ")),
        )),
    }
}

fn isometry(ctx: &CamCtx, field: &str, v: &Value) -> Result<Isometry3<f64>, ImportError> {
    let map = object(ctx, field, Some(v))?;
    only_keys(ctx, field, map, &POSE_KEYS, "a T_imu_cam field")?;
    let mut p = [0.0; 7];
    for (slot, key) in p.iter_mut().zip(POSE_KEYS) {
        *slot = number(ctx, &format!("{field}.{key}"), map.get(key))?;
    }
    let [px, py, pz, qx, qy, qz, qw] = p;
    let q = Quaternion::new(qw, qx, qy, qz);
    if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(ctx.err(
            field,
            format!(
                "quaternion norm is {}, expected 1 (tolerance {QUATERNION_NORM_TOLERANCE})",
                num(q.norm())
            ),
        ));
    }
    let t = Vector3::new(px, py, pz);
    check_translation(&t).map_err(|p| ctx.err(field, p))?;
    Ok(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// The lens of the `intrinsics` entry at `at` (`value0.intrinsics[i]`).
fn lens(ctx: &CamCtx, at: &str, entry: &Value) -> Result<FisheyeLens, ImportError> {
    let entry = object(ctx, at, Some(entry))?;
    let entry_keys = ["camera_type", "intrinsics"];
    only_keys(
        ctx,
        at,
        entry,
        &entry_keys,
        "a field of an intrinsics entry",
    )?;
    let type_field = format!("{at}.camera_type");
    let model = match entry.get("camera_type") {
        Some(Value::String(s)) => s.as_str(),
        None => return Err(ctx.err(&type_field, format!("missing (one of {SUPPORTED})"))),
        other => {
            return Err(ctx.err(
                &type_field,
                format!("expected a string (one of {SUPPORTED}), {}", kind(other)),
            ))
        }
    };
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
        other => return Err(ctx.unknown_model(&type_field, ModelKind::Camera, other, SUPPORTED)),
    };
    let params_field = format!("{at}.intrinsics");
    let params = object(ctx, &params_field, entry.get("intrinsics"))?;
    if let Some(k) = wanted.iter().find(|k| !params.contains_key(**k)) {
        return Err(ctx.err(
            &format!("{params_field}.{k}"),
            format!("missing ({model} needs {})", wanted.join(" ")),
        ));
    }
    let what = format!("a parameter of {model}");
    only_keys(ctx, &params_field, params, wanted, &what)?;
    let get = |k: &str| number(ctx, &format!("{params_field}.{k}"), params.get(k));
    let ie = |e: IntrinsicsError| ctx.err(&format!("{params_field}.{}", e.field), e.problem);
    let focal = Focal::new(get("fx")?, get("fy")?, get("cx")?, get("cy")?).map_err(ie)?;
    let lens = match model {
        "ds" => FisheyeLens::DoubleSphere(
            DoubleSphere::new(focal, get("xi")?, get("alpha")?).map_err(ie)?,
        ),
        "eucm" => FisheyeLens::Eucm(Eucm::new(focal, get("alpha")?, get("beta")?).map_err(ie)?),
        "kb4" => FisheyeLens::KannalaBrandt(
            KannalaBrandt::new(focal, [get("k1")?, get("k2")?, get("k3")?, get("k4")?])
                .map_err(ie)?,
        ),
        "ucm" => FisheyeLens::Eucm(Eucm::new(focal, get("alpha")?, 1.0).map_err(ie)?),
        _ => ctx.pinhole(&params_field, focal)?,
    };
    crate::geometry::rig::check_lens(&lens).map_err(ie)?;
    Ok(lens)
}
