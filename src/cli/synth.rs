//! `mode360 synth`: render synthetic rig frames into a ROS 2 MCAP bag.

use anyhow::{Context, Result};
use clap::Args;
use mode360_core::geometry::Rig;
use mode360_core::memory::BYTES_PER_MIB;
use mode360_synth::blockers::{parse_blocked_lens, validate_blockers};
use mode360_synth::record::{record_synthetic_bag, RecordOptions};
use mode360_synth::{SceneKind, StreetStyle, SynthConfig};
use std::path::PathBuf;

#[derive(Args)]
pub struct SynthArgs {
    /// Rig calibration YAML.
    #[arg(long, default_value = "launch_configs/rig_deep360.yaml")]
    pub rig: PathBuf,
    /// Number of frames to render (at most 100000).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=MAX_SYNTH_FRAMES as i64))]
    pub frames: u32,
    /// Index of the first frame along the drive.
    #[arg(long, default_value_t = 0)]
    pub first_frame: usize,
    /// Panorama width in pixels (height = width / 2): equirectangular cameras and the ground
    /// truth. Fisheye cameras render at their image_size (see --fisheye-scale).
    #[arg(long, default_value_t = 512)]
    pub width: usize,
    /// Soil one or two lenses per frame (mud, water drops, glare).
    #[arg(long)]
    pub soiled: bool,
    /// Scene seed: the same seed gives the same bag.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sky and far-field ground-truth range, metres.
    #[arg(long, default_value_t = mode360_core::geometry::DEFAULT_MAX_DEPTH_M)]
    pub max_depth_m: f64,
    /// Scene kind: a procedural street, or random textured objects all around the rig (new
    /// per frame; defeats monocular depth guessing).
    #[arg(long, value_enum, default_value_t = SceneKind::Street)]
    pub scene: SceneKind,
    /// Street layout: regular (same cross-section for every seed) or varied per seed (road,
    /// lane and sidewalk widths, setbacks, heights, parked cars, trees, rig height and tilt).
    #[arg(long, value_enum, default_value_t = StreetStyle::Regular)]
    pub street: StreetStyle,
    /// Resolution factor for the rig's fisheye and dual-fisheye cameras (0.5: half their
    /// calibrated width and height, intrinsics scaled to match; ERP cameras use --width). The
    /// bag records the scaled rig.
    #[arg(long, default_value_t = 1.0)]
    pub fisheye_scale: f64,
    /// Block a lens in every frame: CAM:FRACTION[:KIND], CAM a camera name or 1-based index,
    /// FRACTION of its view (solid angle; of the seen pixels for a fisheye) in (0, 0.6], KIND
    /// mud (default), mount or vehicle. Repeat for several cameras.
    #[arg(long = "blocked-lens", value_name = "CAM:FRACTION[:KIND]")]
    pub blocked_lens: Vec<String>,
    /// Output bag.
    #[arg(long)]
    pub out: PathBuf,
}

/// Bytes a rendered frame holds per image pixel, with the renderer's buffers (8-bit RGB, an
/// f32 range and ray and hit buffers of a few words a pixel).
const RENDER_BYTES_PER_PIXEL: f64 = 64.0;

/// Refuses a rig whose frames would not fit in memory, before anything is allocated, saying
/// what one frame would need.
fn check_memory(rig: &Rig, width: usize) -> Result<()> {
    // The width's own limits first: they say more than a memory figure.
    mode360_core::geometry::ErpGrid::new(width).with_context(|| format!("--width {width}"))?;
    let pixels: f64 = rig
        .cameras
        .iter()
        .map(|c| match c.projection.image_size() {
            Some(s) => f64::from(s.width) * f64::from(s.height),
            None => (width * width / 2) as f64,
        })
        .sum::<f64>()
        + (width * width / 2) as f64;
    let need_mib = pixels * RENDER_BYTES_PER_PIXEL / BYTES_PER_MIB;
    if let Some(available) = mode360_core::memory::available_mib() {
        if need_mib > available {
            anyhow::bail!(
                "rendering a frame of this rig at width {width} needs about {need_mib:.0} MiB, {available:.0} MiB are available"
            );
        }
    }
    Ok(())
}

/// Most frames one `synth` run renders (a 27-hour drive at 1 Hz; the bag would be hundreds of
/// gigabytes at 512 wide).
pub const MAX_SYNTH_FRAMES: u32 = 100_000;

/// `mode360 synth`: renders the frames into the bag and prints the size and the rate.
pub fn run(a: SynthArgs) -> Result<()> {
    let rig = Rig::from_file_or_shipped(&a.rig)?;
    let rig = if a.fisheye_scale == 1.0 {
        rig
    } else {
        rig.scaled(a.fisheye_scale)
            .map_err(|e| e.in_source(&a.rig.display().to_string()))
            .with_context(|| format!("--fisheye-scale {}", a.fisheye_scale))?
    };
    check_memory(&rig, a.width)?;
    if let Some(part) = mode360_core::geometry::panorama::rig_coverage_warning(&rig) {
        tracing::warn!("rig {}: {part}", a.rig.display());
    }
    let names: Vec<&str> = rig.cameras.iter().map(|c| c.name.as_str()).collect();
    let blockers = a
        .blocked_lens
        .iter()
        .map(|spec| parse_blocked_lens(spec, &names))
        .collect::<Result<Vec<_>, _>>()
        .and_then(|b| validate_blockers(&b).map(|()| b))
        .with_context(|| format!("--blocked-lens (rig {})", a.rig.display()))?;
    let config = SynthConfig {
        seed: a.seed,
        width: a.width,
        soiled: a.soiled,
        max_depth_m: a.max_depth_m,
        scene: a.scene,
        street: a.street,
        blockers,
        ..SynthConfig::default()
    };
    let summary = record_synthetic_bag(&RecordOptions {
        rig,
        config,
        frames: a.frames as usize,
        first_frame: a.first_frame,
        out: a.out.clone(),
        show_progress: true,
    })
    .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "wrote {} frames to {} ({:.1} MiB) in {:.1} s ({:.2} frames/s)",
        summary.frames,
        a.out.display(),
        summary.bytes as f64 / BYTES_PER_MIB,
        summary.elapsed_s,
        summary.frames as f64 / summary.elapsed_s.max(1e-9)
    );
    Ok(())
}
