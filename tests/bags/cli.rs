//! The `mode360` binary end to end: synth -> bag -> eval, and clear errors on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn mode360(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mode360"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the mode360 binary runs")
}

fn rig_path() -> String {
    format!(
        "{}/launch_configs/rig_deep360.yaml",
        env!("CARGO_MANIFEST_DIR")
    )
}

fn synth(dir: &Path, name: &str, extra: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let out_s = out.to_string_lossy().to_string();
    let rig = rig_path();
    let mut args = vec![
        "synth", "--rig", &rig, "--frames", "2", "--width", "128", "--seed", "5", "--out", &out_s,
    ];
    args.extend_from_slice(extra);
    let o = mode360(&args);
    assert!(
        o.status.success(),
        "synth failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

#[test]
fn synth_then_eval_prints_and_writes_the_table() {
    let dir = tempfile::tempdir().unwrap();
    let clean = synth(dir.path(), "clean.mcap", &[]);
    let soiled = synth(dir.path(), "soiled.mcap", &["--soiled"]);
    let json = dir.path().join("eval.json");
    let pngs = dir.path().join("png");
    let o = mode360(&[
        "eval",
        "--bag",
        clean.to_str().unwrap(),
        "--bag",
        soiled.to_str().unwrap(),
        "--estimator",
        "photometric",
        "--json",
        json.to_str().unwrap(),
        "--png-dir",
        pngs.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "eval failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        stdout.contains("| clean |") && stdout.contains("| soiled |"),
        "{stdout}"
    );
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for row in rows {
        assert_eq!(row["frames"], 2);
        let d1 = row["depth"]["delta1_pct"].as_f64().unwrap();
        // A coarse 128x64 sweep is still far better than chance on the synthetic street.
        assert!(d1 > 50.0 && d1 <= 100.0, "delta1 {d1}");
        // the JSON and the printed table report the same AbsRel (4 decimals in the table)
        let abs_rel = row["depth"]["abs_rel"].as_f64().unwrap();
        let condition = row["condition"].as_str().unwrap();
        let printed: f64 = stdout
            .lines()
            .find(|l| l.starts_with(&format!("| {condition} |")))
            .and_then(|l| l.split('|').nth(6))
            .and_then(|c| c.trim().parse().ok())
            .unwrap_or_else(|| panic!("no AbsRel for {condition} in {stdout}"));
        assert!(
            abs_rel > 0.0 && (abs_rel - printed).abs() <= 5e-5,
            "AbsRel {abs_rel} (JSON) vs {printed} (table)"
        );
    }
    let n_png = std::fs::read_dir(&pngs).unwrap().count();
    assert_eq!(n_png, 4, "two previews per bag");
}

#[test]
fn camera_subset_is_one_based_and_validated() {
    let dir = tempfile::tempdir().unwrap();
    let bag = synth(dir.path(), "b.mcap", &[]);
    let o = mode360(&[
        "eval",
        "--bag",
        bag.to_str().unwrap(),
        "--cameras",
        "0,1",
        "--max-frames",
        "1",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("1-based"));
    let o = mode360(&[
        "eval",
        "--bag",
        bag.to_str().unwrap(),
        "--cameras",
        "1,7",
        "--max-frames",
        "1",
    ]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("camera 7"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn bad_rig_yaml_names_the_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad_rig.yaml");
    let text = std::fs::read_to_string(rig_path()).unwrap().replacen(
        "rotation_xyzw: [0.0, 0.0, 0.0, 1.0]",
        "rotation_xyzw: [0.0, 0.0, 0.5, 1.0]",
        1,
    );
    std::fs::write(&bad, text).unwrap();
    let out = dir.path().join("x.mcap");
    let o = mode360(&[
        "synth",
        "--rig",
        bad.to_str().unwrap(),
        "--frames",
        "1",
        "--width",
        "64",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad_rig.yaml") && err.contains("cam1") && err.contains("rotation_xyzw"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn truncated_bag_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let bag = synth(dir.path(), "t.mcap", &[]);
    let bytes = std::fs::read(&bag).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let o = mode360(&["eval", "--bag", cut.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("cut.mcap"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn delta1(report: &serde_json::Value) -> f64 {
    report["rows"][0]["depth"]["delta1_pct"].as_f64().unwrap()
}

#[test]
fn same_image_flags_and_bag_rewrite_agree() {
    let dir = tempfile::tempdir().unwrap();
    let bag = synth(dir.path(), "b.mcap", &[]);
    let bag_s = bag.to_str().unwrap();
    let json = |name: &str| dir.path().join(name);
    let eval = |extra: &[&str], out: &Path| {
        // The sweep, named: the bounds below were measured on it.
        let mut args = vec![
            "eval",
            "--bag",
            bag_s,
            "--max-frames",
            "1",
            "--estimator",
            "photometric",
        ];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--json", out.to_str().unwrap()]);
        mode360(&args)
    };

    let o = eval(&["--geometry-share"], &json("share.json"));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("photometric (true views)"), "{stdout}");
    assert!(
        stdout.contains("photometric (same-image views)"),
        "{stdout}"
    );
    assert!(stdout.contains("geometry share"), "{stdout}");
    let share = read_json(&json("share.json"));
    assert_eq!(share["true_views"]["views"], "true");
    assert_eq!(share["same_image"]["views"], "same-image");
    let row = &share["geometry_share"][0];
    let (t, s) = (delta1(&share["true_views"]), delta1(&share["same_image"]));
    assert_eq!(row["delta1_true_pct"].as_f64(), Some(t));
    assert_eq!(row["delta1_same_image_pct"].as_f64(), Some(s));
    assert!((row["share_pts"].as_f64().unwrap() - (t - s)).abs() <= 1e-9);
    // Even on a coarse 128x64 frame the sweep loses half its δ1 without parallax (measured
    // 66.10 -> 32.21 %, share 33.89 points).
    assert!(t - s > 20.0, "true {t}, same image {s}");

    let o = eval(&["--same-image"], &json("same.json"));
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("(same-image views)"));
    let same = read_json(&json("same.json"));
    assert_eq!(same["views"], "same-image");
    assert_eq!(delta1(&same), s);

    let o = eval(&["--same-image", "--geometry-share"], &json("x.json"));
    assert!(!o.status.success(), "the two flags conflict");

    // The rewritten bag, evaluated with true views, is the same-image pass.
    let rewritten = dir.path().join("same.mcap");
    let o = mode360(&[
        "same-image-bag",
        "--bag",
        bag_s,
        "--out",
        rewritten.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("camera 'cam1'"));
    let o = mode360(&[
        "eval",
        "--bag",
        rewritten.to_str().unwrap(),
        "--max-frames",
        "1",
        "--estimator",
        "photometric",
        "--json",
        json("rewritten.json").to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let rewritten = read_json(&json("rewritten.json"));
    assert_eq!(rewritten["views"], "true");
    assert!((delta1(&rewritten) - s).abs() <= 1e-9);
}

/// One README option table: the command it documents and its rows (option cell, default cell).
struct OptionTable {
    command: String,
    rows: Vec<(Vec<String>, String)>,
}

/// The option tables of docs/commands.md, each announced by `<!-- options: COMMAND -->`.
fn readme_option_tables() -> Vec<OptionTable> {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/commands.md"))
        .expect("docs/commands.md");
    let mut tables = Vec::new();
    let mut lines = readme.lines();
    while let Some(line) = lines.next() {
        let Some(command) = line
            .strip_prefix("<!-- options: ")
            .and_then(|r| r.strip_suffix(" -->"))
        else {
            continue;
        };
        let mut rows = Vec::new();
        for row in lines.by_ref().skip(2) {
            if !row.starts_with('|') {
                break;
            }
            let cells: Vec<&str> = row.split('|').map(str::trim).collect();
            let flags = cells[1]
                .split(',')
                .map(|f| f.trim().trim_matches('`').to_string())
                .collect();
            rows.push((flags, cells[2].trim_matches('`').to_string()));
        }
        tables.push(OptionTable {
            command: command.to_string(),
            rows,
        });
    }
    tables
}

/// `--flag` -> its `[default: X]` (None without one), from `mode360 COMMAND --help`.
fn help_options(command: &str) -> std::collections::BTreeMap<String, Option<String>> {
    // A nested command's table is announced with its words, e.g. `rig import`.
    let mut args: Vec<&str> = command.split_whitespace().collect();
    args.push("--help");
    let o = mode360(&args);
    assert!(o.status.success(), "{command} --help");
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    let mut options = std::collections::BTreeMap::new();
    // clap puts each option on its own line, its default at the end of its help text
    let mut current: Option<String> = None;
    for line in text.lines() {
        let t = line.trim_start();
        if let Some(flag) = t
            .split([' ', ','])
            .find(|w| w.starts_with("--"))
            .filter(|_| t.starts_with('-'))
        {
            current = Some(flag.to_string());
            options.insert(flag.to_string(), None);
        }
        if let (Some(flag), Some(start)) = (&current, t.find("[default: ")) {
            let rest = &t[start + "[default: ".len()..];
            let value = rest.split(']').next().unwrap_or_default().to_string();
            options.insert(flag.clone(), Some(value));
        }
    }
    options.remove("--help");
    options.remove("--version");
    options
}

/// Whether a README default cell states clap's default: the same text, the same number, or
/// the same list (clap shows `default_values_t` space separated, the flag takes commas).
fn same_default(readme: &str, clap: &str) -> bool {
    let number = |s: &str| s.replace('_', "").parse::<f64>().ok();
    let list = |s: &str| -> Vec<String> {
        s.split([',', ' '])
            .filter(|w| !w.is_empty())
            .map(str::to_string)
            .collect()
    };
    readme == clap
        || matches!((number(readme), number(clap)), (Some(a), Some(b)) if a == b)
        || list(readme) == list(clap)
}

/// Every documented command's option table lists exactly the options of its `--help`, with
/// the same defaults where clap has one, and every subcommand but `node` (whose parameters
/// have their own table) has a table.
#[test]
fn readme_option_tables_match_help() {
    let tables = readme_option_tables();
    let mut problems = Vec::new();
    for t in &tables {
        assert!(!t.rows.is_empty(), "{}: empty README table", t.command);
        let help = help_options(&t.command);
        let mut documented = std::collections::BTreeSet::new();
        for (flags, default) in &t.rows {
            for flag in flags {
                documented.insert(flag.clone());
                match help.get(flag) {
                    None => problems.push(format!(
                        "{}: README documents {flag}, --help has no such option",
                        t.command
                    )),
                    Some(Some(d)) if flags.len() == 1 && !same_default(default, d) => problems
                        .push(format!(
                            "{}: {flag} default is '{d}' in --help, '{default}' in the README",
                            t.command
                        )),
                    Some(_) => {}
                }
            }
        }
        for flag in help.keys().filter(|f| !documented.contains(*f)) {
            problems.push(format!(
                "{}: {flag} is missing from the README table",
                t.command
            ));
        }
    }
    let o = mode360(&["--help"]);
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    let commands: Vec<&str> = text
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| !matches!(*c, "help" | "node"))
        .collect();
    assert!(commands.len() >= 10, "{text}");
    for c in commands {
        if !tables
            .iter()
            .any(|t| t.command.split_whitespace().next() == Some(c))
        {
            problems.push(format!("{c}: no README option table"));
        }
    }
    assert!(
        problems.is_empty(),
        "README vs --help:\n{}",
        problems.join("\n")
    );
}

/// `mode360 rig import` writes a rig YAML that loads, from a Kalibr camchain and a Basalt
/// calibration (tests/fixtures/calib); a camchain with an unknown model is a clear error that
/// names the camera and the model, not a panic.
#[test]
fn rig_import_writes_a_loadable_rig_and_refuses_unknown_models() {
    let dir = tempfile::tempdir().unwrap();
    let fixture = |n: &str| format!("{}/tests/fixtures/calib/{n}", env!("CARGO_MANIFEST_DIR"));
    let out = dir.path().join("rig.yaml");
    let o = mode360(&[
        "rig",
        "import",
        "--kalibr",
        &fixture("kalibr_camchain.yaml"),
        "--out",
        out.to_str().unwrap(),
        "--rig-frame",
        "cam0_rig",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rig = mode360::geometry::Rig::from_file(&out).unwrap();
    assert_eq!(rig.rig_frame, "cam0_rig");
    let kinds: Vec<&str> = rig.cameras.iter().map(|c| c.projection.name()).collect();
    assert_eq!(kinds, ["double_sphere", "kannala_brandt", "eucm", "eucm"]);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("cam1: kannala_brandt on /camera1/image_raw")
    );

    let o = mode360(&[
        "rig",
        "import",
        "--basalt",
        &fixture("basalt_calibration.json"),
        "--out",
        out.to_str().unwrap(),
        "--topic-prefix",
        "/vi",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rig = mode360::geometry::Rig::from_file(&out).unwrap();
    assert_eq!(rig.cameras[3].topic, "/vi/cam3/image_raw");

    let bad = dir.path().join("camchain.yaml");
    let text = std::fs::read_to_string(fixture("kalibr_camchain.yaml")).unwrap();
    std::fs::write(
        &bad,
        text.replacen("camera_model: omni", "camera_model: scaramuzza", 1),
    )
    .unwrap();
    let o = mode360(&[
        "rig",
        "import",
        "--kalibr",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("camera 'cam2'") && err.contains("unknown camera model 'scaramuzza'"),
        "{err}"
    );
    // Neither or both sources: clap refuses.
    let o = mode360(&["rig", "import", "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
}

/// A run that fails never touches an existing output: an oversized fisheye calibration and
/// an oversized width are refused before anything is allocated, naming the field and the
/// limit, and the bag already at `--out` keeps its bytes; a run that succeeds replaces it
/// whole and leaves no temporary file.
#[test]
fn failed_runs_leave_existing_outputs_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("keep.mcap");
    std::fs::write(&out, b"precious").unwrap();
    let huge = dir.path().join("huge.yaml");
    std::fs::write(
        &huge,
        "cameras:\n  - {name: a, topic: /a, frame_id: a, projection: kannala_brandt, \
         image_size: [200000, 200000], intrinsics: {fx: 100, fy: 100, cx: 100000, cy: 100000, \
         k1: 0, k2: 0, k3: 0, k4: 0}, rig_from_cam: {translation: [0, 0, 1], rotation_xyzw: [0, 0, 0, 1]}}\n  \
         - {name: b, topic: /b, frame_id: b, rig_from_cam: {translation: [0, 1, 1], rotation_xyzw: [0, 0, 0, 1]}}\n",
    )
    .unwrap();
    let out_arg = out.to_str().unwrap();
    for (args, needles) in [
        (
            vec![
                "synth",
                "--rig",
                huge.to_str().unwrap(),
                "--frames",
                "1",
                "--out",
                out_arg,
            ],
            ["image_size", "16384"],
        ),
        (
            vec![
                "synth", "--width", "100000", "--frames", "1", "--out", out_arg,
            ],
            ["100000", "16384"],
        ),
    ] {
        let o = mode360(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        for n in needles {
            assert!(err.contains(n), "{args:?}: '{err}' should mention {n}");
        }
        assert_eq!(std::fs::read(&out).unwrap(), b"precious", "{args:?}");
    }
    let o = mode360(&["synth", "--width", "64", "--frames", "1", "--out", out_arg]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_ne!(std::fs::read(&out).unwrap(), b"precious");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("partial"))
        .collect();
    assert!(left.is_empty(), "temporary files left: {left:?}");
}

/// A rig whose frames would not fit in memory is refused before rendering, with what a frame
/// would need, and the existing output stays.
#[test]
fn synth_refuses_frames_that_would_not_fit_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("keep.mcap");
    std::fs::write(&out, b"precious").unwrap();
    let big = dir.path().join("big.yaml");
    let camera = |i: usize| {
        format!(
            "  - {{name: c{i}, topic: /c{i}, frame_id: c{i}, projection: kannala_brandt, \
             image_size: [16384, 16384], intrinsics: {{fx: 5000, fy: 5000, cx: 8192, cy: 8192, \
             k1: 0, k2: 0, k3: 0, k4: 0}}, rig_from_cam: {{translation: [0, {i}, 1], \
             rotation_xyzw: [0, 0, 0, 1]}}}}\n"
        )
    };
    let yaml: String = std::iter::once("cameras:\n".to_string())
        .chain((0..4).map(camera))
        .collect();
    std::fs::write(&big, yaml).unwrap();
    // 4 x 16384^2 pixels at 64 bytes a pixel: about 65,600 MiB.
    let need_mib = 4.0 * 16384.0 * 16384.0 * 64.0 / (1024.0 * 1024.0);
    match mode360::memory::available_mib() {
        Some(available) if available < need_mib => {}
        other => {
            println!("skipped: {other:?} MiB available, the rig needs {need_mib:.0}");
            return;
        }
    }
    let o = mode360(&[
        "synth",
        "--rig",
        big.to_str().unwrap(),
        "--frames",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("needs about") && err.contains("MiB are available"),
        "{err}"
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"precious");
}
