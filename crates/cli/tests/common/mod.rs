//! Helpers shared by the end-to-end tests of the `fusiondet` binary.
// Each test file uses only some of these.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `fusiondet SUBCOMMAND ARGS...` and collects its output.
pub fn run(subcommand: &str, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .arg(subcommand)
        .args(args)
        .output()
        .expect("run fusiondet")
}

/// `fusiondet detect` of shipped model `model` on the bundled KITTI val frames into `out`,
/// with the environment variable `var` set to `value`, or removed where `None`.
pub fn detect_bundled_val(model: &str, out: &Path, var: &str, value: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_fusiondet"));
    command.env_remove(var);
    if let Some(value) = value {
        command.env(var, value);
    }
    let checkpoint = repo_root().join(format!("models/{model}.bpk"));
    let data = repo_root().join("data/kitti-sample");
    command
        .args(["detect", "--checkpoint", s(&checkpoint), "--data", s(&data)])
        .args(["--split", "val", "--out", s(out)])
        .output()
        .expect("run fusiondet")
}

/// The repository root (for bundled data and configs).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// stdout followed by stderr.
pub fn all_output(o: &Output) -> String {
    format!("{}{}", text(&o.stdout), text(&o.stderr))
}

/// Runs `fusiondet SUBCOMMAND ARGS...`, which must fail with `needle` in its output.
pub fn assert_fails_with(subcommand: &str, args: &[&str], needle: &str) {
    let o = run(subcommand, args);
    let out = all_output(&o);
    assert!(
        !o.status.success(),
        "{subcommand} {args:?} succeeded:\n{out}"
    );
    assert!(out.contains(needle), "expected `{needle}` in:\n{out}");
}

/// `fusiondet eval` of a result directory against a simulated data set's val split (Car),
/// which must succeed.
pub fn eval_val(data: &Path, results: &Path) {
    let o = run(
        "eval",
        &[
            "--label-dir",
            s(&data.join("training/label_2")),
            "--result-dir",
            s(results),
            "--split",
            s(&data.join("ImageSets/val.txt")),
            "--classes",
            "Car",
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
}

/// Runs `fusiondet SUBCOMMAND ARGS...` with stdout a pipe whose reader has already gone (as in
/// `fusiondet … | head -0`), so every write to stdout fails with a broken pipe.
pub fn run_into_closed_pipe(subcommand: &str, args: &[&str]) -> Output {
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .arg(subcommand)
        .args(args)
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .expect("run fusiondet")
}

/// A run into a closed pipe must end as a normal run would: success and no panic.
pub fn assert_quiet_on_closed_pipe(o: &Output) {
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// Every file under `root` with its bytes, by path relative to `root`; the simulator's lock
/// file, created empty and holding nothing of the data set, is left out.
pub fn snapshot(root: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let rel = path.strip_prefix(root).unwrap().to_path_buf();
                if !rel.ends_with(".fusiondet-sim.lock") {
                    out.insert(rel, std::fs::read(&path).unwrap());
                }
            }
        }
    }
    out
}

/// The voxel family's epochs say where their forward pass went: every line of a run's
/// `metrics.jsonl` splits `step_seconds.forward_loss` into stage one, proposals, RoI sampling,
/// the RoI query, stage two and the loss (and DASANet's STCA, `extra`: its crops and the
/// rest), none negative and together within the whole.
pub fn assert_forward_parts_logged(metrics: &str, extra: &[&str]) {
    for line in metrics.lines() {
        let record: serde_json::Value = serde_json::from_str(line).unwrap();
        let step = &record["step_seconds"];
        let parts = step["forward_parts"]
            .as_object()
            .unwrap_or_else(|| panic!("no forward_parts: {line}"));
        let names: Vec<&str> = parts.keys().map(String::as_str).collect();
        let mut expected = vec![
            "loss",
            "proposals",
            "roi_query",
            "roi_sampling",
            "stage_one",
            "stage_two",
        ];
        expected.extend_from_slice(extra);
        expected.sort_unstable();
        assert_eq!(names, expected, "{line}");
        let sum: f64 = parts.values().map(|v| v.as_f64().unwrap()).sum();
        assert!(parts.values().all(|v| v.as_f64().unwrap() >= 0.0), "{line}");
        let whole = step["forward_loss"].as_f64().unwrap();
        assert!(sum > 0.0 && sum <= whole, "{sum} against {whole}: {line}");
    }
}
