//! `--device` in the `mode360` binary: on a machine without an NVIDIA GPU (CI) or in a build
//! without the `cuda` feature, asking for CUDA is an error that names CUDA and what was found,
//! exit code 1, no panic and no output file, in every command that takes the option; a
//! malformed device is refused by the argument parser with what it expects.

use std::path::Path;
use std::process::{Command, Output};

fn mode360(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mode360"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the mode360 binary runs")
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_string_lossy().to_string()
}

#[test]
fn cuda_without_a_gpu_is_a_clear_error_in_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let bag = path(dir.path(), "one.mcap");
    let o = mode360(&[
        "synth", "--frames", "1", "--width", "64", "--seed", "3", "--out", &bag,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (eval_json, replay_out, bench_json) = (
        path(dir.path(), "eval.json"),
        path(dir.path(), "replay.mcap"),
        path(dir.path(), "bench.json"),
    );
    let run = path(dir.path(), "run");
    let ssmode = ["--estimator", "ssmode", "--device", "cuda:0"];
    let cases: Vec<(Vec<&str>, Option<&str>)> = vec![
        (
            [&["eval", "--bag", &bag, "--json", &eval_json][..], &ssmode].concat(),
            Some(&eval_json),
        ),
        (
            [&["replay", &bag, "--out", &replay_out][..], &ssmode].concat(),
            Some(&replay_out),
        ),
        (
            vec![
                "bench-model",
                "--presets",
                "tiny",
                "--widths",
                "64",
                "--runs",
                "1",
                "--json",
                &bench_json,
                "--device",
                "cuda:0",
            ],
            Some(&bench_json),
        ),
        (
            [
                &["bench-node", "--width", "64", "--duration-s", "1"][..],
                &ssmode,
            ]
            .concat(),
            None,
        ),
        (
            vec![
                "train", "--preset", "compact", "--steps", "1", "--out", &run, "--device", "cuda:0",
            ],
            Some(&run),
        ),
    ];
    for (args, output) in cases {
        let o = mode360(&args);
        if o.status.success() {
            // a GPU host running a `cuda` build: the command ran there
            continue;
        }
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("CUDA device cuda:0") && err.contains("found"),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        if let Some(out) = output {
            assert!(!Path::new(out).exists(), "{args:?} wrote {out}");
        }
    }
}

#[test]
fn a_malformed_device_is_refused_with_what_is_expected() {
    for bad in ["gpu", "cuda:x", "cuda1"] {
        let o = mode360(&["bench-model", "--device", bad]);
        assert_eq!(o.status.code(), Some(2), "--device {bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(&format!("'{bad}'")) && err.contains("cpu or cuda:N"),
            "{err}"
        );
    }
}
