//! Depth from fisheye rigs (issue 12): the OmniMVS-like rig of `launch_configs/` rendered at
//! half resolution, swept by the photometric estimator through each camera's model; its depth
//! must come from parallax (the same-image rig collapses), and where fewer than two lenses see
//! a direction, SSMODE's confidence is zero.

use crate::common::repo_path;
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::ssmode::{default_weights_path, SsmodeEstimator};
use mode360::estimator::DepthEstimator;
use mode360::frame::RigFrame;
use mode360::geometry::panorama::{cameras_seeing, unseen_part};
use mode360::geometry::{ErpGrid, Rig};
use mode360::metrics::depth_metrics;
use mode360::synth::{StreetStyle, SynthConfig, SynthRenderer};

const WIDTH: usize = 128;
const MAX_DEPTH_M: f64 = 1000.0;
/// Half the rig file's 384 x 384 fisheye images.
const FISHEYE_SCALE: f64 = 0.5;
const SEED: u64 = 4242;
/// Lowest δ1 (%) of the photometric sweep on true views, and highest on same-image views
/// (measured 62.7 and 8.3 %).
const MIN_TRUE_DELTA1_PCT: f64 = 55.0;
const MAX_SAME_IMAGE_DELTA1_PCT: f64 = 30.0;

fn omnimvs_frame() -> (Rig, RigFrame) {
    let rig = Rig::from_file(repo_path("launch_configs/rig_omnimvs.yaml"))
        .unwrap()
        .scaled(FISHEYE_SCALE)
        .unwrap();
    let frame = SynthRenderer::new(SynthConfig {
        seed: SEED,
        width: WIDTH,
        max_depth_m: MAX_DEPTH_M,
        street: StreetStyle::Varied,
        ..Default::default()
    })
    .unwrap()
    .render_frame(&rig, 3);
    (rig, frame)
}

#[test]
fn the_photometric_sweep_ranges_a_fisheye_rig_from_parallax() {
    let (rig, frame) = omnimvs_frame();
    let gt = frame.ground_truth.clone().unwrap();
    let grid = ErpGrid::new(WIDTH).unwrap();
    let mut sweep = PhotometricSweep::new(PhotometricConfig::default()).unwrap();
    let truth = sweep.estimate(&rig, &frame.images, grid).unwrap();
    let same: Vec<_> = (0..frame.images.len())
        .map(|_| frame.images[rig.reference].clone())
        .collect();
    let same = sweep.estimate(&rig, &same, grid).unwrap();
    let m_true = depth_metrics(&truth.range_m.data, &gt.data, MAX_DEPTH_M).unwrap();
    let m_same = depth_metrics(&same.range_m.data, &gt.data, MAX_DEPTH_M).unwrap();
    println!(
        "photometric on the OmniMVS-like rig: delta1 {:.1} % true views, {:.1} % same image",
        m_true.delta1_pct, m_same.delta1_pct
    );
    assert!(m_true.delta1_pct >= MIN_TRUE_DELTA1_PCT, "{m_true:?}");
    assert!(m_same.delta1_pct <= MAX_SAME_IMAGE_DELTA1_PCT, "{m_same:?}");
}

#[test]
fn ssmode_has_no_confidence_where_fewer_than_two_lenses_see() {
    // Keep only the two front fisheyes: the back of the sphere is seen by at most one lens.
    let (rig, frame) = omnimvs_frame();
    let front = rig.subset(&[0, 1]).unwrap();
    let images = vec![frame.images[0].clone(), frame.images[1].clone()];
    let grid = ErpGrid::new(WIDTH).unwrap();
    assert!(unseen_part(&front, grid, 100.0).is_some());
    let mut ssmode = SsmodeEstimator::load(default_weights_path()).unwrap();
    let estimate = ssmode.estimate(&front, &images, grid).unwrap();
    // Directions at 1000 m that both lenses see vs those at most one sees.
    let (mut both, mut poor) = (Vec::new(), Vec::new());
    for (&seen, &c) in cameras_seeing(&front, grid, 1000.0)
        .iter()
        .zip(&estimate.confidence.data)
    {
        if seen == 2 {
            both.push(c);
        } else {
            poor.push(c);
        }
    }
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
    println!(
        "ssmode confidence: {:.3} where both lenses see ({} px), {:.3} elsewhere ({} px)",
        mean(&both),
        both.len(),
        mean(&poor),
        poor.len()
    );
    assert!(both.len() > grid.len() / 5 && poor.len() > grid.len() / 5);
    assert!(
        mean(&poor) < 0.1 * mean(&both),
        "{} vs {}",
        mean(&poor),
        mean(&both)
    );
}
