//! `mode360 synth`: render synthetic rig frames into a ROS 2 MCAP bag.

use crate::bag::{BagError, RigBagWriter};
use crate::bag::{MAX_DEPTH_KEY, SOILED_KEY};
use crate::geometry::Rig;
use crate::synth::{SynthConfig, SynthError, SynthRenderer};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Synth(#[from] SynthError),
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
    pub seconds: f64,
    pub bytes: u64,
}

/// Renders `frames` frames and writes them, with the rig and the scene settings, to a bag.
pub fn record_synthetic_bag(opts: &RecordOptions) -> Result<RecordSummary, RecordError> {
    let renderer = SynthRenderer::new(opts.config.clone())?;
    let mut info = opts.config.to_info();
    info.insert(SOILED_KEY.into(), opts.config.soiled.to_string());
    info.insert(MAX_DEPTH_KEY.into(), opts.config.max_depth_m.to_string());
    info.insert("frames".into(), opts.frames.to_string());
    info.insert("first_frame".into(), opts.first_frame.to_string());
    let mut writer = RigBagWriter::create(&opts.out, &opts.rig, &info)?;
    let progress = if opts.show_progress {
        let pb = ProgressBar::new(opts.frames as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "rendering [{elapsed_precise}] {bar:30} {pos}/{len} frames ({per_sec}, ETA {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        pb
    } else {
        ProgressBar::hidden()
    };
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
        seconds: t0.elapsed().as_secs_f64(),
        bytes,
    })
}
