//! Exploration of the lens check on rig bags: per camera, the blocked fraction it finds over
//! the bag's frames, with the ground-truth range or the photometric sweep's estimate as depth.
//!
//! `cargo run --release --example lens_health_explore -- BAG [BAG...]`; `LENS_DEPTH=sweep`
//! uses the sweep's estimate instead of the ground truth. Nothing is asserted here: the tests
//! in tests/model/lens_health.rs are.

use mode360::bag::RigBagReader;
use mode360::estimator::lens_health::{lens_votes, LensHealthAccumulator};
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::DepthEstimator;
use mode360::geometry::ErpGrid;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let use_sweep = std::env::var("LENS_DEPTH").is_ok_and(|v| v == "sweep");
    for path in std::env::args().skip(1) {
        let reader = RigBagReader::open(&path)?;
        let rig = reader.rig().clone();
        let info = reader.info();
        let mut acc = LensHealthAccumulator::default();
        let mut sweep = PhotometricSweep::new(PhotometricConfig::default())?;
        let mut check_s = Vec::new();
        for frame in reader.frames() {
            let frame = frame?;
            let range = if use_sweep {
                let grid = ErpGrid::new(frame.images[rig.reference].width() as usize)?;
                sweep.estimate(&rig, &frame.images, grid)?.range_m
            } else {
                frame.ground_truth.clone().ok_or("no ground truth")?
            };
            let t0 = std::time::Instant::now();
            acc.add(&lens_votes(&rig, &frame.images, &range)?);
            check_s.push(t0.elapsed().as_secs_f64());
        }
        println!(
            "{path} (truth: {:?}); lens check {:.1} ms a frame",
            info.get("blocked_fraction"),
            1e3 * check_s.iter().sum::<f64>() / check_s.len().max(1) as f64
        );
        for (cam, h) in rig.cameras.iter().zip(acc.health()) {
            println!(
                "  {}: blocked {:.3} of the decided {:.3}, {:?}",
                cam.name, h.blocked_fraction, h.decided_fraction, h.region
            );
        }
    }
    Ok(())
}
