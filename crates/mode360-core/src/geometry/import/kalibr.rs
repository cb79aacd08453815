//! Kalibr's camchain YAML (`kalibr_calibrate_cameras` output, `camchain-*.yaml`):
//!
//! ```yaml
//! cam0:
//!   camera_model: ds                 # pinhole | omni | ds | eucm (others are refused)
//!   intrinsics: [xi, alpha, fu, fv, pu, pv]
//!   distortion_model: none           # equidistant with pinhole; none (or all-zero radtan)
//!   distortion_coeffs: []
//!   resolution: [1280, 1024]
//!   rostopic: /cam0/image_raw
//! cam1:
//!   T_cn_cnm1:                       # p_cam1 = T_cn_cnm1 p_cam0, a 4x4 row-major matrix
//!   - [r11, r12, r13, tx]
//!   - ...
//! ```
//!
//! Intrinsics per `camera_model`: `pinhole` `[fu, fv, pu, pv]`, `omni` `[xi, fu, fv, pu, pv]`,
//! `ds` `[xi, alpha, fu, fv, pu, pv]`, `eucm` `[alpha, beta, fu, fv, pu, pv]`.
//! Coefficients per `distortion_model` (required, as Kalibr always writes it): `none` `[]`
//! (all zeros accepted), `radtan` `[k1, k2, p1, p2]`, `equidistant` `[k1, k2, k3, k4]`,
//! `fov` `[w]`. The module docs of [`super`] give the frames, the model conversions and what
//! is refused.

use super::{assemble, read, CamCtx, ImportError, ImportOptions, ImportedCamera, ModelKind};
use crate::geometry::camera::{DoubleSphere, Eucm, FisheyeLens, Focal, KannalaBrandt};
use crate::geometry::rig::{check_focal, num, quoted};
use crate::geometry::rig_yaml::input::yaml_error;
use crate::geometry::rig_yaml::MAX_FLOW_COLLECTIONS;
use crate::geometry::Rig;
use nalgebra::Isometry3;
use serde::de::{Deserializer, MapAccess, Visitor};
use serde::Deserialize;
use serde_yaml::Value;
use std::path::Path;

const SUPPORTED: &str = "pinhole, omni, ds, eucm";
const DISTORTIONS: &str = "none, radtan, equidistant, fov";

/// One camera of a camchain as YAML values; fields Kalibr adds that the rig does not use are
/// ignored. The values are typed by [`Fields::of`], so a wrong type or a number beyond `f64`
/// (YAML reads `1e400` as text) is an error naming the camera and the field.
#[derive(Debug, Deserialize)]
struct KalibrCamera {
    camera_model: Option<Value>,
    intrinsics: Option<Value>,
    distortion_model: Option<Value>,
    distortion_coeffs: Option<Value>,
    resolution: Option<Value>,
    rostopic: Option<Value>,
    #[serde(rename = "T_cn_cnm1")]
    t_cn_cnm1: Option<Value>,
}

/// A camera's fields, typed (`None`: missing or null).
struct Fields {
    camera_model: Option<String>,
    intrinsics: Option<Vec<f64>>,
    distortion_model: Option<String>,
    distortion_coeffs: Option<Vec<f64>>,
    resolution: Option<Vec<f64>>,
    rostopic: Option<String>,
    t_cn_cnm1: Option<Vec<Vec<f64>>>,
}

impl Fields {
    fn of(ctx: &CamCtx, cam: &KalibrCamera) -> Result<Self, ImportError> {
        Ok(Self {
            camera_model: text(ctx, "camera_model", cam.camera_model.as_ref())?,
            intrinsics: numbers(ctx, "intrinsics", cam.intrinsics.as_ref())?,
            distortion_model: text(ctx, "distortion_model", cam.distortion_model.as_ref())?,
            distortion_coeffs: numbers(ctx, "distortion_coeffs", cam.distortion_coeffs.as_ref())?,
            resolution: numbers(ctx, "resolution", cam.resolution.as_ref())?,
            rostopic: text(ctx, "rostopic", cam.rostopic.as_ref())?,
            t_cn_cnm1: match present(cam.t_cn_cnm1.as_ref()) {
                None => None,
                Some(Value::Sequence(rows)) => Some(
                    rows.iter()
                        .enumerate()
                        .map(|(r, row)| {
                            let field = format!("T_cn_cnm1[{r}]");
                            numbers(ctx, &field, Some(row))?.ok_or_else(|| {
                                ctx.err(&field, "expected a row of 4 numbers, got null")
                            })
                        })
                        .collect::<Result<_, _>>()?,
                ),
                Some(other) => {
                    return Err(ctx.err(
                        "T_cn_cnm1",
                        format!(
                            "expected a 4x4 matrix (4 rows of 4 numbers), got {}",
                            kind(other)
                        ),
                    ))
                }
            },
        })
    }
}

