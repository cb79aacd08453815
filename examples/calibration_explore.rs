//! Exploration of the calibration check on a rig bag: each camera's best rotation correction
//! against a starting calibration, with the ground-truth range or the photometric sweep's
//! estimate as depth, and the agreement at a known knock.
//!
//! `cargo run --release --example calibration_explore -- BAG START_RIG.yaml [WIDTH]`;
//! `CAL_DEPTH=sweep` uses the sweep's estimate; `CAL_TRUE=cam:x,y,z` (degrees, rig axes) also
//! prints the agreement of that camera at the true correction; `CAL_DRIFT=1` instead runs the
//! node's drift monitor over every frame of the bag (sweep depth) and counts the frames after
//! which a camera would be warned at 0.3 degrees. Nothing is asserted here: the
//! tests in tests/model/calibration.rs are.

use mode360::bag::RigBagReader;
use mode360::estimator::calibration::{RotationCheck, RotationCheckConfig};
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::DepthEstimator;
use mode360::geometry::{ErpGrid, Rig};
use nalgebra::Vector3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (bag, start) = (&args[0], Rig::from_file(&args[1])?);
    let mut cfg = RotationCheckConfig::refine();
    if let Some(w) = args.get(2) {
        cfg.analysis_width = w.parse()?;
    }
    let use_sweep = std::env::var("CAL_DEPTH").is_ok_and(|v| v == "sweep");
    if std::env::var("CAL_DRIFT").is_ok() {
        return drift(bag, &start);
    }
    let reader = RigBagReader::open(bag)?;
    let check = RotationCheck::new(&start, cfg.clone())?;
    let mut sweep = PhotometricSweep::new(PhotometricConfig::default())?;
    let mut frames = Vec::new();
    for frame in reader.frames().take(6) {
        let frame = frame?;
        let range = if use_sweep {
            let grid = ErpGrid::new(frame.images[0].width() as usize)?;
            sweep.estimate(&start, &frame.images, grid)?.range_m
        } else {
            frame.ground_truth.clone().ok_or("no ground truth")?
        };
        frames.push(check.frame(&frame.images, &range)?);
    }
    if std::env::var("CAL_QUICK").is_ok() {
        // The node's drift check: one frame at a time on the drift grid.
        let quick = RotationCheck::new(&start, RotationCheckConfig::drift())?;
        for (i, frame) in reader.frames().take(6).enumerate() {
            let frame = frame?;
            let grid = ErpGrid::new(frame.images[0].width() as usize)?;
            let range = sweep.estimate(&start, &frame.images, grid)?.range_m;
            let t0 = std::time::Instant::now();
            let f = quick.frame(&frame.images, &range)?;
            let corr = quick.quick_corrections(std::slice::from_ref(&f), 2, 0.25)?;
            let ms = 1e3 * t0.elapsed().as_secs_f64();
            let text: Vec<String> = corr
                .iter()
                .map(|c| format!("{} {:.3} deg (gain {:.4})", c.name, c.angle_deg, c.gain()))
                .collect();
            println!("frame {i}: {ms:.0} ms: {}", text.join(", "));
        }
    }
    let t0 = std::time::Instant::now();
    let corrections = check.corrections(&frames)?;
    println!(
        "corrections in {:.2} s (width {})",
        t0.elapsed().as_secs_f64(),
        cfg.analysis_width
    );
    for c in &corrections {
        let w = c.rotation_vector_rig.map(f64::to_degrees);
        println!(
            "  {}: {:.3} deg ({:+.3}, {:+.3}, {:+.3}); agreement {:.4} -> {:.4}, {} cells",
            c.name, c.angle_deg, w.x, w.y, w.z, c.agreement_before, c.agreement_after, c.cells
        );
    }
    if let Ok(spec) = std::env::var("CAL_TRUE") {
        let (cam, xyz) = spec.split_once(':').ok_or("CAL_TRUE=cam:x,y,z")?;
        let v: Vec<f64> = xyz.split(',').map(str::parse).collect::<Result<_, _>>()?;
        let c: usize = cam.parse()?;
        let w = Vector3::new(v[0], v[1], v[2]).map(f64::to_radians);
        let t1 = std::time::Instant::now();
        let at_true = check.agreement_of(&frames, c, &w)?;
        println!(
            "camera {c} at the true correction: agreement {at_true:.4} ({:.1} ms an evaluation)",
            1e3 * t1.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// The node's drift monitor over every frame of `bag`.
fn drift(bag: &str, rig: &Rig) -> Result<(), Box<dyn std::error::Error>> {
    use mode360::estimator::calibration_drift::CalibrationDriftMonitor;
    const WARN_DEG: f64 = 0.3;
    let reader = RigBagReader::open(bag)?;
    let mut monitor = CalibrationDriftMonitor::new(rig)?;
    let mut sweep = PhotometricSweep::new(PhotometricConfig::default())?;
    let (mut frames, mut warned, mut check_s, mut checks) = (0, 0, 0.0, 0);
    let mut largest = 0.0f64;
    let mut any_largest = 0.0f64;
    for frame in reader.frames() {
        let frame = frame?;
        let grid = ErpGrid::new(frame.images[0].width() as usize)?;
        let range = sweep.estimate(rig, &frame.images, grid)?.range_m;
        let t0 = std::time::Instant::now();
        if monitor.add(&frame.images, &range, &[])? {
            check_s += t0.elapsed().as_secs_f64();
            checks += 1;
        }
        frames += 1;
        for d in monitor.drift() {
            any_largest = any_largest.max(d.correction_deg);
            if d.suspect {
                largest = largest.max(d.correction_deg);
                if d.correction_deg > WARN_DEG {
                    warned += 1;
                    println!(
                        "frame {frames}: {} warned, {:.3} deg",
                        d.name, d.correction_deg
                    );
                }
            }
        }
    }
    println!(
        "{frames} frames, {warned} warned; largest suspect correction {largest:.3} deg, \
         largest of any camera {any_largest:.3} deg; {checks} checks, {:.1} ms each",
        1e3 * check_s / f64::from(checks.max(1))
    );
    Ok(())
}
