//! Synthetic frames recorded into a rig bag: the rig, the scene settings (soiling, maximum
//! depth, blockers with each camera's blocked fraction) in the bag's metadata, then every
//! frame's images and ground truth.

use super::{SynthConfig, SynthError, SynthRenderer, BLOCKED_FRACTION_KEY};
use mode360_core::geometry::Rig;
use mode360_core::progress::frames_bar;
use mode360_io::bag::{BagError, RigBagWriter, MAX_DEPTH_KEY, SOILED_KEY};
use std::path::PathBuf;
use std::time::Instant;

/// Why a recording failed: the renderer's configuration or the bag.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Synth(#[from] SynthError),
    #[error(transparent)]
    Bag(#[from] BagError),
}

/// What to render.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    pub rig: Rig,
    pub config: SynthConfig,
    pub frames: usize,
    /// Index of the first frame (frames are a deterministic function of seed and index).
    pub first_frame: usize,
    pub out: PathBuf,
    pub show_progress: bool,
}

/// What was written.
#[derive(Clone, Debug)]
pub struct RecordSummary {
    pub frames: usize,
    pub elapsed_s: f64,
    pub bytes: u64,
}

/// Renders `frames` frames and writes them, with the rig and the scene settings, to a bag.
/// Any camera model: ERP cameras at the configured width, fisheye and dual-fisheye cameras at
/// their `image_size` (scale the rig first with [`Rig::scaled`] for a lower resolution).
pub fn record_synthetic_bag(opts: &RecordOptions) -> Result<RecordSummary, RecordError> {
    let renderer = SynthRenderer::new(opts.config.clone())?;
    let mut info = opts.config.to_info();
    info.insert(SOILED_KEY.into(), opts.config.soiled.to_string());
    info.insert(MAX_DEPTH_KEY.into(), opts.config.max_depth_m.to_string());
    info.insert("frames".into(), opts.frames.to_string());
    info.insert("first_frame".into(), opts.first_frame.to_string());
    if !opts.config.blockers.is_empty() {
        // Every frame blocks the same pixels: the measured fraction per camera, by name.
        let fractions: Vec<String> = opts
            .rig
            .cameras
            .iter()
            .zip(renderer.blocked_fractions(&opts.rig))
            .map(|(cam, f)| format!("{}={f:.4}", cam.name))
            .collect();
        info.insert(BLOCKED_FRACTION_KEY.into(), fractions.join(","));
    }
    let mut writer = RigBagWriter::create(&opts.out, &opts.rig, &info)?;
    let progress = frames_bar("rendering", opts.frames, opts.show_progress);
    let t0 = Instant::now();
    for i in 0..opts.frames {
        let frame = renderer.render_frame(&opts.rig, opts.first_frame + i);
        writer.write_frame(&frame)?;
        progress.inc(1);
    }
    writer.finish()?;
    progress.finish_and_clear();
    let bytes = std::fs::metadata(&opts.out).map(|m| m.len()).unwrap_or(0);
    Ok(RecordSummary {
        frames: opts.frames,
        elapsed_s: t0.elapsed().as_secs_f64(),
        bytes,
    })
}
