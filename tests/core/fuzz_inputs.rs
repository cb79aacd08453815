//! A deterministic fuzz suite over the inputs a user hands mode360: rig YAML, Kalibr camchains,
//! Basalt calibrations, CDR-encoded images and MCAP rig bags. Each valid seed file is mutated
//! (bytes flipped, lines dropped, duplicated or swapped, cut short, odd values and deep nesting
//! inserted) by a fixed-seed generator, and every case must end in a value or an error: no
//! panic, no case slower than [`CASE_LIMIT`], and a text error that names the file it read.
//!
//! What a refused text file's error must name besides the file ([`where_named`]):
//! - a value the file gives but the rig cannot take (a wrong type, a number beyond `f64`, a
//!   missing or unknown model, a bound) names the field (`field '...'`), and the camera
//!   (`camera '...'`) when the field is a camera's; a model that has no exact counterpart
//!   names the camera and the model (`model '...'`);
//! - text that is not YAML or JSON, or a key given twice, is "malformed" and names the line and
//!   the column (`at line L column C`); rig YAML's type errors are serde_yaml's, which also
//!   give the field's path (`cameras[0].intrinsics.fx: invalid type ...`), while Kalibr's and
//!   Basalt's are never "malformed": they name the camera and the field;
//! - a top-level Kalibr key that is not a camera (`cam0`, `cam1`, ...) names the key;
//! - a problem of the file as a whole (too large, nested too deep, no cameras, a gap in
//!   Kalibr's chain, Basalt's per-camera lists of different lengths) says which
//!   ([`WHOLE_FILE`]).
//!
//! `mode360 rig import` is run on every Kalibr and Basalt case with an existing output file:
//! a refused input leaves it byte for byte, and no partial file beside it.

use mode360::bag::{BagReader, RigBagReader, RigBagWriter};
use mode360::cli::rig::{run_import, RigImportArgs};
use mode360::frame::{RgbImage, RigFrame};
use mode360::geometry::Rig;
use mode360::msgs::image::{image_msg_from_rgb, rgb_from_image_msg};
use mode360::msgs::{decode_cdr, encode_cdr, Header, Image};
use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::time::{Duration, Instant};

/// Mutated cases per seed file.
const CASES_PER_SEED: u64 = 60;
/// Longest a single case may take (a hang guard, generous for a loaded 2-core machine).
const CASE_LIMIT: Duration = Duration::from_secs(5);
/// Values that parsers find hard.
const ODD_TOKENS: [&str; 12] = [
    "nan",
    ".inf",
    "-1e400",
    "1e308",
    "\u{feff}",
    "[[[[[[[[[[[[[[[[",
    "{{{{{{{{",
    "\"\\u0000\"",
    "~",
    "- - - -",
    "'unterminated",
    "99999999999999999999999",
];

/// Errors about a file as a whole: what each says instead of a field or a position.
const WHOLE_FILE: [&str; 6] = [
    "larger than",
    "nested",
    "flow collections",
    "no cameras",
    "the chain has a gap",
    "one each per camera",
];

/// What a refused text file's error names besides the file (the module docs' rules).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Named {
    /// `field '...'` (with `camera '...'` where it is a camera's), or a camera's model.
    Field,
    /// A top-level key that is not a camera, or one given twice: `key '...'`.
    Key,
    /// A malformed file: `line L column C`.
    Position,
    /// A problem of the whole file ([`WHOLE_FILE`]).
    WholeFile,
}

/// Whether `e` says `line <digits> column <digits>`.
fn names_position(e: &str) -> bool {
    let digits = |s: &str| s.chars().take_while(char::is_ascii_digit).count();
    e.match_indices("line ").any(|(i, _)| {
        let rest = &e[i + 5..];
        let n = digits(rest);
        n > 0
            && rest[n..]
                .strip_prefix(" column ")
                .is_some_and(|c| digits(c) > 0)
    })
}

/// What `e` names by the module docs' rules, or `Err` saying which rule it breaks.
fn where_named(e: &str) -> Result<Named, String> {
    if e.contains("malformed") {
        return if names_position(e) {
            Ok(Named::Position)
        } else {
            Err("a malformed file's error names no line and column".into())
        };
    }
    let camera = e.contains("camera '");
    if e.contains("field '") || (camera && e.contains("model '")) {
        return Ok(Named::Field);
    }
    if camera {
        return Err("names a camera but not its field".into());
    }
    if e.contains("key '") || e.contains("key \"") {
        return Ok(Named::Key);
    }
    if WHOLE_FILE.iter().any(|w| e.contains(w)) {
        return Ok(Named::WholeFile);
    }
    Err("names no field, no position and no whole-file problem".into())
}

