//! Calibration drift and `rig refine` on rendered bags: camera 2 of the Deep360 rig turned by
//! 1 degree after calibration. Replayed with the original calibration, `/diagnostics` names
//! camera 2 WARN with "calibration" and the turn in degrees, and no other camera; replayed with
//! the right calibration, no camera is warned. `rig refine` recovers the turn (to 0.25 degrees
//! here; the 0.1 is not met with the sweep's depth), leaves the other cameras, and
//! replaying with its file scores like the true calibration.

use crate::common::{TestResult, RIG_PATH};
use mode360::bag::BagReader;
use mode360::cli::replay::{replay_bag, ReplayOptions};
use mode360::cli::rig::refine::{refine, RigRefineArgs, REFINE_PASSES};
use mode360::cli::rig::write_rig;
use mode360::estimator::{EstimatorKind, EstimatorSpec};
use mode360::geometry::Rig;
use mode360::msgs::{DiagnosticArray, DiagnosticStatus};
use mode360::node::diagnostics::diagnostic_value;
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::SynthConfig;
use nalgebra::{UnitQuaternion, Vector3};
use std::path::Path;

const WIDTH: usize = 256;
/// Held-out world (top bit set).
const SEED: u64 = (1 << 63) + 2126;
/// The knocked camera (rig order) and its turn: 1 degree about an oblique rig axis.
const KNOCKED: usize = 1;
const KNOCK_DEG: f64 = 1.0;
/// The drift check's warning must name a turn this close to the truth, degrees.
const DRIFT_TOLERANCE_DEG: f64 = 0.4;
/// `rig refine` must recover the turn to this, degrees (issue 21's target; measured 0.055 with
/// the sweep's depth at 256 wide, 0.01 with true depth: docs/commands.md, rig refine).
const REFINE_TOLERANCE_DEG: f64 = 0.1;
/// The cameras that were not knocked may be turned at most this much, degrees.
const UNKNOCKED_TOLERANCE_DEG: f64 = 0.1;
/// Replaying with the refined calibration must score this close to the true one, δ1 points.
const REFINED_DELTA1_TOLERANCE: f64 = 0.5;

fn knock_axis() -> Vector3<f64> {
    Vector3::new(0.3, -0.5, 0.8).normalize()
}

/// The Deep360 rig with camera `KNOCKED` turned by `KNOCK_DEG` about `knock_axis()` (rig axes).
fn knocked_rig(rig: &Rig) -> Rig {
    knocked_by(rig, knock_axis(), KNOCK_DEG)
}

/// `rig` with camera `KNOCKED` turned by `deg` about `axis` (rig axes, unit).
fn knocked_by(rig: &Rig, axis: Vector3<f64>, deg: f64) -> Rig {
    let mut out = rig.clone();
    let cam = &mut out.cameras[KNOCKED];
    let turn = UnitQuaternion::from_scaled_axis(axis * deg.to_radians());
    cam.rig_from_cam.rotation = turn * cam.rig_from_cam.rotation;
    out
}

fn render(rig: &Rig, frames: usize, out: &Path) -> TestResult {
    record_synthetic_bag(&RecordOptions {
        rig: rig.clone(),
        config: SynthConfig {
            seed: SEED,
            width: WIDTH,
            ..Default::default()
        },
        frames,
        first_frame: 20,
        out: out.to_path_buf(),
        show_progress: false,
    })?;
    Ok(())
}

/// Replays `input` with the calibration in `rig_file` (the bag's own when `None`); returns
/// the last `/diagnostics` and the δ1 against ground truth.
fn replay(
    input: &Path,
    output: &Path,
    rig_file: Option<&Path>,
) -> Result<(DiagnosticArray, f64), Box<dyn std::error::Error>> {
    let summary = replay_bag(&ReplayOptions {
        input: input.to_path_buf(),
        output: output.to_path_buf(),
        estimator: EstimatorSpec::new(EstimatorKind::Photometric),
        output_width: None,
        max_depth_m: None,
        max_frames: None,
        rig: rig_file.map(Path::to_path_buf),
    })?;
    let delta1 = summary
        .metrics
        .as_ref()
        .ok_or("no metrics against ground truth")?
        .delta1_pct;
    let last = BagReader::open(output)?
        .decode_topic::<DiagnosticArray>("/diagnostics")?
        .pop()
        .ok_or("no /diagnostics")?;
    Ok((last, delta1))
}

fn camera_status<'a>(diag: &'a DiagnosticArray, name: &str) -> &'a DiagnosticStatus {
    let key = format!("mode360: camera {name}");
    diag.status
        .iter()
        .find(|s| s.name == key)
        .unwrap_or_else(|| panic!("no status for {key}"))
}

