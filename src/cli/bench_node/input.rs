//! The bench's input: the estimator checked before anything starts, the bag to play
//! (given, bundled or rendered) and its rig written out for the node, in temporary files
//! removed on drop.

use super::{BenchOptions, DEFAULT_WIDTH, RENDERED_FRAMES};
use crate::cli::bundled_bag::BUNDLED_BAG;
use anyhow::{anyhow, bail, Context, Result};
use mode360_core::shipped::{self, Origin};
use mode360_io::bag::RigBagReader;
use mode360_synth::record::{record_synthetic_bag, RecordOptions};
use mode360_synth::SynthConfig;
use std::path::{Path, PathBuf};

/// A temporary file removed on drop.
pub(super) struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The path of the bench's temporary file `name`, unique to this process.
fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("mode360_bench_{}_{name}", std::process::id()))
}

/// Width of the first camera image of a rig bag.
fn bag_width(reader: &RigBagReader) -> Result<usize> {
    let frame = reader
        .frames()
        .next()
        .ok_or_else(|| anyhow!("the bag has no complete frame"))??;
    Ok(frame.images[0].width() as usize)
}

/// The bag a bench plays and the rig written out for the node.
pub(super) struct BenchInput {
    pub(super) bag_path: PathBuf,
    /// Width of the bag's camera images, pixels.
    pub(super) input_width: usize,
    /// Width of the node's output, pixels.
    pub(super) output_width: usize,
    /// The bag's rig as a temporary YAML file, the node's `rig_file`.
    pub(super) rig_path: PathBuf,
    pub(super) camera_topics: Vec<String>,
}

/// The bag to play (see [`bench_input`]), its widths, and its rig written to a temporary
/// file for the node; temporary files are added to `temps`.
pub(super) fn prepare_input(opts: &BenchOptions, temps: &mut Vec<TempFile>) -> Result<BenchInput> {
    let bag_path = bench_input(opts, temps)?;
    let reader = RigBagReader::open(&bag_path)?;
    let rig = reader.rig().clone();
    let input_width = bag_width(&reader)?;
    let output_width = opts.width.unwrap_or(input_width);
    drop(reader);
    let rig_path = temp_path("rig.yaml");
    std::fs::write(&rig_path, rig.to_yaml())
        .with_context(|| format!("writing {}", rig_path.display()))?;
    temps.push(TempFile(rig_path.clone()));
    let camera_topics: Vec<String> = rig.cameras.iter().map(|c| c.topic.clone()).collect();
    Ok(BenchInput {
        bag_path,
        input_width,
        output_width,
        rig_path,
        camera_topics,
    })
}

/// Fails before rendering or starting anything when the estimator cannot run: its GPU cannot
/// be had, or its weights file is missing.
pub(super) fn check_estimator(opts: &BenchOptions) -> Result<()> {
    if opts.estimator.device.is_cuda() {
        opts.estimator
            .device
            .open()
            .context("the device of the node's estimator (--device)")?;
    }
    if let Some(path) = opts.estimator.weights_path() {
        if !path.exists() {
            bail!(
                "estimator 'ssmode' needs trained weights at {}, which does not exist",
                path.display()
            );
        }
    }
    Ok(())
}

/// The bag to play: the one given, the bundled one when its width fits, or frames rendered
/// into a temporary file (added to `temps`).
fn bench_input(opts: &BenchOptions, temps: &mut Vec<TempFile>) -> Result<PathBuf> {
    if let Some(b) = &opts.bag {
        return Ok(b.clone());
    }
    let width = opts.width.unwrap_or(DEFAULT_WIDTH);
    let bundled = shipped::locate(Path::new(BUNDLED_BAG), &[]);
    if bundled.origin != Origin::NotFound
        && bag_width(&RigBagReader::open(&bundled.path)?)? == width
    {
        return Ok(bundled.path);
    }
    let out = temp_path("input.mcap");
    temps.push(TempFile(out.clone()));
    tracing::info!("rendering {RENDERED_FRAMES} frames at {width} px");
    record_synthetic_bag(&RecordOptions {
        rig: mode360_core::geometry::Rig::from_file_or_shipped(&opts.rig_file)?,
        config: SynthConfig {
            width,
            seed: 1,
            ..Default::default()
        },
        frames: RENDERED_FRAMES,
        first_frame: 0,
        out: out.clone(),
        show_progress: false,
    })
    .context("rendering the bench input")?;
    Ok(out)
}
