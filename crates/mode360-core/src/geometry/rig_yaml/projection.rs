//! The `projection` of a rig camera in the rig YAML: its model name, image size and
//! intrinsics, read with errors that name the file, the camera and the field.
//!
//! ```yaml
//! projection: equirectangular            # the default; no image_size, no intrinsics
//!                                        # (a camera with those and no projection is an error)
//!
//! projection: double_sphere              # or kannala_brandt, eucm
//! image_size: [1280, 1024]               # width, height in pixels
//! intrinsics: {fx: 380.0, fy: 380.0, cx: 640.0, cy: 512.0, xi: -0.2, alpha: 0.6}
//!
//! projection: dual_fisheye
//! image_size: [3840, 1920]
//! lenses:                                # exactly two: [0] left half, [1] right half
//!   - projection: kannala_brandt
//!     intrinsics: {fx: 610, fy: 610, cx: 960, cy: 960, k1: 0.02, k2: 0, k3: 0, k4: 0}
//!     cam_from_lens: {translation: [0.01, 0, 0], rotation_rpy: [-1.5707963, 0, -1.5707963]}
//!   - ...
//! ```
//!
//! Intrinsics per model: `double_sphere` fx fy cx cy xi alpha; `kannala_brandt` fx fy cx cy
//! k1 k2 k3 k4; `eucm` fx fy cx cy alpha beta. Principal points are in full-image pixels.

use super::fields::{parse_pose, pose_to_raw, Ctx, RawPose};
use crate::geometry::camera::{
    DoubleSphere, DualFisheye, DualLens, Eucm, FisheyeCamera, FisheyeLens, Focal, ImageSize,
    IntrinsicsError, KannalaBrandt, DUAL_FISHEYE_LENSES,
};
use crate::geometry::rig::{Projection, RigError};
use serde::{Deserialize, Serialize};

/// The projection names the rig YAML accepts.
pub const PROJECTION_NAMES: [&str; 5] = [
    "equirectangular",
    DoubleSphere::NAME,
    KannalaBrandt::NAME,
    Eucm::NAME,
    DualFisheye::NAME,
];

/// The single-lens model names (allowed as a dual-fisheye lens's `projection`).
const LENS_NAMES: [&str; 3] = [DoubleSphere::NAME, KannalaBrandt::NAME, Eucm::NAME];

/// Intrinsics as written in the YAML: every parameter any model uses, each optional.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawIntrinsics {
    #[serde(skip_serializing_if = "Option::is_none")]
    fx: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    fy: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    cx: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    cy: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    xi: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    alpha: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    beta: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k1: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k2: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k3: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k4: Option<f64>,
}

/// One lens of a dual-fisheye camera as written in the YAML.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawLens {
    projection: Option<String>,
    intrinsics: Option<RawIntrinsics>,
    cam_from_lens: Option<RawPose>,
}

/// The projection-related fields of one camera in the YAML.
pub(super) struct RawProjection<'a> {
    pub projection: Option<&'a str>,
    pub image_size: Option<&'a [f64]>,
    pub intrinsics: Option<&'a RawIntrinsics>,
    pub lenses: Option<&'a [RawLens]>,
}

/// The same fields, owned, for writing YAML.
pub(super) struct RawProjectionOut {
    pub projection: String,
    pub image_size: Option<Vec<f64>>,
    pub intrinsics: Option<RawIntrinsics>,
    pub lenses: Option<Vec<RawLens>>,
}

fn intrinsics_err(ctx: &Ctx, prefix: &str, e: IntrinsicsError) -> RigError {
    ctx.err(&format!("{prefix}{}", e.field), e.problem)
}

fn parse_image_size(ctx: &Ctx, raw: Option<&[f64]>) -> Result<ImageSize, RigError> {
    let field = "image_size";
    let v = raw.ok_or_else(|| ctx.err(field, "missing (give [width, height] in pixels)"))?;
    if v.len() != 2 {
        return Err(ctx.err(
            field,
            format!("expected [width, height], got {} numbers", v.len()),
        ));
    }
    let side = |x: f64| -> Result<u32, RigError> {
        if x.is_finite() && x.fract() == 0.0 && x > 0.0 && x <= u32::MAX as f64 {
            Ok(x as u32)
        } else {
            Err(ctx.err(
                field,
                format!("{x} is not a positive whole number of pixels"),
            ))
        }
    };
    ImageSize::new(side(v[0])?, side(v[1])?).map_err(|e| intrinsics_err(ctx, "", e))
}

/// The parameters each model reads, in the order its constructor takes them.
fn model_fields(model: &str) -> &'static [&'static str] {
    match model {
        DoubleSphere::NAME => &["fx", "fy", "cx", "cy", "xi", "alpha"],
        KannalaBrandt::NAME => &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"],
        _ => &["fx", "fy", "cx", "cy", "alpha", "beta"],
    }
}

