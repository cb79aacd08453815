//! The lens check through replay: a rendered bag whose camera 3 is one third blocked by mud
//! replays with camera 3 WARN on `/diagnostics` ("lens looks blocked"), its
//! `blocked_fraction` near the truth, and the clean cameras OK.

use crate::common::{TestResult, RIG_PATH};
use mode360::bag::BagReader;
use mode360::cli::replay::{replay_bag, ReplayOptions};
use mode360::estimator::{EstimatorKind, EstimatorSpec};
use mode360::geometry::Rig;
use mode360::msgs::{DiagnosticArray, DiagnosticStatus};
use mode360::node::diagnostics::diagnostic_value;
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::{BlockedLens, BlockerKind, SynthConfig};

const WIDTH: usize = 256;
const FRAMES: usize = 3;
/// Held-out world (top bit set).
const SEED: u64 = (1 << 63) + 2122;
const BLOCKED_TOLERANCE: f64 = 0.1;
const CLEAN_MAX: f64 = 0.05;

#[test]
fn replay_names_the_blocked_lens_on_diagnostics() -> TestResult {
    let dir = tempfile::tempdir()?;
    let input = dir.path().join("in.mcap");
    let output = dir.path().join("out.mcap");
    let rig = Rig::from_file(RIG_PATH)?;
    let blocker = BlockedLens {
        camera: 2,
        fraction: 1.0 / 3.0,
        kind: BlockerKind::Mud,
    };
    record_synthetic_bag(&RecordOptions {
        rig: rig.clone(),
        config: SynthConfig {
            seed: SEED,
            width: WIDTH,
            blockers: vec![blocker],
            ..Default::default()
        },
        frames: FRAMES,
        first_frame: 60,
        out: input.clone(),
        show_progress: false,
    })?;
    replay_bag(&ReplayOptions {
        input,
        output: output.clone(),
        estimator: EstimatorSpec::new(EstimatorKind::Photometric),
        output_width: None,
        max_depth_m: None,
        max_frames: None,
        rig: None,
    })?;
    let last = BagReader::open(&output)?
        .decode_topic::<DiagnosticArray>("/diagnostics")?
        .pop()
        .ok_or("no /diagnostics")?;
    for (c, cam) in rig.cameras.iter().enumerate() {
        let name = format!("mode360: camera {}", cam.name);
        let status = last
            .status
            .iter()
            .find(|s| s.name == name)
            .ok_or("camera status missing")?;
        let fraction: f64 = diagnostic_value(&last, &name, "blocked_fraction")
            .ok_or("no blocked_fraction")?
            .parse()?;
        // The Deep360 rig's four panoramas let the check decide (nearly) the whole view.
        let decided: f64 = diagnostic_value(&last, &name, "lens_decided_fraction")
            .ok_or("no lens_decided_fraction")?
            .parse()?;
        assert!(
            decided > 0.9 && decided <= 1.0,
            "{}: decided {decided}",
            cam.name
        );
        if c == blocker.camera {
            assert!(
                (fraction - blocker.fraction).abs() <= BLOCKED_TOLERANCE,
                "{}: {fraction}",
                cam.name
            );
            assert_eq!(status.level, DiagnosticStatus::WARN, "{status:?}");
            assert!(status.message.contains("lens looks blocked"), "{status:?}");
        } else {
            assert!(fraction < CLEAN_MAX, "{}: {fraction}", cam.name);
            assert_eq!(status.level, DiagnosticStatus::OK, "{status:?}");
        }
    }
    Ok(())
}
