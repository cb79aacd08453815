//! Exploration of the lens masks ([`mode360::estimator::lens_mask`]) on a bag with a blocked
//! lens: the photometric sweep runs under a [`LensGuard`] over the bag's frames, and each
//! camera's mask is compared with the truth, the pixels that differ from the same frames of a
//! bag rendered without the blocker (ERP cameras).
//!
//! `cargo run --release --example lens_mask_explore -- BLOCKED_BAG CLEAN_BAG`;
//! `LENS_ESTIMATOR=ssmode` runs the shipped SSMODE instead of the sweep. Nothing is
//! asserted here: the tests in tests/model/lens_mask.rs are.

use mode360::bag::RigBagReader;
use mode360::estimator::lens_guard::LensGuard;
use mode360::estimator::lens_window::LENS_WINDOW_FRAMES;
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::{DepthEstimator, EstimatorKind, EstimatorSpec};
use mode360::geometry::ErpGrid;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [blocked_bag, clean_bag] = args.as_slice() else {
        return Err("usage: lens_mask_explore BLOCKED_BAG CLEAN_BAG".into());
    };
    let blocked = RigBagReader::open(blocked_bag)?;
    let clean = RigBagReader::open(clean_bag)?;
    let rig = blocked.rig().clone();
    let mut sweep: Box<dyn DepthEstimator> = match std::env::var("LENS_ESTIMATOR").as_deref() {
        Ok("ssmode") => EstimatorSpec::new(EstimatorKind::Ssmode).build()?,
        _ => Box::new(PhotometricSweep::new(PhotometricConfig::default())?),
    };
    let mut guard = LensGuard::new(LENS_WINDOW_FRAMES, true);
    for (n, (frame, clean_frame)) in blocked.frames().zip(clean.frames()).enumerate() {
        let (frame, clean_frame) = (frame?, clean_frame?);
        let grid = ErpGrid::new(frame.images[rig.reference].width() as usize)?;
        guard.estimate(sweep.as_mut(), &rig, &frame.images, grid)?;
        println!(
            "frame {n}: health {:?}",
            guard
                .health()
                .iter()
                .map(|h| (h.blocked_fraction * 1000.0).round() / 1000.0)
                .collect::<Vec<_>>()
        );
        for (c, cam) in rig.cameras.iter().enumerate() {
            let (img, clean_img) = (&frame.images[c], &clean_frame.images[c]);
            let camera_grid = ErpGrid::new(img.width() as usize)?;
            let truth: Vec<bool> = img
                .pixels()
                .zip(clean_img.pixels())
                .map(|(a, b)| a != b)
                .collect();
            let mask = guard
                .masks()
                .get(c)
                .and_then(Option::as_ref)
                .map(|m| m.blocked_on(camera_grid));
            let weight = |k: usize| {
                let v = (k / camera_grid.width()) as f64 + 0.5;
                (std::f64::consts::FRAC_PI_2
                    - v * std::f64::consts::PI / camera_grid.height() as f64)
                    .cos()
            };
            let (mut t, mut m, mut hit) = (0.0, 0.0, 0.0);
            let mut all = 0.0;
            for (k, &is_blocked) in truth.iter().enumerate() {
                let w = weight(k);
                let masked = mask.as_ref().is_some_and(|m| m[k]);
                all += w;
                t += if is_blocked { w } else { 0.0 };
                m += if masked { w } else { 0.0 };
                hit += if masked && is_blocked { w } else { 0.0 };
            }
            println!(
                "  {}: truth {:.3}, masked {:.3}, truth masked {:.0} %, mask on clear view {:.3}",
                cam.name,
                t / all,
                m / all,
                if t > 0.0 { 100.0 * hit / t } else { 100.0 },
                (m - hit) / all
            );
        }
    }
    Ok(())
}