/// A single-lens model from its YAML intrinsics; `prefix` is the path of the intrinsics
/// mapping (`intrinsics.` or `lenses[0].intrinsics.`).
fn parse_lens(
    ctx: &Ctx,
    prefix: &str,
    model: &str,
    raw: Option<&RawIntrinsics>,
) -> Result<FisheyeLens, RigError> {
    let map_name = prefix.trim_end_matches('.');
    let raw = raw.ok_or_else(|| {
        ctx.err(
            map_name,
            format!("missing ({model} needs {})", model_fields(model).join(" ")),
        )
    })?;
    let all = [
        ("fx", raw.fx),
        ("fy", raw.fy),
        ("cx", raw.cx),
        ("cy", raw.cy),
        ("xi", raw.xi),
        ("alpha", raw.alpha),
        ("beta", raw.beta),
        ("k1", raw.k1),
        ("k2", raw.k2),
        ("k3", raw.k3),
        ("k4", raw.k4),
    ];
    let wanted = model_fields(model);
    if let Some((name, _)) = all.iter().find(|(n, v)| v.is_some() && !wanted.contains(n)) {
        return Err(ctx.err(
            &format!("{prefix}{name}"),
            format!("not a parameter of {model} (it takes {})", wanted.join(" ")),
        ));
    }
    let get = |name: &str| -> Result<f64, RigError> {
        all.iter()
            .find(|(n, _)| *n == name)
            .and_then(|(_, v)| *v)
            .ok_or_else(|| ctx.err(&format!("{prefix}{name}"), "missing"))
    };
    let ie = |e| intrinsics_err(ctx, prefix, e);
    let focal = Focal::new(get("fx")?, get("fy")?, get("cx")?, get("cy")?).map_err(ie)?;
    Ok(match model {
        DoubleSphere::NAME => FisheyeLens::DoubleSphere(
            DoubleSphere::new(focal, get("xi")?, get("alpha")?).map_err(ie)?,
        ),
        KannalaBrandt::NAME => FisheyeLens::KannalaBrandt(
            KannalaBrandt::new(focal, [get("k1")?, get("k2")?, get("k3")?, get("k4")?])
                .map_err(ie)?,
        ),
        _ => FisheyeLens::Eucm(Eucm::new(focal, get("alpha")?, get("beta")?).map_err(ie)?),
    })
}

/// The projection name of a camera: as given, or `equirectangular` when the camera has none
/// of the fisheye fields (with one of them present, the projection is what is missing).
fn projection_name<'a>(ctx: &Ctx, raw: &RawProjection<'a>) -> Result<&'a str, RigError> {
    // No projection means equirectangular, which takes none of the fisheye fields: with one of
    // them present, the projection is what is missing.
    let fisheye_field = [
        ("image_size", raw.image_size.is_some()),
        ("intrinsics", raw.intrinsics.is_some()),
        ("lenses", raw.lenses.is_some()),
    ]
    .into_iter()
    .find_map(|(f, present)| present.then_some(f));
    match (raw.projection, fisheye_field) {
        (Some(name), _) => Ok(name),
        (None, None) => Ok("equirectangular"),
        (None, Some(f)) => Err(ctx.err(
            "projection",
            format!(
                "missing, but the camera has {f}, which only fisheye projections take: give projection: {} (without projection and fisheye fields a camera is equirectangular)",
                PROJECTION_NAMES[1..].join(", ")
            ),
        )),
    }
}

/// An error when `field` is `present` but projection `name` does not use it.
fn refuse_unused_field(ctx: &Ctx, name: &str, field: &str, present: bool) -> Result<(), RigError> {
    if present {
        Err(ctx.err(field, format!("not used by projection {name}")))
    } else {
        Ok(())
    }
}

/// The camera's projection from its YAML fields.
pub(super) fn parse_projection(ctx: &Ctx, raw: &RawProjection) -> Result<Projection, RigError> {
    let name = projection_name(ctx, raw)?;
    let refuse_extra = |field: &str, present: bool| refuse_unused_field(ctx, name, field, present);
    match name {
        "equirectangular" => {
            refuse_extra("image_size", raw.image_size.is_some())?;
            refuse_extra("intrinsics", raw.intrinsics.is_some())?;
            refuse_extra("lenses", raw.lenses.is_some())?;
            Ok(Projection::Equirectangular)
        }
        DualFisheye::NAME => {
            refuse_extra("intrinsics", raw.intrinsics.is_some())?;
            parse_dual_fisheye(ctx, raw)
        }
        model if LENS_NAMES.contains(&model) => {
            refuse_extra("lenses", raw.lenses.is_some())?;
            let size = parse_image_size(ctx, raw.image_size)?;
            let lens = parse_lens(ctx, "intrinsics.", model, raw.intrinsics)?;
            FisheyeCamera::new(lens, size)
                .map(Projection::Fisheye)
                .map_err(|e| intrinsics_err(ctx, "intrinsics.", e))
        }
        other => Err(ctx.err(
            "projection",
            format!(
                "unsupported projection '{other}' (supported: {})",
                PROJECTION_NAMES.join(", ")
            ),
        )),
    }
}