#[test]
fn a_knocked_camera_is_warned_by_name_and_refined() -> TestResult {
    let dir = tempfile::tempdir()?;
    let rig = Rig::from_file(RIG_PATH)?;
    let calibration = dir.path().join("calibration.yaml");
    write_rig(&rig, &calibration)?;
    let knocked = dir.path().join("knocked.mcap");
    // 9 frames: the drift check runs on frames 0, 3 and 6 and takes the median of the three.
    render(&knocked_rig(&rig), 9, &knocked)?;

    // Replayed with the calibration the camera had before the knock: camera 2 is warned.
    let (diag, delta1_stale) =
        replay(&knocked, &dir.path().join("stale.mcap"), Some(&calibration))?;
    for (c, cam) in rig.cameras.iter().enumerate() {
        let status = camera_status(&diag, &cam.name);
        let correction: f64 = diagnostic_value(&diag, &status.name, "calibration_correction_deg")
            .ok_or("no calibration_correction_deg")?
            .parse()?;
        if c == KNOCKED {
            assert_eq!(status.level, DiagnosticStatus::WARN, "{status:?}");
            assert!(status.message.contains("calibration"), "{status:?}");
            assert!(
                (correction - KNOCK_DEG).abs() <= DRIFT_TOLERANCE_DEG,
                "{}: correction {correction} deg",
                cam.name
            );
        } else {
            assert!(!status.message.contains("calibration"), "{status:?}");
        }
    }

    // Replayed with its own (true) calibration: nobody is warned.
    let (diag, delta1_true) = replay(&knocked, &dir.path().join("true.mcap"), None)?;
    for cam in &rig.cameras {
        let status = camera_status(&diag, &cam.name);
        assert_eq!(status.level, DiagnosticStatus::OK, "{status:?}");
    }

    // rig refine from the stale calibration recovers the turn.
    let summary = refine(&RigRefineArgs {
        bag: knocked.clone(),
        out: dir.path().join("refined.yaml"),
        rig: Some(calibration.clone()),
        frames: 6,
        passes: REFINE_PASSES,
    })?;
    let truth = knock_axis() * KNOCK_DEG.to_radians();
    let found = &summary.corrections[KNOCKED];
    let error_deg = (found.rotation_vector_rig - truth).norm().to_degrees();
    eprintln!("refine: the knocked camera off by {error_deg:.3} deg");
    assert!(
        error_deg <= REFINE_TOLERANCE_DEG,
        "refine off by {error_deg} deg: {found:?}"
    );
    for (c, other) in summary.corrections.iter().enumerate() {
        if c != KNOCKED {
            assert!(other.angle_deg <= UNKNOCKED_TOLERANCE_DEG, "{other:?}");
        }
    }
    let refined = dir.path().join("refined.yaml");
    write_rig(&summary.rig, &refined)?;
    let (_, delta1_refined) = replay(&knocked, &dir.path().join("refined.mcap"), Some(&refined))?;
    assert!(
        (delta1_refined - delta1_true).abs() <= REFINED_DELTA1_TOLERANCE,
        "δ1 refined {delta1_refined} vs true {delta1_true} (stale {delta1_stale})"
    );
    assert!(
        delta1_stale < delta1_true,
        "stale {delta1_stale} vs true {delta1_true}"
    );
    Ok(())
}

#[test]
fn rig_refine_refuses_too_few_frames_and_a_foreign_rig() -> TestResult {
    let dir = tempfile::tempdir()?;
    let rig = Rig::from_file(RIG_PATH)?;
    let bag = dir.path().join("two.mcap");
    render(&rig, 2, &bag)?;
    let args_passes = |frames: usize, rig_file: Option<&Path>, passes: usize| RigRefineArgs {
        bag: bag.clone(),
        out: dir.path().join("out.yaml"),
        rig: rig_file.map(Path::to_path_buf),
        frames,
        passes,
    };
    let args =
        |frames: usize, rig_file: Option<&Path>| args_passes(frames, rig_file, REFINE_PASSES);
    let err = refine(&args(6, None))
        .err()
        .ok_or("6 frames from a 2-frame bag")?;
    let text = format!("{err:#}");
    assert!(
        text.contains("2 readable frame(s)") && text.contains("asked for 6"),
        "{text}"
    );
    let err = refine(&args(1, None)).err().ok_or("1 frame")?;
    assert!(format!("{err:#}").contains("at least 2 frames"), "{err:#}");
    let err = refine(&args_passes(2, None, 0)).err().ok_or("0 passes")?;
    assert!(format!("{err:#}").contains("--passes 0"), "{err:#}");
    // A calibration whose second camera has another name.
    let mut foreign = rig.clone();
    foreign.cameras[1].name = "front_left".to_string();
    let foreign_file = dir.path().join("foreign.yaml");
    write_rig(&foreign, &foreign_file)?;
    let err = refine(&args(2, Some(&foreign_file)))
        .err()
        .ok_or("a rig of other cameras")?;
    let text = format!("{err:#}");
    assert!(
        text.contains("front_left") || text.contains("cam2"),
        "{text}"
    );
    assert!(!dir.path().join("out.yaml").exists());
    Ok(())
}

/// A knock larger than the drift check's first two Newton steps can reach (2 x 0.5 degree per
/// axis, about one rig axis) is read at its size: the check keeps stepping while its steps hit
/// the clamp. Before it did, a 2-degree roll read 1.00 degree (measured 1.92 since).
#[test]
fn a_two_degree_knock_is_read_at_its_size() -> TestResult {
    const BIG_KNOCK_DEG: f64 = 2.0;
    /// The correction the warning names must be this close to the knock, degrees.
    const BIG_KNOCK_TOLERANCE_DEG: f64 = 0.4;
    let dir = tempfile::tempdir()?;
    let rig = Rig::from_file(RIG_PATH)?;
    let calibration = dir.path().join("calibration.yaml");
    write_rig(&rig, &calibration)?;
    let knocked = dir.path().join("rolled.mcap");
    render(&knocked_by(&rig, Vector3::x(), BIG_KNOCK_DEG), 9, &knocked)?;
    let (diag, _) = replay(&knocked, &dir.path().join("stale.mcap"), Some(&calibration))?;
    let status = camera_status(&diag, &rig.cameras[KNOCKED].name);
    assert_eq!(status.level, DiagnosticStatus::WARN, "{status:?}");
    let correction: f64 = diagnostic_value(&diag, &status.name, "calibration_correction_deg")
        .ok_or("no calibration_correction_deg")?
        .parse()?;
    assert!(
        (correction - BIG_KNOCK_DEG).abs() <= BIG_KNOCK_TOLERANCE_DEG,
        "a {BIG_KNOCK_DEG} degree roll read as {correction} degree"
    );
    Ok(())
}
