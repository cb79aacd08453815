//! Deep360 reader: a fixture written in the dataset's layout (Cassini PNGs + npz) from a
//! synthetic frame reads back as the original ERP frame within interpolation tolerance.

use mode360::deep360::{
    deep360_rig, erp_to_cassini_range, erp_to_cassini_rgb, write_npz, Deep360Dataset, Deep360Error,
    Deep360FrameId, Deep360Split, CASSINI_HEIGHT, CASSINI_WIDTH, DEPTH_NPZ_KEY,
};
use mode360::synth::{SynthConfig, SynthRenderer};

const ERP_WIDTH: usize = 256;
const FRAME: u32 = 42;

fn write_fixture(root: &std::path::Path) -> mode360::frame::RigFrame {
    let rig = deep360_rig().unwrap();
    let renderer = SynthRenderer::new(SynthConfig {
        seed: 11,
        width: ERP_WIDTH,
        ..SynthConfig::default()
    })
    .unwrap();
    let frame = renderer.render_frame(&rig, 3);
    let split = root.join("ep2_500frames").join("validation");
    std::fs::create_dir_all(split.join("rgb")).unwrap();
    std::fs::create_dir_all(split.join("depth")).unwrap();
    for (k, img) in frame.images.iter().enumerate() {
        let cam = k + 1;
        let pair = if cam <= 2 { "12" } else { "34" };
        let cassini = erp_to_cassini_rgb(img, CASSINI_WIDTH, CASSINI_HEIGHT);
        // RGBA like the dataset.
        let rgba = image::DynamicImage::ImageRgb8(cassini).to_rgba8();
        rgba.save(
            split
                .join("rgb")
                .join(format!("{FRAME:06}_{pair}_rgb{cam}.png")),
        )
        .unwrap();
    }
    let gt = frame.ground_truth.as_ref().unwrap();
    let cassini_range = erp_to_cassini_range(gt, CASSINI_WIDTH, CASSINI_HEIGHT);
    write_npz(
        &split.join("depth").join(format!("{FRAME:06}_depth.npz")),
        DEPTH_NPZ_KEY,
        &[CASSINI_HEIGHT, CASSINI_WIDTH],
        &cassini_range.data,
    )
    .unwrap();
    frame
}

#[test]
fn fixture_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let original = write_fixture(dir.path());
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let ids = ds.frame_ids(Deep360Split::Validation).unwrap();
    assert_eq!(
        ids,
        vec![Deep360FrameId {
            episode: 2,
            frame: FRAME
        }]
    );
    assert!(ds.frame_ids(Deep360Split::Training).unwrap().is_empty());
    let frame = ds
        .load_frame(ids[0], Deep360Split::Validation, false, ERP_WIDTH)
        .unwrap();
    assert_eq!(frame.images.len(), 4);
    // Colour: ERP -> Cassini (2x finer) -> ERP, bilinear both ways.
    for (k, (a, b)) in original.images.iter().zip(&frame.images).enumerate() {
        assert_eq!(a.dimensions(), b.dimensions());
        let diffs: Vec<f64> = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(&x, &y)| (f64::from(x) - f64::from(y)).abs())
            .collect();
        let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
        let within = diffs.iter().filter(|d| **d <= 12.0).count() as f64 / diffs.len() as f64;
        assert!(mean < 4.0, "camera {}: mean abs diff {mean}", k + 1);
        assert!(within > 0.93, "camera {}: {within} within 12 levels", k + 1);
    }
    // Range: nearest neighbour both ways, exact except at depth edges.
    let gt_a = original.ground_truth.as_ref().unwrap();
    let gt_b = frame.ground_truth.as_ref().unwrap();
    let close = gt_a
        .data
        .iter()
        .zip(&gt_b.data)
        .filter(|(a, b)| ((*a - *b) / *a).abs() < 0.01)
        .count() as f64
        / gt_a.data.len() as f64;
    assert!(close > 0.97, "only {close} of range pixels within 1%");
}

#[test]
fn missing_and_corrupt_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    write_fixture(dir.path());
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let id = Deep360FrameId {
        episode: 2,
        frame: FRAME,
    };
    // Soiled images were not written.
    let err = ds
        .load_frame(id, Deep360Split::Validation, true, ERP_WIDTH)
        .unwrap_err();
    assert!(matches!(err, Deep360Error::Io { .. }));
    assert!(err.to_string().contains("rgb_soiled"), "{err}");
    assert!(err.to_string().contains("000042_12_rgb1.png"), "{err}");
    // Corrupt depth archive.
    let depth = ds.depth_path(id, Deep360Split::Validation);
    std::fs::write(&depth, b"not a zip").unwrap();
    let err = ds
        .load_frame(id, Deep360Split::Validation, false, ERP_WIDTH)
        .unwrap_err();
    assert!(matches!(err, Deep360Error::Npz { .. }));
    assert!(err.to_string().contains("000042_depth.npz"), "{err}");
    assert!(Deep360Dataset::open(dir.path().join("nope")).is_err());
}
