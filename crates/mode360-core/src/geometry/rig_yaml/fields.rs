//! The YAML fields every part of a rig file shares: where a problem was found ([`Ctx`]),
//! finite number lists, non-empty strings and poses (`translation` with `rotation_xyzw` or
//! `rotation_rpy`; translations and angles within the bounds of
//! [`crate::geometry::rig::MAX_TRANSLATION_M`] and [`crate::geometry::rig::MAX_RPY_ABS_RAD`]).

use crate::geometry::rig::{check_rpy, check_translation, RigError, QUATERNION_NORM_TOLERANCE};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPose {
    translation: Option<Vec<f64>>,
    rotation_xyzw: Option<Vec<f64>>,
    rotation_rpy: Option<Vec<f64>>,
}

/// Where a problem was found, for error messages.
pub(super) struct Ctx<'a> {
    pub(super) file: &'a str,
    pub(super) camera: Option<&'a str>,
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

pub(super) fn finite_vec<const N: usize>(
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
    check_translation(&nalgebra::Vector3::new(tx, ty, tz))
        .map_err(|p| ctx.err(&field("translation"), p))?;
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
            check_rpy(&field("rotation_rpy"), &[r, p, y])
                .map_err(|e| ctx.err(&e.field, e.problem))?;
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

pub(super) fn non_empty(ctx: &Ctx, field: &str, v: &Option<String>) -> Result<String, RigError> {
    match v.as_deref().map(str::trim) {
        None => Err(ctx.err(field, "missing")),
        Some("") => Err(ctx.err(field, "empty")),
        Some(s) => Ok(s.to_string()),
    }
}