/// A `dual_fisheye` camera: its image size and exactly [`DUAL_FISHEYE_LENSES`] lenses.
fn parse_dual_fisheye(ctx: &Ctx, raw: &RawProjection) -> Result<Projection, RigError> {
    let size = parse_image_size(ctx, raw.image_size)?;
    let lenses = raw
        .lenses
        .ok_or_else(|| ctx.err("lenses", "missing (dual_fisheye needs two lenses)"))?;
    if lenses.len() != DUAL_FISHEYE_LENSES {
        return Err(ctx.err(
            "lenses",
            format!(
                "dual_fisheye needs exactly {DUAL_FISHEYE_LENSES} lenses (left half, right half), found {}",
                lenses.len()
            ),
        ));
    }
    let mut parsed = Vec::with_capacity(DUAL_FISHEYE_LENSES);
    for (i, l) in lenses.iter().enumerate() {
        parsed.push(parse_dual_lens(ctx, i, l)?);
    }
    let [a, b]: [DualLens; DUAL_FISHEYE_LENSES] = parsed
        .try_into()
        .map_err(|_| ctx.err("lenses", "expected two lenses"))?;
    DualFisheye::new([a, b], size)
        .map(Projection::DualFisheye)
        .map_err(|e| intrinsics_err(ctx, "", e))
}

/// Lens `i` of a dual-fisheye camera: its single-lens model, intrinsics and `cam_from_lens`.
fn parse_dual_lens(ctx: &Ctx, i: usize, l: &RawLens) -> Result<DualLens, RigError> {
    let at = format!("lenses[{i}]");
    let model = l
        .projection
        .as_deref()
        .ok_or_else(|| ctx.err(&format!("{at}.projection"), "missing"))?;
    if !LENS_NAMES.contains(&model) {
        return Err(ctx.err(
            &format!("{at}.projection"),
            format!(
                "'{model}' is not a lens model (use one of {})",
                LENS_NAMES.join(", ")
            ),
        ));
    }
    let model = parse_lens(
        ctx,
        &format!("{at}.intrinsics."),
        model,
        l.intrinsics.as_ref(),
    )?;
    let pose = l
        .cam_from_lens
        .as_ref()
        .ok_or_else(|| ctx.err(&format!("{at}.cam_from_lens"), "missing"))?;
    let cam_from_lens = parse_pose(ctx, &format!("{at}.cam_from_lens"), pose)?;
    Ok(DualLens {
        model,
        cam_from_lens,
    })
}

fn lens_to_raw(lens: &FisheyeLens) -> RawIntrinsics {
    let f = lens.focal();
    let mut raw = RawIntrinsics {
        fx: Some(f.fx),
        fy: Some(f.fy),
        cx: Some(f.cx),
        cy: Some(f.cy),
        ..Default::default()
    };
    match lens {
        FisheyeLens::DoubleSphere(m) => {
            raw.xi = Some(m.xi());
            raw.alpha = Some(m.alpha());
        }
        FisheyeLens::KannalaBrandt(m) => {
            let [k1, k2, k3, k4] = m.coefficients();
            (raw.k1, raw.k2, raw.k3, raw.k4) = (Some(k1), Some(k2), Some(k3), Some(k4));
        }
        FisheyeLens::Eucm(m) => {
            raw.alpha = Some(m.alpha());
            raw.beta = Some(m.beta());
        }
    }
    raw
}

/// The YAML fields of a projection (the form [`parse_projection`] reads).
pub(super) fn projection_to_raw(p: &Projection) -> RawProjectionOut {
    use crate::geometry::camera::CameraModel;
    let size = |s: crate::geometry::camera::ImageSize| Some(vec![s.width as f64, s.height as f64]);
    match p {
        Projection::Equirectangular => RawProjectionOut {
            projection: "equirectangular".into(),
            image_size: None,
            intrinsics: None,
            lenses: None,
        },
        Projection::Fisheye(cam) => RawProjectionOut {
            projection: cam.lens().name().into(),
            image_size: size(cam.image_size()),
            intrinsics: Some(lens_to_raw(cam.lens())),
            lenses: None,
        },
        Projection::DualFisheye(d) => RawProjectionOut {
            projection: DualFisheye::NAME.into(),
            image_size: size(d.image_size()),
            intrinsics: None,
            lenses: Some(
                d.lenses()
                    .iter()
                    .map(|l| RawLens {
                        projection: Some(l.model.name().into()),
                        intrinsics: Some(lens_to_raw(&l.model)),
                        cam_from_lens: Some(pose_to_raw(&l.cam_from_lens)),
                    })
                    .collect(),
            ),
        },
    }
}
