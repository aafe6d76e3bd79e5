//! Sharded runs from the binary: `simulate`, `detect`, `depth-complete` and `pseudo-points`
//! with `--shard i/n`, run one after another and as concurrent processes, leave the same
//! files as one unsharded run (the shard records apart); `merge` and `eval` name what an
//! unfinished run lacks.

mod common;

use common::{all_output, assert_fails_with, repo_root, run, s};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};

/// Every file under `root` with its bytes, leaving out the shards' records and the
/// unsharded simulator's lock file.
fn tree(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let path = entry.path();
            let name = path.strip_prefix(root).unwrap().display().to_string();
            // The records and the writers' locks are bookkeeping, not output.
            if name.starts_with(".fusiondet-shards")
                || name == ".fusiondet-sim.lock"
                || name == fusiondet_kitti::atomic::WRITER_LOCK_FILE
            {
                continue;
            }
            if path.is_dir() {
                stack.push(path);
            } else {
                files.insert(name, std::fs::read(&path).unwrap());
            }
        }
    }
    files
}

fn spawn(subcommand: &str, args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .arg(subcommand)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start fusiondet")
}

/// Runs `fusiondet SUBCOMMAND ARGS... --shard i/n` for every i at once; all must succeed.
fn shards_at_once(subcommand: &str, args: &[&str], n: usize) {
    let children: Vec<(usize, Child)> = (0..n)
        .map(|i| {
            let shard = format!("{i}/{n}");
            let mut a = args.to_vec();
            a.extend(["--shard", &shard]);
            (i, spawn(subcommand, &a))
        })
        .collect();
    for (i, child) in children {
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "shard {i}/{n}: {}", all_output(&o));
    }
}

fn ok(subcommand: &str, args: &[&str]) -> String {
    let o = run(subcommand, args);
    let out = all_output(&o);
    assert!(o.status.success(), "{subcommand} {args:?}:\n{out}");
    out
}

fn simulate_args(out: &Path) -> Vec<String> {
    [
        "--out",
        s(out),
        "--frames",
        "6",
        "--seed",
        "7",
        "--val-fraction",
        "0.5",
    ]
    .map(String::from)
    .to_vec()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

#[test]
fn sharded_runs_equal_one_unsharded_run_and_merge_names_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();

    // simulate: three shards at once, against one run.
    let whole = d.join("sim");
    ok("simulate", &strs(&simulate_args(&whole)));
    let sharded = d.join("sim-sharded");
    shards_at_once("simulate", &strs(&simulate_args(&sharded)), 3);
    assert_eq!(tree(&sharded), tree(&whole));
    let out = ok("merge", &["--dir", s(&sharded)]);
    assert!(
        out.contains("simulate: 3 shards, 6 frames: complete"),
        "{out}"
    );

    // detect with the shipped model: shard 0 of 2 alone is not a finished run ...
    let model = repo_root().join("models/fconvnet-car.bpk");
    let detect_args = |out: &Path| -> Vec<String> {
        [
            "--checkpoint",
            s(&model),
            "--data",
            s(&whole),
            "--split",
            "val",
            "--out",
            s(out),
        ]
        .map(String::from)
        .to_vec()
    };
    let results = d.join("results");
    ok("detect", &strs(&detect_args(&results)));
    let serial = d.join("results-serial");
    let mut first = detect_args(&serial);
    first.extend(["--shard", "0/2"].map(String::from));
    let out = ok("detect", &strs(&first));
    assert!(out.contains("shards not started: 1/2"), "{out}");
    assert_fails_with("merge", &["--dir", s(&serial)], "shards not started: 1/2");
    assert_fails_with(
        "eval",
        &[
            "--label-dir",
            s(&whole.join("training/label_2")),
            "--result-dir",
            s(&serial),
            "--split",
            s(&whole.join("ImageSets/val.txt")),
        ],
        "sharded `fusiondet detect` that has not finished",
    );
    // ... a shard of another run (another point count) is refused ...
    let mut other = detect_args(&serial);
    other.extend(["--shard", "1/2", "--points", "512"].map(String::from));
    assert_fails_with("detect", &strs(&other), "shards of another detect run");
    // ... and the second shard completes it: the same files as the unsharded run.
    let mut second = detect_args(&serial);
    second.extend(["--shard", "1/2"].map(String::from));
    let out = ok("detect", &strs(&second));
    assert!(out.contains("every shard has finished"), "{out}");
    assert_eq!(tree(&serial), tree(&results));
    common::eval_val(&whole, &serial);
    // Concurrent processes give the same.
    let together = d.join("results-together");
    shards_at_once("detect", &strs(&detect_args(&together)), 2);
    assert_eq!(tree(&together), tree(&results));
    let out = ok(
        "merge",
        &["--dir", s(&together), "--data", s(&whole), "--split", "val"],
    );
    assert!(out.contains("have their output"), "{out}");
    // A shard run again changes nothing.
    ok("detect", &strs(&second));
    assert_eq!(tree(&serial), tree(&results));

    // pseudo-points and depth-complete: per-frame outputs, three shards at once.
    let training = whole.join("training");
    for command in ["pseudo-points", "depth-complete"] {
        let args = |out: &Path| -> Vec<String> {
            ["--data-dir", s(&training), "--out-dir", s(out)]
                .map(String::from)
                .to_vec()
        };
        let one: PathBuf = d.join(format!("{command}-whole"));
        ok(command, &strs(&args(&one)));
        let many = d.join(format!("{command}-sharded"));
        shards_at_once(command, &strs(&args(&many)), 3);
        assert_eq!(tree(&many), tree(&one), "{command}");
        assert_eq!(tree(&one).len(), 6, "{command}");
        let out = ok(
            "merge",
            &[
                "--dir",
                s(&many),
                "--data",
                s(&whole),
                "--split",
                "trainval",
            ],
        );
        assert!(out.contains("all 6 frames of split `trainval`"), "{out}");
        // A frame lost after the run is named.
        let lost = std::fs::read_dir(&many)
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .find(|p| p.is_file() && !p.file_name().unwrap().to_string_lossy().starts_with('.'))
            .unwrap();
        std::fs::remove_file(&lost).unwrap();
        let stem = lost.file_stem().unwrap().to_str().unwrap().to_string();
        assert_fails_with("merge", &["--dir", s(&many)], &stem);
    }
}

#[test]
fn bad_shards_are_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    for bad in ["2/2", "1/0", "x", "1/2/3"] {
        let mut args = simulate_args(&out);
        args.extend(["--shard", bad].map(String::from));
        assert_fails_with("simulate", &strs(&args), "expected I/N");
    }
    assert_fails_with("merge", &["--dir", s(dir.path())], "holds no shard records");
}
