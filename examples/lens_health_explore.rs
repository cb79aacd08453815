//! Exploration of the lens check on rig bags: per camera, the blocked fraction it finds over
//! the bag's frames, with the ground-truth range or the photometric sweep's estimate as depth.
//!
//! `cargo run --release --example lens_health_explore -- BAG [BAG...]`; `LENS_DEPTH=sweep`
//! uses the sweep's estimate instead of the ground truth; `LENS_PNG=DIR` writes per camera
//! `camN.png`, its own panorama on the analysis grid in four panels: the first frame, the
//! change over the frames (x10), the temporal cue (red blocked, green clear) and the mask.
//! Nothing is asserted here: the tests in tests/model/lens_health.rs are.

use mode360::bag::RigBagReader;
use mode360::estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360::estimator::DepthEstimator;
use mode360::geometry::ErpGrid;
use mode360::health::lens_health::{analysis_grid, lens_votes, LensVotes};
use mode360::health::lens_motion::{cell_changes, motion_votes, LensGeometry};
use mode360::health::lens_window::LensHealthWindow;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let use_sweep = std::env::var("LENS_DEPTH").is_ok_and(|v| v == "sweep");
    for path in std::env::args().skip(1) {
        let reader = RigBagReader::open(&path)?;
        let rig = reader.rig().clone();
        let info = reader.info();
        let mut window = LensHealthWindow::new(usize::MAX);
        let mut sweep = PhotometricSweep::new(PhotometricConfig::default())?;
        let mut check_s = Vec::new();
        let mut frames = Vec::new();
        for frame in reader.frames() {
            let frame = frame?;
            let range = if use_sweep {
                let grid = ErpGrid::new(frame.images[rig.reference].width() as usize)?;
                sweep.estimate(&rig, &frame.images, grid)?.range_m
            } else {
                frame.ground_truth.clone().ok_or("no ground truth")?
            };
            let t0 = std::time::Instant::now();
            let votes = lens_votes(&rig, &frame.images, &range)?;
            window.add(&rig, votes.clone());
            frames.push(votes);
            check_s.push(t0.elapsed().as_secs_f64());
        }
        let rest = check_s.get(1..).unwrap_or_default();
        println!(
            "{path} (truth: {:?}); lens check {:.1} ms on the first frame (the rig's tables), \
             {:.1} ms a frame after it",
            info.get("blocked_fraction"),
            1e3 * check_s.first().copied().unwrap_or_default(),
            1e3 * rest.iter().sum::<f64>() / rest.len().max(1) as f64
        );
        let t0 = std::time::Instant::now();
        let geometry = LensGeometry::new(&rig);
        let t1 = std::time::Instant::now();
        let refs: Vec<_> = frames.iter().collect();
        let motion = motion_votes(&geometry, &refs, &cell_changes(&refs));
        if let Ok(dir) = std::env::var("LENS_PNG") {
            let masks = window.masks();
            for c in 0..rig.cameras.len() {
                let mask = masks[c].as_ref().map(|m| m.cells());
                cell_picture(&refs, c, &motion[c], mask).save(format!("{dir}/cam{c}.png"))?;
            }
        }
        println!(
            "geometry {:.0} ms, motion votes {:.1} ms",
            1e3 * (t1 - t0).as_secs_f64(),
            1e3 * t1.elapsed().as_secs_f64()
        );
        for (c, (cam, h)) in rig.cameras.iter().zip(window.health()).enumerate() {
            let w = &geometry.weights()[c];
            let all: f64 = w.iter().sum();
            let (mut blocked, mut clear) = (0.0, 0.0);
            for (j, v) in motion[c].iter().enumerate() {
                match v {
                    Some(true) => blocked += w[j],
                    Some(false) => clear += w[j],
                    None => {}
                }
            }
            println!(
                "  {}: blocked {:.3} of the decided {:.3}, {:?}; motion: blocked {:.3} of the decided {:.3} (blocked/all {:.3})",
                cam.name,
                h.blocked_fraction,
                h.decided_fraction,
                h.region,
                blocked / (blocked + clear).max(1e-9),
                (blocked + clear) / all,
                blocked / all
            );
        }
    }
    Ok(())
}

/// Camera `c`'s picture (see the module docs), scaled up 4x.
fn cell_picture(
    frames: &[&LensVotes],
    c: usize,
    motion: &[Option<bool>],
    mask: Option<&[bool]>,
) -> image::RgbImage {
    let g = analysis_grid();
    let (w, h) = (g.width() as u32, g.height() as u32);
    let change = &cell_changes(frames)[c];
    let mut img = image::RgbImage::new(w, 4 * h);
    for (j, vote) in motion.iter().enumerate() {
        let (u, v) = (j as u32 % w, j as u32 / w);
        let grey = frames[0].grey[c][j].map_or(0, |x| (x * 255.0) as u8);
        let ch = change[j].map_or(0, |x| (x * 2550.0).min(255.0) as u8);
        let cue = match vote {
            Some(true) => [255, 0, 0],
            Some(false) => [0, 160, 0],
            None => [0, 0, 0],
        };
        let masked = if mask.is_some_and(|m| m[j]) {
            [255, 0, 0]
        } else {
            [grey / 2; 3]
        };
        img.put_pixel(u, v, image::Rgb([grey; 3]));
        img.put_pixel(u, v + h, image::Rgb([ch; 3]));
        img.put_pixel(u, v + 2 * h, image::Rgb(cue));
        img.put_pixel(u, v + 3 * h, image::Rgb(masked));
    }
    image::imageops::resize(&img, 4 * w, 16 * h, image::imageops::FilterType::Nearest)
}
