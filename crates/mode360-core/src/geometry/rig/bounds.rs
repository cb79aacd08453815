//! Values no calibration means: bounds on focal lengths, distortion parameters, translations
//! and roll-pitch-yaw angles, beyond the models' own validity ranges. [`super::Rig::new`]
//! applies them to every rig; the rig YAML and calibration importers apply them first, under
//! their files' own field names. Principal points are bounded by the image already
//! ([`crate::geometry::camera::FisheyeCamera::new`]).

use crate::geometry::camera::{FisheyeLens, IntrinsicsError};
use nalgebra::Vector3;

/// The smallest focal length accepted, pixels.
pub const MIN_FOCAL_PX: f64 = 1e-3;
/// The largest focal length accepted, pixels (a 1 km lens on a 1 µm pixel).
pub const MAX_FOCAL_PX: f64 = 1e6;
/// The largest magnitude of a distortion parameter: Kannala-Brandt `k1..k4` and EUCM `beta`
/// (real lenses stay within about 10).
pub const MAX_DISTORTION_ABS: f64 = 1e3;
/// The farthest a camera, lens or output frame may sit from its parent frame's origin, metres.
pub const MAX_TRANSLATION_M: f64 = 1e3;
/// The largest roll, pitch or yaw accepted, radians: one turn. A larger value is a mistake
/// (often degrees written for radians).
pub const MAX_RPY_ABS_RAD: f64 = std::f64::consts::TAU;

/// `v` for a message: plain for ordinary magnitudes, in exponent form for huge or tiny ones
/// (`1e308`, not 309 digits).
pub fn num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e7).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `Err` naming `field` unless `v` is a focal length in `[MIN_FOCAL_PX, MAX_FOCAL_PX]`.
pub fn check_focal(field: &str, v: f64) -> Result<(), IntrinsicsError> {
    if !(MIN_FOCAL_PX..=MAX_FOCAL_PX).contains(&v) {
        return Err(IntrinsicsError::new(
            field,
            format!(
                "focal length {} px is outside the plausible range [{MIN_FOCAL_PX}, {MAX_FOCAL_PX}] px",
                num(v)
            ),
        ));
    }
    Ok(())
}

/// `Err` naming `field` unless `|v| <= MAX_DISTORTION_ABS`.
pub fn check_distortion(field: &str, v: f64) -> Result<(), IntrinsicsError> {
    if !(-MAX_DISTORTION_ABS..=MAX_DISTORTION_ABS).contains(&v) {
        return Err(IntrinsicsError::new(
            field,
            format!(
                "{} is outside the plausible range [-{MAX_DISTORTION_ABS}, {MAX_DISTORTION_ABS}]",
                num(v)
            ),
        ));
    }
    Ok(())
}

/// A lens's focal lengths and distortion parameters within the bounds; the error names the
/// parameter (`fx`, `k3`, `beta`).
pub fn check_lens(lens: &FisheyeLens) -> Result<(), IntrinsicsError> {
    let f = lens.focal();
    check_focal("fx", f.fx)?;
    check_focal("fy", f.fy)?;
    match lens {
        FisheyeLens::KannalaBrandt(m) => {
            for (i, k) in m.coefficients().iter().enumerate() {
                check_distortion(&format!("k{}", i + 1), *k)?;
            }
        }
        FisheyeLens::Eucm(m) => check_distortion("beta", m.beta())?,
        FisheyeLens::DoubleSphere(_) => {}
    }
    Ok(())
}

/// `Err` (the problem, for the caller's field) unless the translation is finite and within
/// [`MAX_TRANSLATION_M`] of the origin.
pub fn check_translation(t: &Vector3<f64>) -> Result<(), String> {
    // Scaled by the largest component first, so that 1e308 m is not an overflow to inf.
    let m = t.amax();
    let n = if !t.iter().all(|v| v.is_finite()) {
        f64::INFINITY
    } else if m == 0.0 {
        0.0
    } else {
        m * (t / m).norm()
    };
    if !(0.0..=MAX_TRANSLATION_M).contains(&n) {
        return Err(format!(
            "translation [{}, {}, {}] is {} m from the origin, more than the plausible {MAX_TRANSLATION_M} m",
            num(t.x),
            num(t.y),
            num(t.z),
            num(n)
        ));
    }
    Ok(())
}

/// `Err` naming `field` unless `|angle| <= MAX_RPY_ABS_RAD`.
pub fn check_rpy(field: &str, angles: &[f64]) -> Result<(), IntrinsicsError> {
    if let Some(a) = angles
        .iter()
        .find(|a| !(-MAX_RPY_ABS_RAD..=MAX_RPY_ABS_RAD).contains(*a))
    {
        return Err(IntrinsicsError::new(
            field,
            format!(
                "angle {} rad is outside [-{MAX_RPY_ABS_RAD:.6}, {MAX_RPY_ABS_RAD:.6}] (one turn; angles are in radians)",
                num(*a)
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_name_the_bound() {
        assert!(check_focal("fx", 350.0).is_ok());
        for bad in [1e-300, 1e308, 0.0, -1.0, f64::NAN] {
            let e = check_focal("fx", bad).unwrap_err();
            assert_eq!(e.field, "fx");
            assert!(e.problem.contains("[0.001, 1000000] px"), "{e}");
        }
        assert!(check_distortion("k1", -0.3).is_ok());
        let e = check_distortion("k1", 1e10).unwrap_err();
        assert!(e.problem.contains("[-1000, 1000]"), "{e}");
        assert!(check_translation(&Vector3::new(0.5, -0.2, 1.8)).is_ok());
        let e = check_translation(&Vector3::new(1e308, 0.0, 0.0)).unwrap_err();
        assert!(e.contains("1000 m") && e.contains("is 1e308 m"), "{e}");
        assert_eq!(num(1e-300), "1e-300");
        assert_eq!(num(350.5), "350.5");
        assert!(check_translation(&Vector3::new(f64::INFINITY, 0.0, 0.0)).is_err());
        assert!(check_rpy(
            "r",
            &[-std::f64::consts::FRAC_PI_2, 0.0, std::f64::consts::PI]
        )
        .is_ok());
        let e = check_rpy("r", &[1e300, 0.0, 0.0]).unwrap_err();
        assert!(e.problem.contains("6.283185"), "{e}");
    }
}
