//! The lens check on rendered frames (held-out world seeds, the Deep360 rig at 256x128, the
//! photometric sweep's estimate as depth, as in the node): a blocked lens is named with its
//! blocked fraction, clean and soiled-but-clear lenses read clean, a two-camera rig cannot
//! tell and reads clean.

use crate::common::deep360_rig;
use mode360::estimator::lens_health::{lens_votes, LensHealth, LensHealthAccumulator};
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::DepthEstimator;
use mode360::geometry::{ErpGrid, Rig};
use mode360::synth::blockers::{BlockedLens, BlockerKind};
use mode360::synth::{SynthConfig, SynthRenderer};

const WIDTH: usize = 256;
const FRAMES: usize = 3;
/// A world seed with the top bit set: never drawn by training.
const SEED: u64 = (1 << 63) + 2121;
/// Issue 21's bounds: the blocked fraction within this of the truth...
const BLOCKED_TOLERANCE: f64 = 0.1;
/// ...and clean or soiled-but-clear lenses below this.
const CLEAN_MAX: f64 = 0.05;

/// Each camera's health over `FRAMES` frames of `cfg`, and the true blocked fractions.
fn check(rig: &Rig, cfg: SynthConfig) -> (Vec<LensHealth>, Vec<f64>) {
    let renderer = SynthRenderer::new(cfg).expect("synth config");
    let truth = renderer.blocked_fractions(rig);
    let mut sweep = PhotometricSweep::new(PhotometricConfig::default()).expect("sweep");
    let grid = ErpGrid::new(WIDTH).expect("grid");
    let mut acc = LensHealthAccumulator::default();
    for i in 0..FRAMES {
        let frame = renderer.render_frame(rig, 60 + i);
        let estimate = sweep.estimate(rig, &frame.images, grid).expect("estimate");
        acc.add(&lens_votes(rig, &frame.images, &estimate.range_m).expect("votes"));
    }
    (acc.health(), truth)
}

fn config(soiled: bool, blockers: Vec<BlockedLens>) -> SynthConfig {
    SynthConfig {
        seed: SEED,
        width: WIDTH,
        soiled,
        blockers,
        ..Default::default()
    }
}

#[test]
fn a_blocked_lens_is_named_with_its_fraction_and_the_others_read_clean() {
    let rig = deep360_rig();
    for (camera, fraction, kind) in [
        (2, 1.0 / 3.0, BlockerKind::Mud),
        (1, 0.25, BlockerKind::Vehicle),
    ] {
        let blocker = BlockedLens {
            camera,
            fraction,
            kind,
        };
        let (health, truth) = check(&rig, config(false, vec![blocker]));
        for (c, (h, t)) in health.iter().zip(&truth).enumerate() {
            if c == camera {
                assert!(
                    (h.blocked_fraction - t).abs() <= BLOCKED_TOLERANCE,
                    "{kind:?} on camera {}: found {:.3}, truth {t:.3}",
                    c + 1,
                    h.blocked_fraction
                );
                assert!(h.region.is_some(), "no region named: {h:?}");
            } else {
                assert!(
                    h.blocked_fraction < CLEAN_MAX,
                    "{kind:?} on camera {}: clean camera {} reads {:.3}",
                    camera + 1,
                    c + 1,
                    h.blocked_fraction
                );
            }
        }
    }
}

#[test]
fn clean_and_soiled_but_clear_lenses_read_clean() {
    let rig = deep360_rig();
    for soiled in [false, true] {
        let (health, _) = check(&rig, config(soiled, Vec::new()));
        for (c, h) in health.iter().enumerate() {
            assert!(
                h.blocked_fraction < CLEAN_MAX,
                "soiled {soiled}: camera {} reads {:.3}",
                c + 1,
                h.blocked_fraction
            );
            assert!(h.decided_fraction > 0.9, "camera {}: {h:?}", c + 1);
        }
    }
}

#[test]
fn two_cameras_cannot_tell_which_lens_is_blocked() {
    let rig = deep360_rig().subset(&[0, 2]).expect("pair");
    let blocker = BlockedLens {
        camera: 1,
        fraction: 1.0 / 3.0,
        kind: BlockerKind::Mud,
    };
    let (health, _) = check(&rig, config(false, vec![blocker]));
    for h in &health {
        assert_eq!(h.blocked_fraction, 0.0, "{h:?}");
        assert_eq!(h.decided_fraction, 0.0, "{h:?}");
    }
}