/// xorshift64*: a fixed stream per case.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One mutation of `text` (line-aware for text formats).
fn mutate_text(text: &str, rng: &mut Rng) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let n = lines.len().max(1);
    match rng.below(7) {
        0 => {
            lines.remove(rng.below(n).min(lines.len().saturating_sub(1)));
        }
        1 => {
            let i = rng.below(n).min(lines.len().saturating_sub(1));
            let line = lines[i].clone();
            lines.insert(i, line);
        }
        2 => {
            let (a, b) = (rng.below(n), rng.below(n));
            if a < lines.len() && b < lines.len() {
                lines.swap(a, b);
            }
        }
        3 => {
            let i = rng.below(n).min(lines.len().saturating_sub(1));
            let token = ODD_TOKENS[rng.below(ODD_TOKENS.len())];
            let line = &mut lines[i];
            let at = rng.below(line.len() + 1);
            let at = (0..=at)
                .rev()
                .find(|&k| line.is_char_boundary(k))
                .unwrap_or(0);
            line.insert_str(at, token);
        }
        4 => {
            let i = rng.below(n).min(lines.len().saturating_sub(1));
            // Replace a number with an odd one.
            let token = ODD_TOKENS[rng.below(ODD_TOKENS.len())];
            lines[i] = lines[i]
                .split(' ')
                .map(|w| {
                    if w.trim_matches(|c: char| !c.is_ascii_digit()).is_empty() {
                        w.to_string()
                    } else {
                        token.to_string()
                    }
                })
                .collect::<Vec<_>>()
                .join(" ");
        }
        5 => {
            let keep = rng.below(text.len() + 1);
            let keep = (0..=keep)
                .rev()
                .find(|&k| text.is_char_boundary(k))
                .unwrap_or(0);
            return text[..keep].to_string();
        }
        _ => {
            let mut bytes = text.as_bytes().to_vec();
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(bytes.len());
                if let Some(b) = bytes.get_mut(i) {
                    *b ^= 1 << rng.below(7);
                }
            }
            return String::from_utf8_lossy(&bytes).into_owned();
        }
    }
    lines.join("\n")
}

/// One mutation of binary `bytes`: flips, a cut, or a zeroed run.
fn mutate_bytes(bytes: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut out = bytes.to_vec();
    match rng.below(3) {
        0 => {
            for _ in 0..1 + rng.below(8) {
                let i = rng.below(out.len());
                if let Some(b) = out.get_mut(i) {
                    *b ^= 1 << rng.below(8);
                }
            }
        }
        1 => out.truncate(rng.below(bytes.len())),
        _ => {
            let start = rng.below(out.len());
            let end = (start + 1 + rng.below(64)).min(out.len());
            out[start..end].fill(0);
        }
    }
    out
}

/// Runs `case` for every mutation of `seed` and checks the outcome; returns (accepted, refused).
fn fuzz<T>(
    name: &str,
    cases: u64,
    mut case: impl FnMut(u64) -> Result<T, String>,
) -> (usize, usize) {
    let (mut ok, mut refused) = (0, 0);
    for k in 0..cases {
        let t0 = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| case(k)));
        let took = t0.elapsed();
        assert!(took < CASE_LIMIT, "{name} case {k} took {took:?}");
        match outcome {
            Err(_) => panic!("{name} case {k} panicked"),
            Ok(Ok(_)) => ok += 1,
            Ok(Err(e)) => {
                assert!(!e.trim().is_empty(), "{name} case {k}: empty error");
                refused += 1;
            }
        }
    }
    (ok, refused)
}

fn repo(relative: &str) -> String {
    format!("{}/{relative}", env!("CARGO_MANIFEST_DIR"))
}

