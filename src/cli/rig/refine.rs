//! `mode360 rig refine BAG --out RIG.yaml [--rig START.yaml]`: the cameras' rotations refined
//! from a bag's images ([`mode360_health::calibration`] does the work: the
//! rotation of each camera that makes it agree best with the others at the estimated depth).
//! Depth comes from the learning-free photometric sweep: per camera, from the other cameras
//! (so that a turned camera cannot bend it towards itself), estimated again after each pass.
//! Translations are kept: on these rigs they move a point by a fraction of a pixel beyond a
//! few metres, so the images do not pin them down.

use anyhow::{bail, Context, Result};
use clap::Args;
use mode360_core::frame::RigFrame;
use mode360_core::geometry::{ErpGrid, Rig};
use mode360_estimator::photometric::{PhotometricConfig, PhotometricSweep};
use mode360_health::calibration::{
    keep_earned_corrections, refine_rotations, turns, CameraCorrection, CheckFrame, RotationCheck,
    RotationCheckConfig, MIN_TEXTURED_CELLS,
};
use mode360_io::bag::RigBagReader;
use nalgebra::Vector3;
use std::path::PathBuf;

/// Fewest frames `rig refine` accepts: one frame's depth errors and occlusions are too easily
/// mistaken for a turned camera.
pub const MIN_REFINE_FRAMES: usize = 2;
/// Frames used by default.
pub const DEFAULT_REFINE_FRAMES: usize = 6;
/// Depth-and-rotation passes: the sweep's depth is estimated again with the rotations refined
/// so far. The third pass brings a knocked camera closer (a 1 degree oblique knock 0.124 ->
/// 0.055 degree on the bags test's world) and can turn a camera that was not knocked (0.17
/// degree of yaw there), which [`keep_earned_corrections`] undoes (docs/commands.md, rig
/// refine).
pub const REFINE_PASSES: usize = 3;
/// Cameras a rig needs for each camera to be checked against depth estimated without it; a
/// two-camera rig uses the joint depth.
pub const MIN_CAMERAS_FOR_EXCLUSION: usize = 3;

#[derive(Args)]
pub struct RigRefineArgs {
    /// Rig bag whose images are used.
    pub bag: PathBuf,
    /// Rig YAML to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Starting calibration (default: the bag's); it must have the bag's cameras.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Frames to use, from the start of the bag.
    #[arg(long, default_value_t = DEFAULT_REFINE_FRAMES)]
    pub frames: usize,
    /// Depth-and-rotation passes: each estimates depth again with the rotations refined so
    /// far.
    #[arg(long, default_value_t = REFINE_PASSES)]
    pub passes: usize,
}

/// What [`refine`] found.
pub struct RefineSummary {
    pub rig: Rig,
    pub corrections: Vec<CameraCorrection>,
    pub frames: usize,
}

/// Refines the rotations of `a.rig` (or the bag's calibration) from `a.bag`'s first frames.
pub fn refine(a: &RigRefineArgs) -> Result<RefineSummary> {
    let file = a.bag.display().to_string();
    if a.frames < MIN_REFINE_FRAMES {
        bail!(
            "--frames {}: rig refine needs at least {MIN_REFINE_FRAMES} frames",
            a.frames
        );
    }
    if a.passes == 0 {
        bail!("--passes 0: rig refine needs at least 1 depth-and-rotation pass");
    }
    let reader = RigBagReader::open(&a.bag)?;
    let start = crate::cli::replay::calibration_for(&reader, a.rig.as_deref(), &file)?;
    let recorded = read_frames(&reader, a.frames, &file)?;
    let cfg = RotationCheckConfig::refine();
    let passes = refine_passes(&start, &recorded, a.passes, &cfg, &file)?;
    // A turn that undoing costs next to nothing was fitted to the depth errors a knocked camera
    // leaves near itself: the camera keeps its starting rotation.
    let (rig, _gains) = keep_earned_corrections(&start, &passes.rig, &passes.last_frames, &cfg)?;
    let corrections = whole_corrections(&start, &rig, &passes, &cfg)?;
    let frames = recorded.len();
    Ok(RefineSummary {
        rig,
        corrections,
        frames,
    })
}

/// The first `count` frames of `reader` that have images (unreadable ones are skipped with a
/// warning); an error when the bag `file` has fewer.
fn read_frames(reader: &RigBagReader, count: usize, file: &str) -> Result<Vec<RigFrame>> {
    let mut recorded = Vec::new();
    for frame in reader.frames() {
        if recorded.len() >= count {
            break;
        }
        match frame {
            Ok(f) if !f.images.is_empty() => recorded.push(f),
            Ok(_) => continue,
            Err(e) => tracing::warn!("bag '{file}': skipping a frame: {e}"),
        }
    }
    if recorded.len() < count {
        bail!(
            "bag '{file}' has {} readable frame(s); rig refine was asked for {} (at least {MIN_REFINE_FRAMES})",
            recorded.len(),
            count
        );
    }
    Ok(recorded)
}

/// Where the depth-and-rotation passes left the rig.
struct Passes {
    /// The rig after the last pass.
    rig: Rig,
    /// The first pass's corrections (their agreement before refining).
    first_pass: Vec<CameraCorrection>,
    /// The last pass's corrections.
    last_pass: Vec<CameraCorrection>,
    /// The last pass's frames (its depth).
    last_frames: Vec<CheckFrame>,
}

