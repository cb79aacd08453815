//! Deep360 reader: a fixture written in the dataset's layout (Cassini PNGs + npz) from a
//! synthetic frame reads back as the original ERP frame within interpolation tolerance, and
//! missing or corrupt files are named; and ground truth and images written by Python (numpy)
//! from the format's description alone (not by this crate's writer) read as the known scene
//! along every ERP ray. The fixture writers are in `deep360_writer`.

use crate::deep360_writer::{write_fixture, ERP_WIDTH, FRAME};
use mode360::deep360::{
    Deep360Dataset, Deep360Error, Deep360FrameId, Deep360Split, CASSINI_HEIGHT, CASSINI_WIDTH,
    DEPTH_NPZ_KEY,
};

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

/// Python (numpy) writes Deep360 ground truth from the format's description alone: the range
/// from camera 1 to the walls of a box room around it, off centre so that a mirrored or
/// rotated convention would not match (dataset frame `D`: x left, y up, z forward; walls at
/// x -2 and 4 m, y -1.5 and 3 m, z -3 and 7 m) as a Cassini image (row i, column j look along
/// `(sin phi, cos phi sin theta, cos phi cos theta)`, `theta = pi - (i + 0.5) 2 pi / H`,
/// `phi = pi/2 - (j + 0.5) pi / W`), saved by `numpy.savez` and `numpy.savez_compressed` with
/// numpy's own `.npy` writer. The crate reads the archives and resamples them to ERP; every
/// ERP pixel must hold the room's range along its own REP 103 direction (x forward = z_D,
/// y left = x_D, z up = y_D), computed here independently of the Cassini formulas.
#[test]
fn numpy_written_cassini_range_reads_as_the_room_along_every_erp_ray() {
    use mode360::deep360::{cassini_to_erp_range, read_npz_array};
    use mode360::frame::FloatImage;
    use mode360::geometry::{ErpGrid, PixelCoord};
    /// The room's walls along x_D, y_D, z_D (below and above camera 1), metres.
    const LOW_M: [f64; 3] = [-2.0, -1.5, -3.0];
    const HIGH_M: [f64; 3] = [4.0, 3.0, 7.0];
    const CASSINI_W: usize = 128;
    const CASSINI_H: usize = 256;
    let Some(python) = crate::common::python_with_numpy("the numpy-written fixture") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let script = format!(
        r#"
import sys, numpy as np
W, H = {CASSINI_W}, {CASSINI_H}
low = np.array([{}, {}, {}])[:, None, None]
high = np.array([{}, {}, {}])[:, None, None]
i = np.arange(H)[:, None] + 0.5
j = np.arange(W)[None, :] + 0.5
theta = np.pi - i * 2 * np.pi / H
phi = np.pi / 2 - j * np.pi / W
d = np.stack(np.broadcast_arrays(np.sin(phi), np.cos(phi) * np.sin(theta), np.cos(phi) * np.cos(theta)))
with np.errstate(divide="ignore", invalid="ignore"):
    t = np.where(d > 0, high / d, np.where(d < 0, low / d, np.inf))
r = np.min(t, axis=0)
np.savez(sys.argv[1], r.astype(np.float32))
np.savez_compressed(sys.argv[2], r.astype(np.float32))
"#,
        LOW_M[0], LOW_M[1], LOW_M[2], HIGH_M[0], HIGH_M[1], HIGH_M[2]
    );
    let (plain, compressed) = (
        dir.path().join("plain.npz"),
        dir.path().join("compressed.npz"),
    );
    let out = std::process::Command::new(&python)
        .args(["-c", &script])
        .arg(&plain)
        .arg(&compressed)
        .output()
        .expect("running python");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let grid = ErpGrid::new(128).unwrap();
    for path in [&plain, &compressed] {
        let arr = read_npz_array(path, DEPTH_NPZ_KEY).unwrap();
        assert_eq!(arr.shape, vec![CASSINI_H, CASSINI_W], "{}", path.display());
        let cassini = FloatImage {
            width: CASSINI_W,
            height: CASSINI_H,
            data: arr.data,
        };
        let erp = cassini_to_erp_range(&cassini, grid);
        let (mut worst, mut compared) = (0f64, 0usize);
        for v in 0..grid.height() {
            for u in 0..grid.width() {
                let rep = grid.dir_from_pixel(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                });
                // REP 103 -> dataset axes: x_D = y_rep (left), y_D = z_rep (up), z_D = x_rep
                let d = [rep.y, rep.z, rep.x];
                let expected = (0..3)
                    .map(|k| match d[k] {
                        x if x > 0.0 => HIGH_M[k] / x,
                        x if x < 0.0 => LOW_M[k] / x,
                        _ => f64::INFINITY,
                    })
                    .fold(f64::INFINITY, f64::min);
                let got = f64::from(erp.data[v * grid.width() + u]);
                // nearest-neighbour resampling: compare in relative terms away from the room's
                // edges, where a neighbouring Cassini pixel may see the other wall
                let rel = (got - expected).abs() / expected;
                worst = worst.max(rel.min(1.0));
                if rel < 0.05 {
                    compared += 1;
                }
            }
        }
        let share = compared as f64 / grid.len() as f64;
        assert!(
            share > 0.97,
            "{}: only {:.1} % of ERP pixels within 5 % of the room's range (worst {worst:.3})",
            path.display(),
            100.0 * share
        );
    }
}