/// Mutated text files read by `read`; errors must name the file and what the module docs'
/// rules ask. Returns (accepted, refused) and the refusals by what they name.
fn fuzz_text_files(
    label: &str,
    seed_file: &str,
    extension: &str,
    read: impl Fn(&Path) -> Result<(), String>,
) -> ((usize, usize), BTreeMap<Named, usize>) {
    let text = std::fs::read_to_string(repo(seed_file)).expect("seed file");
    let dir = tempfile::tempdir().expect("tempdir");
    let mut named = BTreeMap::new();
    let counts = fuzz(label, CASES_PER_SEED, |k| {
        let mut rng = Rng::new(k + 1);
        let mut mutated = text.clone();
        for _ in 0..1 + rng.below(3) {
            mutated = mutate_text(&mutated, &mut rng);
        }
        let path = dir.path().join(format!("case{k}.{extension}"));
        std::fs::write(&path, mutated).expect("write case");
        read(&path).map_err(|e| {
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            assert!(
                e.contains(name.as_deref().unwrap_or("?")),
                "{label} case {k}: error does not name the file: {e}"
            );
            match where_named(&e) {
                Ok(n) => *named.entry(n).or_insert(0) += 1,
                Err(rule) => panic!("{label} case {k}: {rule}: {e}"),
            }
            e
        })
    });
    (counts, named)
}

/// `mode360 rig import` of `input` (`--kalibr` or `--basalt`) over an existing `out` file:
/// refused, `out` keeps its bytes and nothing is left beside it; imported, `out` is a rig.
fn import_over_existing(input: &Path, kalibr: bool, out: &Path) -> Result<(), String> {
    const BEFORE: &[u8] = b"# an existing rig file the import must not touch when it fails\n";
    std::fs::write(out, BEFORE).expect("existing output");
    let input = Some(input.to_path_buf());
    let outcome = run_import(RigImportArgs {
        kalibr: input.clone().filter(|_| kalibr),
        basalt: input.filter(|_| !kalibr),
        out: out.to_path_buf(),
        rig_frame: "rig".into(),
        topic_prefix: None,
    });
    let after = std::fs::read(out).expect("output still there");
    let dir = out.parent().expect("output folder");
    let partial = std::fs::read_dir(dir)
        .expect("list output folder")
        .filter_map(|f| f.ok())
        .map(|f| f.file_name().to_string_lossy().into_owned())
        .find(|f| f.contains("partial"));
    assert_eq!(
        partial,
        None,
        "a partial file is left beside {}",
        out.display()
    );
    match outcome {
        Err(e) => {
            let message = format!("{e:#}");
            // A field's value of the wrong type is the camera's field's error, not serde's.
            assert!(
                !message.contains("expected f64") && !message.contains("expected a sequence"),
                "a bad value is reported as malformed: {message}"
            );
            assert!(
                after == BEFORE,
                "a refused import changed {}: {e:#}",
                out.display()
            );
            Err(format!("{e:#}"))
        }
        Ok(()) => {
            assert!(
                after != BEFORE,
                "an accepted import left {} as it was",
                out.display()
            );
            if let Err(e) = Rig::from_file(out) {
                panic!("the imported rig does not read back: {e}");
            }
            Ok(())
        }
    }
}

#[test]
fn mutated_rig_yaml_files_are_read_or_refused_naming_the_file() {
    let mut total = (0, 0);
    let mut named = BTreeMap::new();
    for seed in [
        "launch_configs/rig_deep360.yaml",
        "launch_configs/rig_omnimvs.yaml",
        "launch_configs/rig_dual_fisheye.yaml",
    ] {
        let ((ok, refused), by) = fuzz_text_files("rig yaml", seed, "yaml", |p| {
            Rig::from_file(p).map(|_| ()).map_err(|e| e.to_string())
        });
        total = (total.0 + ok, total.1 + refused);
        for (n, c) in by {
            *named.entry(n).or_insert(0) += c;
        }
    }
    println!(
        "rig YAML: {} accepted, {} refused naming {named:?}",
        total.0, total.1
    );
    assert!(named.contains_key(&Named::Field) && named.contains_key(&Named::Position));
    assert!(
        total.1 > total.0,
        "most mutations should be refused: {total:?}"
    );
}

