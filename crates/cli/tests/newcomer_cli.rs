//! End-to-end tests of a new user's path (issue 36): `--split` as a name or a file in every
//! command, `eval`'s defaults and refusals, errors that say what to do (data roots one
//! level off, missing 2D detections, checkpoints), training's feedback (a line per epoch
//! into a pipe, Ctrl-C, no run directory left by a failed start), progress bars on a
//! terminal, and the help texts.

mod common;

use common::{all_output, repo_root, run, s, text};
use std::path::{Path, PathBuf};
use std::process::Command;

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let dest = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &dest);
        } else {
            std::fs::copy(&path, &dest).unwrap();
        }
    }
}

/// A writable copy of the bundled KITTI frames.
fn kitti_copy(dir: &Path) -> PathBuf {
    let data = dir.join("kitti");
    copy_dir(&repo_root().join("data/kitti-sample"), &data);
    data
}

/// Six simulated frames (enough frustums for the tiny network's batches).
fn simulated(dir: &Path) -> PathBuf {
    let data = dir.join("sim");
    let o = run(
        "simulate",
        &["--out", s(&data), "--frames", "6", "--seed", "3"],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    data
}

fn model(name: &str) -> PathBuf {
    repo_root().join("models").join(format!("{name}.bpk"))
}

fn detect(data: &Path, split: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    let checkpoint = model("fconvnet-car");
    let mut args = vec![
        "--checkpoint",
        s(&checkpoint),
        "--data",
        s(data),
        "--split",
        split,
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    run("detect", &args)
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    out.sort();
    out
}

#[test]
fn a_split_is_a_name_or_a_file_and_eval_defaults_to_the_results() {
    let tmp = tempfile::tempdir().unwrap();
    let data = kitti_copy(tmp.path());
    let split_file = data.join("ImageSets/val.txt");
    let val: Vec<String> = std::fs::read_to_string(&split_file)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    let (by_name, by_file) = (tmp.path().join("by-name"), tmp.path().join("by-file"));
    let o = detect(&data, "val", &by_name, &[]);
    assert!(o.status.success(), "{}", all_output(&o));
    let o = detect(&data, s(&split_file), &by_file, &[]);
    assert!(o.status.success(), "{}", all_output(&o));
    assert_eq!(files(&by_name), files(&by_file));

    // eval: no --split, no --classes → the manifest's frames and the classes in them.
    let labels = data.join("training/label_2");
    let o = run(
        "eval",
        &["--label-dir", s(&labels), "--result-dir", s(&by_name)],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let stdout = text(&o.stdout);
    let first = stdout.lines().next().unwrap();
    assert_eq!(
        first,
        format!(
            "evaluating {} frames (the frames the results' manifest lists) for Car (the classes \
             in the results); --split and --classes choose others",
            val.len()
        )
    );
    assert!(!stdout.contains("Pedestrian"), "{stdout}");
    // The same table with the split by name and by file.
    let table = |split: &str| {
        let o = run(
            "eval",
            &[
                "--label-dir",
                s(&labels),
                "--result-dir",
                s(&by_name),
                "--split",
                split,
            ],
        );
        assert!(o.status.success(), "{}", all_output(&o));
        text(&o.stdout)
            .lines()
            .skip(1)
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(table("val"), table(s(&split_file)));
    assert_eq!(
        table("val"),
        stdout.lines().skip(1).collect::<Vec<_>>().join("\n")
    );

    // merge and view take the name too.
    let o = run(
        "merge",
        &[
            "--dir",
            s(&by_name),
            "--data",
            s(&data),
            "--split",
            s(&split_file),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
}

#[test]
fn eval_refuses_what_is_not_a_result_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let data = kitti_copy(tmp.path());
    let labels = data.join("training/label_2");
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    for (dir, needle) in [
        (&empty, "holds no result files"),
        (&data, "so it is a data set, not detection results"),
    ] {
        common::assert_fails_with(
            "eval",
            &["--label-dir", s(&labels), "--result-dir", s(dir)],
            needle,
        );
    }
}

#[test]
fn errors_say_what_to_do_and_say_it_once() {
    let tmp = tempfile::tempdir().unwrap();
    let data = kitti_copy(tmp.path());
    let out = tmp.path().join("out");

    // A frustum model without 2D detections names --detections and the file looked for.
    std::fs::remove_dir_all(data.join("rgb_detections")).unwrap();
    let o = detect(&data, "val", &out, &[]);
    assert!(!o.status.success());
    let err = all_output(&o);
    assert!(err.contains("pass --detections FILE"), "{err}");
    assert!(
        err.contains("rgb_detections/rgb_detection_val.txt"),
        "{err}"
    );
    // A missing file given: its error once, not followed by its own cause again.
    let missing = tmp.path().join("no-such-detections.txt");
    let o = detect(&data, "val", &out, &["--detections", s(&missing)]);
    let err = all_output(&o);
    assert!(!o.status.success());
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");

    // One level too deep or too shallow: the layout and the folder meant.
    let o = detect(&data.join("training"), "val", &out, &[]);
    let err = all_output(&o);
    assert!(!o.status.success());
    assert!(err.contains("training/velodyne/NNNNNN.bin"), "{err}");
    assert!(
        err.contains(&format!("did you mean --data {}?", data.display())),
        "{err}"
    );
    let picture = tmp.path().join("f.png");
    common::assert_fails_with(
        "viz",
        &[
            "--data-dir",
            s(&data),
            "--id",
            "000001",
            "--out",
            s(&picture),
        ],
        &format!(
            "did you mean --data-dir {}?",
            data.join("training").display()
        ),
    );

    // Checkpoints: missing, and not one at all.
    let text_file = tmp.path().join("notes.bpk");
    std::fs::write(&text_file, "not weights\n").unwrap();
    let config = repo_root().join("models/fconvnet-car.toml");
    for (checkpoint, needle) in [
        (tmp.path().join("missing.bpk"), "checkpoint not found"),
        (text_file, "not a fusiondet checkpoint"),
    ] {
        common::assert_fails_with(
            "detect",
            &[
                "--checkpoint",
                s(&checkpoint),
                "--config",
                s(&config),
                "--data",
                s(&data),
                "--out",
                s(&out),
            ],
            needle,
        );
    }
}

fn train_args<'a>(
    config: &'a Path,
    data: &'a Path,
    out: &'a Path,
    epochs: &'a str,
) -> Vec<&'a str> {
    vec![
        "train",
        "--config",
        s(config),
        "--data",
        s(data),
        "--out",
        s(out),
        "--epochs",
        epochs,
    ]
}

#[test]
fn training_reports_each_epoch_into_a_pipe_and_a_failed_start_leaves_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let data = simulated(tmp.path());
    let config = repo_root().join("configs/tiny.toml");
    let run_dir = tmp.path().join("run");
    // A train split listing a frame that is not there fails after the run was opened.
    let split = data.join("ImageSets/train.txt");
    let kept = std::fs::read(&split).unwrap();
    let mut broken = kept.clone();
    broken.extend_from_slice(b"000999\n");
    std::fs::write(&split, broken).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .args(train_args(&config, &data, &run_dir, "2"))
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", all_output(&o));
    assert!(all_output(&o).contains("000999"), "{}", all_output(&o));
    assert!(
        !run_dir.exists(),
        "a failed start left {}",
        run_dir.display()
    );

    // The corrected command runs as it was, one line per epoch on stdout (a pipe here).
    std::fs::write(&split, kept).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .args(train_args(&config, &data, &run_dir, "2"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", all_output(&o));
    let stdout = text(&o.stdout);
    for epoch in ["epoch 1/2: loss ", "epoch 2/2: loss "] {
        assert_eq!(stdout.matches(epoch).count(), 1, "{stdout}");
    }
}

#[cfg(unix)]
#[test]
fn ctrl_c_stops_training_after_a_committed_epoch_and_says_how_to_resume() {
    use std::io::{BufRead, BufReader};
    let tmp = tempfile::tempdir().unwrap();
    let data = simulated(tmp.path());
    let config = repo_root().join("configs/tiny.toml");
    let run_dir = tmp.path().join("run");
    let mut child = Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .args(train_args(&config, &data, &run_dir, "10000"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let first = BufReader::new(child.stdout.take().unwrap())
        .lines()
        .map(Result::unwrap)
        .find(|line| line.starts_with("epoch "));
    assert!(
        first
            .as_deref()
            .is_some_and(|l| l.starts_with("epoch 1/10000: loss ")),
        "{first:?}"
    );
    // SAFETY: signals the child this test started.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) };
    let status = child.wait().unwrap();
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    assert_eq!(status.code(), Some(130), "{stderr}");
    let done: usize = std::fs::read_to_string(run_dir.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .count();
    assert!(done >= 1);
    assert!(
        stderr.contains(&format!(
            "interrupted after epoch {done}; rerun with --resume to continue"
        )),
        "{stderr}"
    );
}

/// `script` (util-linux) runs a command on a pseudo-terminal, where progress bars draw.
fn on_a_terminal(command: &str) -> Option<String> {
    let o = Command::new("script")
        .args(["-qec", command, "/dev/null"])
        .output()
        .ok()?;
    assert!(o.status.success(), "{}", all_output(&o));
    Some(all_output(&o))
}

#[test]
fn per_frame_commands_draw_a_bar_on_a_terminal_only() {
    // A machine without util-linux's `script`, or without pseudo-terminals, has no terminal
    // to test on.
    let probe = Command::new("script")
        .args(["-qec", "true", "/dev/null"])
        .output();
    if !probe.is_ok_and(|o| o.status.success()) {
        eprintln!("skipped: no pseudo-terminal through `script` (util-linux) here");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let data = kitti_copy(tmp.path());
    let bin = env!("CARGO_BIN_EXE_fusiondet");
    let training = data.join("training");
    let cases = [
        (
            format!(
                "{bin} detect --checkpoint {} --data {} --out {}",
                s(&model("fconvnet-car")),
                s(&data),
                s(&tmp.path().join("results"))
            ),
            "detect [",
        ),
        (
            format!(
                "{bin} depth-complete --data-dir {} --out-dir {}",
                s(&training),
                s(&tmp.path().join("depth"))
            ),
            "depth-complete [",
        ),
        (
            format!(
                "{bin} pseudo-points --data-dir {} --out-dir {}",
                s(&training),
                s(&tmp.path().join("pseudo"))
            ),
            "pseudo-points [",
        ),
        (
            format!("{bin} gt-database --data {} --split train", s(&data)),
            "gt-database [",
        ),
    ];
    for (command, bar) in &cases {
        let shown = on_a_terminal(command).unwrap();
        assert!(shown.contains(bar), "{command}:\n{shown}");
    }
    // Training on a terminal draws its bar, and stdout sent to a file still gets each epoch.
    let sim = simulated(tmp.path());
    let log = tmp.path().join("train.log");
    let shown = on_a_terminal(&format!(
        "{bin} train --config {} --data {} --out {} --epochs 2 > {}",
        s(&repo_root().join("configs/tiny.toml")),
        s(&sim),
        s(&tmp.path().join("run")),
        s(&log)
    ))
    .unwrap();
    assert!(shown.contains("batches"), "{shown}");
    let logged = std::fs::read_to_string(&log).unwrap();
    for epoch in ["epoch 1/2: loss ", "epoch 2/2: loss "] {
        assert_eq!(logged.matches(epoch).count(), 1, "{logged}");
    }
    // Into a pipe: the summary lines alone.
    let o = detect(&data, "val", &tmp.path().join("again"), &[]);
    assert!(o.status.success());
    assert!(!all_output(&o).contains("detect ["), "{}", all_output(&o));
}

#[test]
fn help_texts_say_what_the_commands_need() {
    let help = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_fusiondet"))
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success());
        text(&o.stdout)
    };
    let top = help(&["--help"]);
    assert!(
        top.contains("training a tiny one only with --train-tiny"),
        "{top}"
    );
    let train = help(&["train", "--help"]);
    assert!(train.contains("`[detector] kind`"), "{train}");
    let info = help(&["info", "--help"]);
    assert!(info.contains("Voxel R-CNN's or DASANet's"), "{info}");
    let simulate = help(&["simulate", "--help"]);
    assert!(simulate.contains("depth_2"), "{simulate}");
    let detect = help(&["detect", "--help"]);
    assert!(
        detect.contains("a split name (DATA/ImageSets/<name>.txt"),
        "{detect}"
    );
    let eval = help(&["eval", "--help"]);
    assert!(
        eval.contains("the frames of the results' manifest"),
        "{eval}"
    );
}

#[test]
fn eval_of_an_unfinished_sharded_run_names_the_real_merge_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let data = kitti_copy(tmp.path());
    let out = tmp.path().join("sharded");
    let o = detect(&data, "val", &out, &["--shard", "0/2"]);
    assert!(o.status.success(), "{}", all_output(&o));
    common::assert_fails_with(
        "eval",
        &[
            "--label-dir",
            s(&data.join("training/label_2")),
            "--result-dir",
            s(&out),
        ],
        "`fusiondet merge --dir DIR` says which shards or frames are missing",
    );
    // The flag it names is merge's.
    common::assert_fails_with("merge", &["--dir", s(&out)], "shards not started: 1/2");
}