/// `passes` depth-and-rotation passes over `recorded` from `start`; an error names a camera
/// that shares too little texture with the others.
fn refine_passes(
    start: &Rig,
    recorded: &[RigFrame],
    passes: usize,
    cfg: &RotationCheckConfig,
    file: &str,
) -> Result<Passes> {
    let mut sweep = PhotometricSweep::new(PhotometricConfig::default())?;
    let mut rig = start.clone();
    let mut first_pass: Option<Vec<CameraCorrection>> = None;
    let mut last_pass = Vec::new();
    let mut last_frames = Vec::new();
    for _pass in 0..passes {
        // Depth with the calibration as refined so far: a turned camera bends the sweep's
        // depth towards agreeing with it, so each pass starts from better depth.
        let check = RotationCheck::new(&rig, cfg.clone())?;
        let mut frames = Vec::with_capacity(recorded.len());
        for frame in recorded {
            frames.push(check_frame(&mut sweep, &rig, &check, frame, file)?);
        }
        let (refined, corrections) = refine_rotations(&rig, &frames, cfg)?;
        if let Some(poor) = corrections.iter().find(|c| c.cells < MIN_TEXTURED_CELLS) {
            bail!(
                "bag '{file}': camera '{}' shares too little texture with the others to refine \
                 ({} textured cells over {} frames, at least {MIN_TEXTURED_CELLS})",
                poor.name,
                poor.cells,
                frames.len()
            );
        }
        rig = refined;
        first_pass.get_or_insert_with(|| corrections.clone());
        last_pass = corrections;
        last_frames = frames;
    }
    Ok(Passes {
        rig,
        first_pass: first_pass.unwrap_or_default(),
        last_pass,
        last_frames,
    })
}

/// One recorded frame checked against `rig`: the sweep's joint depth, and with enough cameras
/// ([`MIN_CAMERAS_FOR_EXCLUSION`]) each camera's depth from the others only.
fn check_frame(
    sweep: &mut PhotometricSweep,
    rig: &Rig,
    check: &RotationCheck,
    frame: &RigFrame,
    file: &str,
) -> Result<CheckFrame> {
    let output = ErpGrid::new(frame.images[0].width() as usize)
        .with_context(|| format!("bag '{file}': frame at {} ns", frame.stamp_ns))?;
    let context = || format!("bag '{file}': frame at {} ns", frame.stamp_ns);
    let estimate = sweep
        .estimate_with(rig, &frame.images, output, true)
        .with_context(context)?;
    if rig.cameras.len() < MIN_CAMERAS_FOR_EXCLUSION {
        return Ok(check.frame(&frame.images, &estimate.range_m)?);
    }
    // Per camera, depth from the others only (a turned camera bends a joint estimate
    // towards itself).
    let mut without = Vec::with_capacity(rig.cameras.len());
    for c in 0..rig.cameras.len() {
        let others: Vec<usize> = (0..rig.cameras.len()).filter(|&k| k != c).collect();
        let images: Vec<_> = others.iter().map(|&k| frame.images[k].clone()).collect();
        let sub = rig.subset(&others)?;
        let range = sweep
            .estimate_with(&sub, &images, output, true)
            .with_context(context)?
            .range_m;
        without.push(range);
    }
    Ok(check.frame_with_exclusions(&frame.images, &estimate.range_m, &without)?)
}

/// Each camera's whole change from the `start` calibration to `rig`, with the agreement
/// before the first pass and after (on the last pass's depth).
fn whole_corrections(
    start: &Rig,
    rig: &Rig,
    passes: &Passes,
    cfg: &RotationCheckConfig,
) -> Result<Vec<CameraCorrection>> {
    let final_check = RotationCheck::new(rig, cfg.clone())?;
    let mut corrections = Vec::with_capacity(rig.cameras.len());
    for (c, w) in turns(start, rig).into_iter().enumerate() {
        corrections.push(CameraCorrection {
            camera: c,
            name: rig.cameras[c].name.clone(),
            rotation_vector_rig: w,
            angle_deg: w.norm().to_degrees(),
            agreement_before: passes
                .first_pass
                .get(c)
                .map_or(f64::NAN, |x| x.agreement_before),
            agreement_after: final_check.agreement_of(&passes.last_frames, c, &Vector3::zeros())?,
            cells: passes.last_pass.get(c).map_or(0, |x| x.cells),
        });
    }
    Ok(corrections)
}

/// `mode360 rig refine`: refines, writes the rig YAML and prints the change per camera.
pub fn run_refine(a: RigRefineArgs) -> Result<()> {
    let summary = refine(&a)?;
    super::write_rig(&summary.rig, &a.out)?;
    println!(
        "refined {} cameras' rotations on {} frames of {}; wrote {}",
        summary.rig.cameras.len(),
        summary.frames,
        a.bag.display(),
        a.out.display()
    );
    for c in &summary.corrections {
        let w = c.rotation_vector_rig.map(f64::to_degrees);
        println!(
            "  {}: turned {:.3} deg (about rig x {:+.3}, y {:+.3}, z {:+.3} deg); agreement {:.4} -> {:.4}",
            c.name, c.angle_deg, w.x, w.y, w.z, c.agreement_before, c.agreement_after
        );
    }
    Ok(())
}