/// Python writes a Deep360 frame from the format's description alone: each camera's RGBA PNG
/// (written with zlib and the PNG chunk layout, not an image library) is a Cassini image whose
/// pixel colour encodes the direction that pixel looks along in the dataset frame `D`
/// (`colour = round(127.5 (1 + d_D))` per axis, with row i, column j looking along
/// `(sin phi, cos phi sin theta, cos phi cos theta)`, `theta = pi - (i + 0.5) 2 pi / H`,
/// `phi = pi/2 - (j + 0.5) pi / W`); the depth archive is numpy's. Read through the crate's
/// dataset loader, every ERP pixel must show the colour of its own REP 103 direction
/// (x forward = z_D, y left = x_D, z up = y_D), computed here independently.
#[test]
fn python_written_cassini_images_look_along_their_erp_directions() {
    use mode360::geometry::{ErpGrid, PixelCoord};
    /// Largest angle between an ERP pixel's direction and the one its colour encodes.
    const MAX_ANGLE_DEG: f64 = 2.0;
    const ERP_W: usize = 256;
    let Some(python) = crate::common::python_with_numpy("the numpy-written fixture") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let split = dir.path().join("ep1_500frames").join("testing");
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(split.join(sub)).unwrap();
    }
    let script = format!(
        r#"
import sys, struct, zlib, numpy as np
W, H = {CASSINI_WIDTH}, {CASSINI_HEIGHT}
i = np.arange(H)[:, None] + 0.5
j = np.arange(W)[None, :] + 0.5
theta = np.pi - i * 2 * np.pi / H
phi = np.pi / 2 - j * np.pi / W
d = np.stack(np.broadcast_arrays(np.sin(phi), np.cos(phi) * np.sin(theta), np.cos(phi) * np.cos(theta)), axis=-1)
rgb = np.round(127.5 * (1.0 + d)).astype(np.uint8)
rgba = np.concatenate([rgb, np.full((H, W, 1), 255, np.uint8)], axis=-1)
# PNG: signature, IHDR (8-bit RGBA), IDAT (filter byte 0 per row, zlib), IEND
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
raw = b"".join(b"\x00" + rgba[r].tobytes() for r in range(H))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 6, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
split = sys.argv[1]
for name in ["12_rgb1", "12_rgb2", "34_rgb3", "34_rgb4"]:
    open(f"{{split}}/rgb/000000_{{name}}.png", "wb").write(png)
np.savez(f"{{split}}/depth/000000_depth.npz", np.full((H, W), 10.0, np.float32))
"#
    );
    let out = std::process::Command::new(&python)
        .args(["-c", &script])
        .arg(&split)
        .output()
        .expect("running python");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ds = Deep360Dataset::open(dir.path()).unwrap();
    let ids = ds.frame_ids(Deep360Split::Testing).unwrap();
    assert_eq!(ids.len(), 1);
    let frame = ds
        .load_frame(ids[0], Deep360Split::Testing, false, ERP_W)
        .unwrap();
    assert_eq!(frame.images.len(), 4);
    let grid = ErpGrid::new(ERP_W).unwrap();
    let max_cos = MAX_ANGLE_DEG.to_radians().cos();
    for (cam, img) in frame.images.iter().enumerate() {
        assert_eq!(
            (img.width() as usize, img.height() as usize),
            (ERP_W, ERP_W / 2)
        );
        let (mut within, mut worst_deg) = (0usize, 0f64);
        for v in 0..grid.height() {
            for u in 0..grid.width() {
                let rep = grid.dir_from_pixel(PixelCoord {
                    u: u as f64,
                    v: v as f64,
                });
                let p = img.get_pixel(u as u32, v as u32).0;
                let decode = |c: u8| f64::from(c) / 127.5 - 1.0;
                let (xd, yd, zd) = (decode(p[0]), decode(p[1]), decode(p[2]));
                // dataset axes -> REP 103: x = z_D, y = x_D, z = y_D
                let seen = nalgebra::Vector3::new(zd, xd, yd);
                let cos = seen.dot(&rep) / seen.norm().max(1e-12);
                worst_deg = worst_deg.max(cos.clamp(-1.0, 1.0).acos().to_degrees());
                if cos >= max_cos {
                    within += 1;
                }
            }
        }
        let share = within as f64 / grid.len() as f64;
        // Bilinear blending across the wrap seam and at the poles blurs a few pixels' colours.
        assert!(
            share > 0.98,
            "camera {}: only {:.2} % of ERP pixels look within {MAX_ANGLE_DEG} deg of their colour's direction (worst {worst_deg:.1} deg)",
            cam + 1,
            100.0 * share
        );
    }
}
