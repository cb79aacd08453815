//! SSMODE's far field ([`mode360::geometry::FarField`]) on a short baseline: the shipped
//! weights read the sky of a held-out vertical pair (0.3 m, never trained on) as the far plane,
//! where the test on the farthest hypothesis alone spread it over tens of metres.

use candle_core::Device;
use mode360::estimator::ssmode::{default_weights_path, SsmodeEstimator};
use mode360::estimator::DepthEstimator;
use mode360::geometry::{ErpGrid, Rig};
use mode360::metrics::depth_metrics;
use mode360::model::{load_weights_and_readout, Readout, Ssmode};
use mode360::synth::{SynthConfig, SynthRenderer};

/// A held-out world (top bit set; not the issue-19 rows' seed) and one frame along its street.
const WORLD_SEED: u64 = (1 << 63) + 41;
const FRAME: usize = 60;
/// Lowest share of sky pixels read within δ1 of the far plane with the shipped readout, %.
const MIN_SKY_DELTA1_PCT: f64 = 80.0;
/// Lowest gain on the sky over the far plane alone, points.
const MIN_SKY_GAIN_PTS: f64 = 20.0;

#[test]
fn a_short_baselines_sky_reads_the_far_plane() {
    let rig = Rig::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/eval_rigs/rig_vertical_pair.yaml"
    ))
    .expect("vertical pair rig");
    let (shipped, readout, vb) =
        load_weights_and_readout(default_weights_path(), &Device::Cpu).expect("weights");
    assert_eq!(
        readout,
        Readout::default(),
        "the shipped file's readout is the default"
    );
    assert!(
        readout.far_parallax_cells > 0.0,
        "the default readout has no far field"
    );
    let far_plane_alone = Readout {
        far_parallax_cells: 0.0,
        far_plane_probability: 0.8,
        ..readout
    };
    let renderer = SynthRenderer::new(SynthConfig {
        seed: WORLD_SEED,
        width: shipped.width,
        ..SynthConfig::default()
    })
    .expect("renderer");
    let frame = renderer.render_frame(&rig, FRAME);
    let gt = frame.ground_truth.as_ref().expect("ground truth");
    let max_depth_m = shipped.max_depth_m as f32;
    let sky: Vec<usize> = (0..gt.data.len())
        .filter(|&k| gt.data[k] >= max_depth_m)
        .collect();
    assert!(
        sky.len() * 10 > gt.data.len(),
        "only {} sky pixels",
        sky.len()
    );
    let grid = ErpGrid::new(shipped.width).expect("grid");
    let mut scores = Vec::new();
    for readout in [readout, far_plane_alone] {
        let model = Ssmode::new(&shipped, vb.clone())
            .and_then(|m| m.with_readout(readout).map_err(candle_core::Error::wrap))
            .expect("network");
        let mut estimator = SsmodeEstimator::from_model(model, "shipped weights");
        let out = estimator
            .estimate(&rig, &frame.images, grid)
            .expect("estimate");
        let range = &out.range_m.data;
        let sky_ok = sky
            .iter()
            .filter(|&&k| range[k] * 1.25 > max_depth_m)
            .count();
        let sky_pct = 100.0 * sky_ok as f64 / sky.len() as f64;
        let all = depth_metrics(range, &gt.data, shipped.max_depth_m).expect("metrics");
        eprintln!(
            "far_parallax_cells {}: sky δ1 {sky_pct:.1} %, δ1 {:.1} %",
            readout.far_parallax_cells, all.delta1_pct
        );
        scores.push((sky_pct, all.delta1_pct));
    }
    let ((sky, all), (sky_alone, all_alone)) = (scores[0], scores[1]);
    assert!(sky >= MIN_SKY_DELTA1_PCT, "sky δ1 {sky:.1} %");
    assert!(
        sky >= sky_alone + MIN_SKY_GAIN_PTS,
        "sky δ1 {sky:.1} % against {sky_alone:.1} % with the far plane alone"
    );
    assert!(all > all_alone, "δ1 {all:.1} % against {all_alone:.1} %");
}