#[test]
fn mutated_kalibr_and_basalt_files_are_imported_or_refused_naming_the_file() {
    let out_dir = tempfile::tempdir().expect("tempdir");
    let out = out_dir.path().join("rig.yaml");
    let (kalibr, kalibr_named) = fuzz_text_files(
        "kalibr",
        "tests/fixtures/calib/kalibr_camchain.yaml",
        "yaml",
        |p| import_over_existing(p, true, &out),
    );
    let (basalt, basalt_named) = fuzz_text_files(
        "basalt",
        "tests/fixtures/calib/basalt_calibration.json",
        "json",
        |p| import_over_existing(p, false, &out),
    );
    println!(
        "Kalibr: {kalibr:?} naming {kalibr_named:?}, Basalt: {basalt:?} naming {basalt_named:?} \
         (accepted, refused)"
    );
    assert!(kalibr.1 > 0 && basalt.1 > 0);
    assert!(kalibr_named.contains_key(&Named::Field) && basalt_named.contains_key(&Named::Field));
}

#[test]
fn the_naming_rules_accept_and_refuse_what_they_say() {
    let ok = |e: &str, n: Named| assert_eq!(where_named(e), Ok(n), "{e}");
    ok(
        "a.yaml: camera 'cam0': field 'intrinsics[2]': \"1e400\" is beyond",
        Named::Field,
    );
    ok(
        "a.yaml: camera 'cam2': model 'omni/radtan' cannot be represented",
        Named::Field,
    );
    ok(
        "a.yaml: key 'cao2' is not a Kalibr camera (cam0, cam1, ...)",
        Named::Key,
    );
    ok(
        "a.yaml: malformed YAML: did not find expected key at line 3 column 5",
        Named::Position,
    );
    ok(
        "a.json: 4 intrinsics, 3 T_imu_cam and 4 resolution entries: one each per camera",
        Named::WholeFile,
    );
    for bad in [
        "a.yaml: malformed YAML: invalid type: string, expected f64",
        "a.yaml: malformed YAML: at line 3",
        "a.yaml: camera 'cam0': cannot read it",
        "a.yaml: something went wrong",
    ] {
        assert!(where_named(bad).is_err(), "{bad}");
    }
}

#[test]
fn mutated_cdr_images_decode_or_are_refused() {
    let img = RgbImage::from_fn(16, 8, |u, v| image::Rgb([u as u8 * 9, v as u8 * 17, 3]));
    let bytes = encode_cdr(&image_msg_from_rgb(Header::new(5, "cam1"), &img));
    let (ok, refused) = fuzz("cdr image", 4 * CASES_PER_SEED, |k| {
        let mut rng = Rng::new(1000 + k);
        let mutated = mutate_bytes(&bytes, &mut rng);
        let msg: Image = decode_cdr(&mutated).map_err(|e| e.to_string())?;
        rgb_from_image_msg(&msg).map_err(|e| e.to_string())
    });
    println!("CDR images: {ok} decoded, {refused} refused");
    assert!(refused > 0);
}

#[test]
fn mutated_bags_are_read_or_refused_without_losing_good_frames() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rig = Rig::from_file(repo("launch_configs/rig_deep360.yaml")).expect("rig");
    let seed_bag = dir.path().join("seed.mcap");
    let mut writer = RigBagWriter::create(&seed_bag, &rig, &BTreeMap::new()).expect("writer");
    for f in 0..3u64 {
        let img = RgbImage::from_fn(32, 16, |u, v| image::Rgb([u as u8, v as u8, f as u8]));
        writer
            .write_frame(&RigFrame {
                stamp_ns: 1_000_000_000 + f * 100_000_000,
                images: vec![img; rig.cameras.len()],
                ground_truth: None,
                labels: None,
            })
            .expect("frame");
    }
    writer.finish().expect("finish");
    let bytes = std::fs::read(&seed_bag).expect("seed bag");
    let (ok, refused) = fuzz("bag", CASES_PER_SEED, |k| {
        let mut rng = Rng::new(5000 + k);
        let path = dir.path().join(format!("case{k}.mcap"));
        std::fs::write(&path, mutate_bytes(&bytes, &mut rng)).expect("write case");
        let name = format!("case{k}.mcap");
        let named = |e: String| {
            assert!(
                e.contains(&name),
                "bag case {k}: error does not name the file: {e}"
            );
            e
        };
        BagReader::open(&path).map_err(|e| named(e.to_string()))?;
        let reader = RigBagReader::open(&path).map_err(|e| named(e.to_string()))?;
        let frames = reader.frames().filter(|f| f.is_ok()).count();
        assert!(frames <= 3, "bag case {k}: {frames} frames from 3");
        Ok(frames)
    });
    println!("bags: {ok} read, {refused} refused");
    assert!(ok + refused == CASES_PER_SEED as usize);
}
