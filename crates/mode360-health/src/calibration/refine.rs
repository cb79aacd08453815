//! [`refine_rotations`]: the rig's rotations corrected camera by camera.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};

use super::check::RotationCheck;
use super::frame::CheckFrame;
use super::{CameraCorrection, RotationCheckConfig, MIN_KEEP_GAIN, MIN_REFINE_GAIN};
use mode360_core::geometry::Rig;
use mode360_estimator::EstimatorError;

/// `rig` with each correction applied: camera `c`'s rotation becomes `Q_c R_c`.
pub fn apply_corrections(rig: &Rig, corrections: &[CameraCorrection]) -> Rig {
    let mut out = rig.clone();
    for corr in corrections {
        if let Some(cam) = out.cameras.get_mut(corr.camera) {
            cam.rig_from_cam = Isometry3::from_parts(
                cam.rig_from_cam.translation,
                corr.rotation_rig() * cam.rig_from_cam.rotation,
            );
        }
    }
    out
}

/// Corrects the rig's rotations camera by camera: each round finds every camera's best
/// correction against the others and applies the one that raises the agreement most, until
/// no correction is larger than the search's last step or gains [`MIN_REFINE_GAIN`]. The
/// reference camera is never turned: turning every camera alike changes little that the
/// images show, so the others are aligned to it (as a calibration tool anchors camera 0).
/// Returns the refined rig and each camera's total correction (rig axes).
pub fn refine_rotations(
    rig: &Rig,
    frames: &[CheckFrame],
    cfg: &RotationCheckConfig,
) -> Result<(Rig, Vec<CameraCorrection>), EstimatorError> {
    let n = rig.cameras.len();
    let mut current = rig.clone();
    let mut total: Vec<UnitQuaternion<f64>> = vec![UnitQuaternion::identity(); n];
    let mut last = Vec::new();
    for _round in 0..n {
        let check = RotationCheck::new(&current, cfg.clone())?;
        let corrections = check.corrections(frames)?;
        let best = corrections
            .iter()
            .filter(|c| c.camera != rig.reference)
            .max_by(|a, b| a.gain().total_cmp(&b.gain()))
            .cloned();
        last = corrections;
        let Some(best) = best else { break };
        if best.angle_deg < cfg.min_step_deg || best.gain() < MIN_REFINE_GAIN {
            break;
        }
        total[best.camera] = best.rotation_rig() * total[best.camera];
        current = apply_corrections(&current, std::slice::from_ref(&best));
    }
    let before_check = RotationCheck::new(rig, cfg.clone())?;
    let after_check = RotationCheck::new(&current, cfg.clone())?;
    let mut summary = Vec::with_capacity(n);
    for (c, q) in total.iter().enumerate() {
        let w = q.scaled_axis();
        let before = before_check.agreement_of(frames, c, &Vector3::zeros())?;
        let after = after_check.agreement_of(frames, c, &Vector3::zeros())?;
        let cells = last.iter().find(|x| x.camera == c).map_or(0, |x| x.cells);
        summary.push(CameraCorrection {
            camera: c,
            name: rig.cameras[c].name.clone(),
            rotation_vector_rig: w,
            angle_deg: w.norm().to_degrees(),
            agreement_before: before,
            agreement_after: after,
            cells,
        });
    }
    Ok((current, summary))
}

/// What keeping each camera's whole correction is worth: for every camera turned between
/// `start` and `refined`, its agreement on `refined` minus its agreement with its own turn
/// undone (the others kept), on the cells of `refined`'s check:
///
/// ```text
/// g_c = A_c(0) - A_c(-w_c),   exp([w_c]x) = R'_c R_c^-1
/// ```
///
/// Cameras not turned get 0.
pub fn correction_gains(
    start: &Rig,
    refined: &Rig,
    frames: &[CheckFrame],
    cfg: &RotationCheckConfig,
) -> Result<Vec<f64>, EstimatorError> {
    gains_of_turns(&turns(start, refined), refined, frames, cfg)
}

/// [`correction_gains`] for the turns `turns` (one per camera, as [`turns`] gives them) that
/// led to `refined`.
fn gains_of_turns(
    turns: &[Vector3<f64>],
    refined: &Rig,
    frames: &[CheckFrame],
    cfg: &RotationCheckConfig,
) -> Result<Vec<f64>, EstimatorError> {
    let check = RotationCheck::new(refined, cfg.clone())?;
    let mut gains = Vec::with_capacity(refined.cameras.len());
    for (c, turn) in turns.iter().enumerate() {
        if turn.norm() == 0.0 {
            gains.push(0.0);
            continue;
        }
        let kept = check.agreement_of(frames, c, &Vector3::zeros())?;
        let undone = check.agreement_of(frames, c, &(-turn))?;
        gains.push(kept - undone);
    }
    Ok(gains)
}

/// `refined` with the corrections that do not earn their keep undone: a camera whose
/// [`correction_gains`] entry is under [`MIN_KEEP_GAIN`] gets its rotation from `start` back.
/// Depth estimated with one camera knocked is slightly wrong near that camera, and the
/// refinement turns cameras that were right by up to a tenth of a degree to fit it; undoing
/// such a turn costs almost nothing, undoing a real correction a great deal. Returns the rig
/// and the gains.
pub fn keep_earned_corrections(
    start: &Rig,
    refined: &Rig,
    frames: &[CheckFrame],
    cfg: &RotationCheckConfig,
) -> Result<(Rig, Vec<f64>), EstimatorError> {
    let turns = turns(start, refined);
    let gains = gains_of_turns(&turns, refined, frames, cfg)?;
    let mut out = refined.clone();
    for (c, (turn, gain)) in turns.iter().zip(&gains).enumerate() {
        if turn.norm() > 0.0 && *gain < MIN_KEEP_GAIN {
            out.cameras[c].rig_from_cam.rotation = start.cameras[c].rig_from_cam.rotation;
        }
    }
    Ok((out, gains))
}

/// Each camera's turn from `start` to `now` (rig axes, radians): `exp([w]x) = R_now R_start^-1`.
pub fn turns(start: &Rig, now: &Rig) -> Vec<Vector3<f64>> {
    now.cameras
        .iter()
        .zip(&start.cameras)
        .map(|(n, s)| (n.rig_from_cam.rotation * s.rig_from_cam.rotation.inverse()).scaled_axis())
        .collect()
}