/// `v` unless it is missing or null.
fn present(v: Option<&Value>) -> Option<&Value> {
    v.filter(|v| !v.is_null())
}

/// What a YAML value is, for "expected ..., got ..." messages.
fn kind(v: &Value) -> String {
    match v {
        Value::Null => "null".into(),
        Value::Bool(b) => format!("{b}"),
        Value::Number(n) => format!("the number {n}"),
        Value::String(s) => format!("the text {}", quoted(s)),
        Value::Sequence(_) => "a list".into(),
        Value::Mapping(_) => "a mapping".into(),
        Value::Tagged(t) => format!("a value tagged {}", quoted(&t.tag.to_string())),
    }
}

/// A text field (a model name, a topic).
fn text(ctx: &CamCtx, field: &str, v: Option<&Value>) -> Result<Option<String>, ImportError> {
    match present(v) {
        None => Ok(None),
        Some(Value::String(s)) => Ok(Some(s.clone())),
        Some(other) => Err(ctx.err(field, format!("expected text, got {}", kind(other)))),
    }
}

/// A list of numbers; the element's index names a bad one (`intrinsics[2]`). Non-finite
/// numbers (`.nan`, `.inf`) pass here and are refused with their field's bound later.
fn numbers(ctx: &CamCtx, field: &str, v: Option<&Value>) -> Result<Option<Vec<f64>>, ImportError> {
    let items = match present(v) {
        None => return Ok(None),
        Some(Value::Sequence(items)) => items,
        Some(other) => {
            return Err(ctx.err(
                field,
                format!("expected a list of numbers, got {}", kind(other)),
            ))
        }
    };
    items
        .iter()
        .enumerate()
        .map(|(i, item)| {
            let at = || format!("{field}[{i}]");
            match item {
                Value::Number(n) => n
                    .as_f64()
                    .ok_or_else(|| ctx.err(&at(), format!("{n} is not a number"))),
                // YAML resolves a number beyond f64 (`1e400`) as text.
                Value::String(s)
                    if s.trim().parse::<f64>().is_ok_and(f64::is_infinite)
                        && !s
                            .trim()
                            .trim_start_matches(['+', '-'])
                            .starts_with(['i', 'I']) =>
                {
                    Err(ctx.err(
                        &at(),
                        format!("{} is beyond the range of a 64-bit float", quoted(s)),
                    ))
                }
                other => Err(ctx.err(&at(), format!("expected a number, got {}", kind(other)))),
            }
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// The camchain's cameras in file order, a camera key given twice kept twice (serde_yaml
/// refuses a field given twice within a camera, but a map would keep the last camera).
struct Cameras(Vec<(String, KalibrCamera)>);

impl<'de> Deserialize<'de> for Cameras {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct CamerasVisitor;
        impl<'de> Visitor<'de> for CamerasVisitor {
            type Value = Cameras;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a mapping of cameras (cam0, cam1, ...)")
            }

            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Cameras, A::Error> {
                let mut cams = Vec::new();
                while let Some(key) = map.next_key::<String>()? {
                    cams.push((key, map.next_value()?));
                }
                Ok(Cameras(cams))
            }
        }
        d.deserialize_map(CamerasVisitor)
    }
}

/// Reads a Kalibr camchain file into a rig (camera 0 is the rig frame).
pub fn rig_from_kalibr_camchain(
    path: impl AsRef<Path>,
    opts: &ImportOptions,
) -> Result<Rig, ImportError> {
    let (file, text) = read(path.as_ref(), Some(MAX_FLOW_COLLECTIONS))?;
    let Cameras(raw) = serde_yaml::from_str(&text).map_err(|e| ImportError::Parse {
        file: file.clone(),
        format: "Kalibr camchain YAML",
        message: yaml_error(&text, &e),
    })?;
    if let Some(twice) = raw
        .iter()
        .enumerate()
        .find_map(|(i, (key, _))| raw[..i].iter().any(|(k, _)| k == key).then_some(key))
    {
        return Err(duplicate_camera(&file, &text, twice));
    }
    // cam0, cam1, ... in chain order, none missing.
    let mut ordered: Vec<(usize, &String, &KalibrCamera)> = Vec::with_capacity(raw.len());
    for (key, cam) in &raw {
        let index = key
            .strip_prefix("cam")
            .and_then(|n| n.parse::<usize>().ok())
            .ok_or_else(|| ImportError::File {
                file: file.clone(),
                problem: format!("key '{key}' is not a Kalibr camera (cam0, cam1, ...)"),
            })?;
        ordered.push((index, key, cam));
    }
    ordered.sort_by_key(|(i, _, _)| *i);
    if let Some((pos, (i, key, _))) = ordered.iter().enumerate().find(|(pos, (i, _, _))| pos != i) {
        return Err(ImportError::File {
            file: file.clone(),
            problem: format!("the chain has a gap: '{key}' (index {i}) where cam{pos} should be"),
        });
    }
    let mut cams = Vec::with_capacity(ordered.len());
    let mut cn_from_c0 = Isometry3::identity();
    for (i, key, cam) in ordered {
        let ctx = CamCtx {
            file: &file,
            camera: key,
        };
        let cam = &Fields::of(&ctx, cam)?;
        if i > 0 {
            let rows = cam.t_cn_cnm1.as_deref().ok_or_else(|| {
                ctx.err("T_cn_cnm1", "missing (every camera after cam0 needs it)")
            })?;
            cn_from_c0 = ctx.isometry("T_cn_cnm1", rows)? * cn_from_c0;
        }
        cams.push(ImportedCamera {
            name: key.clone(),
            topic: cam.rostopic.clone(),
            projection: projection(&ctx, cam)?,
            rig_from_cam: cn_from_c0.inverse(),
        });
    }
    assemble(&file, cams, opts)
}

/// A camera key given twice: malformed at the line of its second block-style `key:`, else
/// (flow style) named without a position.
fn duplicate_camera(file: &str, text: &str, key: &str) -> ImportError {
    let problem = format!(
        "duplicate key {} (each camera may appear once)",
        quoted(key)
    );
    let second = text
        .lines()
        .enumerate()
        .filter(|(_, l)| {
            l.trim_start_matches(['"', '\''])
                .strip_prefix(key)
                .is_some_and(|rest| rest.trim_start_matches(['"', '\'']).starts_with(':'))
                && !l.starts_with(char::is_whitespace)
        })
        .nth(1);
    match second {
        Some((i, _)) => ImportError::Parse {
            file: file.into(),
            format: "Kalibr camchain YAML",
            message: format!("{problem} at line {} column 1", i + 1),
        },
        None => ImportError::File {
            file: file.into(),
            problem,
        },
    }
}

/// `Err` naming `field` unless `v` has `n` numbers.
fn exactly<'a>(
    ctx: &CamCtx,
    field: &str,
    v: &'a [f64],
    n: usize,
    layout: &str,
) -> Result<&'a [f64], ImportError> {
    if v.len() != n {
        return Err(ctx.err(
            field,
            format!("expected {n} numbers {layout}, got {}", v.len()),
        ));
    }
    Ok(v)
}

