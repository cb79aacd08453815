//! Fixture writers of the Deep360 tests: a synthetic frame on the Deep360 rig written in the
//! dataset's layout (RGBA Cassini PNGs under `ep{episode}_500frames/{split}/rgb*/` and the
//! depth `.npz`), whole splits of clean and soiled renderings, the fine-tuning fixture's
//! training split, and the conversion of a fixture's testing split to a rig bag.

use mode360::cli::deep360_bag::{convert_deep360_to_bag, Deep360BagOptions};
use mode360::deep360::{
    deep360_rig, erp_to_cassini_range, erp_to_cassini_rgb, write_npz, Deep360FrameId, Deep360Split,
    CASSINI_HEIGHT, CASSINI_WIDTH, DEPTH_NPZ_KEY,
};
use mode360::frame::RigFrame;
use mode360::synth::{SynthConfig, SynthRenderer};
use std::path::Path;

/// ERP width the fixture frames are rendered at.
pub const ERP_WIDTH: usize = 256;
/// Frame number of the single-frame fixture ([`write_fixture`]).
pub const FRAME: u32 = 42;

/// Writes `frame` in the dataset's layout: its four cameras as RGBA Cassini PNGs under
/// `ep{episode}_500frames/{split}/{image_dir}/` and, with `with_depth`, its range as the
/// depth `.npz`.
fn write_frame_files(
    root: &Path,
    episode: u32,
    split: &str,
    frame_number: u32,
    frame: &RigFrame,
    image_dir: &str,
    with_depth: bool,
) {
    let split = root.join(format!("ep{episode}_500frames")).join(split);
    std::fs::create_dir_all(split.join(image_dir)).unwrap();
    std::fs::create_dir_all(split.join("depth")).unwrap();
    for (k, img) in frame.images.iter().enumerate() {
        let cam = k + 1;
        let pair = if cam <= 2 { "12" } else { "34" };
        let cassini = erp_to_cassini_rgb(img, CASSINI_WIDTH, CASSINI_HEIGHT);
        // RGBA like the dataset.
        let rgba = image::DynamicImage::ImageRgb8(cassini).to_rgba8();
        rgba.save(
            split
                .join(image_dir)
                .join(format!("{frame_number:06}_{pair}_rgb{cam}.png")),
        )
        .unwrap();
    }
    if with_depth {
        let gt = frame.ground_truth.as_ref().unwrap();
        let cassini_range = erp_to_cassini_range(gt, CASSINI_WIDTH, CASSINI_HEIGHT);
        write_npz(
            &split
                .join("depth")
                .join(format!("{frame_number:06}_depth.npz")),
            DEPTH_NPZ_KEY,
            &[CASSINI_HEIGHT, CASSINI_WIDTH],
            &cassini_range.data,
        )
        .unwrap();
    }
}

/// A synthetic frame on the Deep360 rig at `ERP_WIDTH`, clean or soiled.
fn render(index: usize, soiled: bool) -> RigFrame {
    let renderer = SynthRenderer::new(SynthConfig {
        seed: 11,
        width: ERP_WIDTH,
        soiled,
        ..SynthConfig::default()
    })
    .unwrap();
    renderer.render_frame(&deep360_rig().unwrap(), index)
}

/// The single-frame fixture: a clean frame with depth as frame [`FRAME`] of episode 2's
/// validation split; returns the frame it was written from.
pub fn write_fixture(root: &Path) -> RigFrame {
    let frame = render(3, false);
    write_frame_files(root, 2, "validation", FRAME, &frame, "rgb", true);
    frame
}

/// ERP width of the converted bags (half the fixture's rendering width).
pub const BAG_WIDTH: usize = 128;

/// Frames of the fixture's testing split: (episode, frame, render index).
pub const TEST_FRAMES: [(u32, u32, usize); 3] = [(1, 7, 20), (1, 8, 21), (3, 7, 40)];

/// One fixture frame: its id and the clean and soiled renderings it was written from.
pub struct Written {
    pub id: Deep360FrameId,
    pub clean: RigFrame,
    pub soiled: RigFrame,
}

/// Writes `frames` (clean in `rgb/`, soiled in `rgb_soiled/`) into `split`.
pub fn write_split(root: &Path, split: &str, frames: &[(u32, u32, usize)]) -> Vec<Written> {
    frames
        .iter()
        .map(|&(episode, frame, index)| {
            let clean = render(index, false);
            let soiled = render(index, true);
            write_frame_files(root, episode, split, frame, &clean, "rgb", true);
            write_frame_files(root, episode, split, frame, &soiled, "rgb_soiled", false);
            Written {
                id: Deep360FrameId { episode, frame },
                clean,
                soiled,
            }
        })
        .collect()
}

/// Converts the testing split under `root` (soiled images or clean) to a rig bag at `out`
/// of width [`BAG_WIDTH`]; returns the number of frames written.
pub fn convert(root: &Path, soiled: bool, out: &Path) -> anyhow::Result<usize> {
    convert_deep360_to_bag(&Deep360BagOptions {
        root: root.to_path_buf(),
        split: Deep360Split::Testing,
        soiled,
        width: BAG_WIDTH,
        max_frames: None,
        episode: None,
        out: out.to_path_buf(),
        show_progress: false,
    })
    .map(|s| s.frames)
}

/// Training split of the fine-tuning fixture: two frames of episode 1 with both image sets,
/// and a frame of episode 2 with clean images only.
pub fn write_training_split(root: &Path) {
    write_split(root, "training", &[(1, 0, 5), (1, 1, 6)]);
    write_frame_files(root, 2, "training", 5, &render(9, false), "rgb", true);
}