/// `[fu, fv, pu, pv]`: finite, positive and plausible focal lengths.
fn focal(ctx: &CamCtx, f: &[f64]) -> Result<Focal, ImportError> {
    let ie = |e| ctx.intrinsics("intrinsics", e);
    let focal = Focal::new(f[0], f[1], f[2], f[3]).map_err(ie)?;
    check_focal("fx", focal.fx).map_err(ie)?;
    check_focal("fy", focal.fy).map_err(ie)?;
    Ok(focal)
}

fn projection(ctx: &CamCtx, cam: &Fields) -> Result<crate::geometry::Projection, ImportError> {
    let model = cam
        .camera_model
        .as_deref()
        .ok_or_else(|| ctx.err("camera_model", format!("missing (one of {SUPPORTED})")))?;
    if !SUPPORTED.split(", ").any(|m| m == model) {
        return Err(ctx.unknown_model("camera_model", ModelKind::Camera, model, SUPPORTED));
    }
    let intr = cam
        .intrinsics
        .as_deref()
        .ok_or_else(|| ctx.err("intrinsics", "missing"))?;
    let size = ctx.image_size(
        "resolution",
        cam.resolution
            .as_deref()
            .ok_or_else(|| ctx.err("resolution", "missing"))?,
    )?;
    let (distortion, coeffs) = distortion(ctx, cam)?;
    // A distortion that is there in name only (all coefficients zero) changes nothing.
    let undistorted = coeffs.iter().all(|c| *c == 0.0);
    let refuse = |reason: &str| ctx.unrepresentable(&format!("{model}/{distortion}"), reason);
    let ie = |e| ctx.intrinsics("intrinsics", e);
    let lens = match model {
        "ds" | "eucm" | "omni" if !undistorted => return Err(refuse(
            "the rig's fisheye models carry no extra distortion (expected distortion_model: none)",
        )),
        "ds" => {
            let v = exactly(ctx, "intrinsics", intr, 6, "[xi, alpha, fu, fv, pu, pv]")?;
            FisheyeLens::DoubleSphere(
                DoubleSphere::new(focal(ctx, &v[2..])?, v[0], v[1]).map_err(ie)?,
            )
        }
        "eucm" => {
            let v = exactly(ctx, "intrinsics", intr, 6, "[alpha, beta, fu, fv, pu, pv]")?;
            FisheyeLens::Eucm(Eucm::new(focal(ctx, &v[2..])?, v[0], v[1]).map_err(ie)?)
        }
        "omni" => {
            let v = exactly(ctx, "intrinsics", intr, 5, "[xi, fu, fv, pu, pv]")?;
            // The file's focal lengths are checked as written, before the conversion.
            focal(ctx, &v[1..])?;
            let xi = v[0];
            if !(xi >= 0.0 && xi.is_finite()) {
                return Err(refuse(&format!(
                    "xi = {xi}: the unified model maps to EUCM only for xi >= 0"
                )));
            }
            let s = 1.0 + xi;
            let f = Focal::new(v[1] / s, v[2] / s, v[3], v[4]).map_err(ie)?;
            FisheyeLens::Eucm(Eucm::new(f, xi / s, 1.0).map_err(ie)?)
        }
        _ => {
            let v = exactly(ctx, "intrinsics", intr, 4, "[fu, fv, pu, pv]")?;
            let f = focal(ctx, v)?;
            match distortion {
                "equidistant" => FisheyeLens::KannalaBrandt(
                    KannalaBrandt::new(f, [coeffs[0], coeffs[1], coeffs[2], coeffs[3]])
                        .map_err(|e| ctx.intrinsics("distortion_coeffs", e))?,
                ),
                _ if undistorted => ctx.pinhole("intrinsics", f)?,
                _ => {
                    return Err(refuse(
                        "only equidistant (Kannala-Brandt) or no distortion converts exactly",
                    ))
                }
            }
        }
    };
    ctx.plausible(&lens, |p| {
        if p.starts_with('k') {
            "distortion_coeffs"
        } else {
            "intrinsics"
        }
        .to_string()
    })?;
    ctx.fisheye("intrinsics", lens, size)
}

/// The camera's `distortion_model` (required) and its `distortion_coeffs`, as many as the
/// model takes: refuses an unknown model, a wrong count, non-finite values, and non-zero
/// coefficients that `none` would ignore.
fn distortion<'a>(ctx: &CamCtx, cam: &'a Fields) -> Result<(&'a str, &'a [f64]), ImportError> {
    let model = cam.distortion_model.as_deref().ok_or_else(|| {
        ctx.err(
            "distortion_model",
            format!("missing (Kalibr writes one for every camera: {DISTORTIONS}; none for ds, eucm and omni)"),
        )
    })?;
    let (n, layout) = match model {
        "none" => (0, "[]"),
        "radtan" => (4, "[k1, k2, p1, p2]"),
        "equidistant" => (4, "[k1, k2, k3, k4]"),
        "fov" => (1, "[w]"),
        other => {
            return Err(ctx.unknown_model(
                "distortion_model",
                ModelKind::Distortion,
                other,
                DISTORTIONS,
            ))
        }
    };
    let field = "distortion_coeffs";
    let coeffs: &[f64] = match (cam.distortion_coeffs.as_deref(), n) {
        (None, 0) => &[],
        (None, _) => {
            return Err(ctx.err(field, format!("missing ({model} takes {n}: {layout})")));
        }
        (Some(c), _) => c,
    };
    if let Some(bad) = coeffs.iter().find(|c| !c.is_finite()) {
        return Err(ctx.err(field, format!("value {bad} is not finite")));
    }
    if n == 0 {
        if let Some(c) = coeffs.iter().find(|c| **c != 0.0) {
            return Err(ctx.err(
                field,
                format!(
                    "{} coefficients (one is {}) would be ignored: distortion_model none takes none (give [] or the distortion model they belong to)",
                    coeffs.len(),
                    num(*c)
                ),
            ));
        }
    } else {
        exactly(ctx, field, coeffs, n, layout)?;
    }
    Ok((model, coeffs))
}
