//! Nothing a user owns is lost, whatever door a careless or unlucky command line opens:
//! outputs spelled to reach inputs (links, `..`, nested folders, ids that are paths), special
//! files where a file is read, sizes that would exhaust memory, and two writers at once.
//! Each case was a reported failure; each test fails without its fix.

mod common;

use common::{all_output, assert_fails_with, repo_root, run, s, snapshot};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A copy of the bundled KITTI sample (the `R` of the reports), which the tests may damage.
fn kitti_copy(dir: &Path) -> PathBuf {
    let from = repo_root().join("data/kitti-sample");
    let to = dir.join("R");
    let mut stack = vec![from.clone()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            let target = to.join(path.strip_prefix(&from).unwrap());
            if path.is_dir() {
                std::fs::create_dir_all(&target).unwrap();
                stack.push(path);
            } else {
                std::fs::create_dir_all(target.parent().unwrap()).unwrap();
                std::fs::copy(&path, &target).unwrap();
            }
        }
    }
    to
}

/// Runs the binary and kills it after `limit`: a hang fails the test instead of stalling it.
fn run_bounded(subcommand: &str, args: &[&str], limit: Duration) -> (bool, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .arg(subcommand)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            let o = child.wait_with_output().unwrap();
            return (o.status.success(), all_output(&o));
        }
        if start.elapsed() > limit {
            child.kill().unwrap();
            panic!("`fusiondet {subcommand} {args:?}` hung for {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[cfg(unix)]
fn mkfifo(path: &Path) {
    let status = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(status.success(), "mkfifo {}", path.display());
}

#[cfg(unix)]
#[test]
fn a_simulation_never_writes_through_a_linked_folder() {
    let dir = tempfile::tempdir().unwrap();
    let r = kitti_copy(dir.path());
    let sim = dir.path().join("S");
    let o = run(
        "simulate",
        &["--out", s(&sim), "--frames", "2", "--seed", "3"],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let before = snapshot(&r);
    // The whole training folder, then only the scans, linked to someone's data set.
    std::fs::remove_dir_all(sim.join("training")).unwrap();
    std::os::unix::fs::symlink(r.join("training"), sim.join("training")).unwrap();
    let args = ["--out", s(&sim), "--frames", "2", "--seed", "3", "--force"];
    assert_fails_with("simulate", &args, "is a symbolic link");
    assert_eq!(snapshot(&r), before);
    std::fs::remove_file(sim.join("training")).unwrap();
    std::fs::create_dir_all(sim.join("training")).unwrap();
    std::os::unix::fs::symlink(r.join("training/velodyne"), sim.join("training/velodyne")).unwrap();
    assert_fails_with("simulate", &args, "is a symbolic link");
    assert_eq!(snapshot(&r), before);
}

#[cfg(unix)]
#[test]
fn per_frame_outputs_never_land_in_the_data_set_or_outside_their_folder() {
    let dir = tempfile::tempdir().unwrap();
    let r = kitti_copy(dir.path());
    let training = r.join("training");
    let before = snapshot(&r);
    let velodyne = training.join("velodyne");
    for out in [
        velodyne.clone(),
        training.join("velodyne/../velodyne"),
        training.join("depth_2"),
        training.clone(),
    ] {
        for command in ["pseudo-points", "depth-complete"] {
            let args = [
                "--data-dir",
                s(&training),
                "--out-dir",
                s(&out),
                "--ids",
                "000000",
            ];
            assert_fails_with(command, &args, "--data-dir");
        }
    }
    // Through a link to the scans.
    let link = dir.path().join("to-velodyne");
    std::os::unix::fs::symlink(&velodyne, &link).unwrap();
    assert_fails_with(
        "pseudo-points",
        &["--data-dir", s(&training), "--out-dir", s(&link)],
        "--data-dir",
    );
    // Ids are frame ids, not paths.
    let out = dir.path().join("out");
    for command in ["pseudo-points", "depth-complete"] {
        let args = [
            "--data-dir",
            s(&training),
            "--out-dir",
            s(&out),
            "--ids",
            "../evil",
        ];
        assert_fails_with(command, &args, "is not a frame id");
    }
    assert!(!dir.path().join("evil.bin").exists() && !dir.path().join("evil.png").exists());
    assert_eq!(snapshot(&r), before);
    // A short id is padded as everywhere else.
    let o = run(
        "depth-complete",
        &[
            "--data-dir",
            s(&training),
            "--out-dir",
            s(&out),
            "--ids",
            "1",
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    assert!(out.join("000001.png").is_file());
}

#[test]
fn eval_never_replaces_the_split_it_read() {
    let dir = tempfile::tempdir().unwrap();
    let r = kitti_copy(dir.path());
    let split = r.join("ImageSets/val.txt");
    let before = std::fs::read(&split).unwrap();
    let labels = r.join("training/label_2");
    assert_fails_with(
        "eval",
        &[
            "--label-dir",
            s(&labels),
            "--result-dir",
            s(&labels),
            "--split",
            s(&split),
            "--json",
            s(&r.join("ImageSets/../ImageSets/val.txt")),
        ],
        "--split",
    );
    assert_eq!(std::fs::read(&split).unwrap(), before);
}

#[cfg(unix)]
#[test]
fn special_files_where_a_file_is_read_are_refused_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    let r = kitti_copy(dir.path());
    let training = r.join("training");
    let limit = Duration::from_secs(120);
    // A pipe as a result file, and a result linked to /dev/zero.
    let results = dir.path().join("results");
    std::fs::create_dir_all(&results).unwrap();
    mkfifo(&results.join("000001.txt"));
    std::os::unix::fs::symlink("/dev/zero", results.join("000000.txt")).unwrap();
    let (ok, out) = run_bounded(
        "eval",
        &[
            "--label-dir",
            s(&training.join("label_2")),
            "--result-dir",
            s(&results),
            "--classes",
            "Car",
        ],
        limit,
    );
    assert!(!ok && out.contains("not a regular file"), "{out}");
    // A pipe as a frame's image: viz, pseudo-points and depth-complete refuse it.
    let image = training.join("image_2/000001.png");
    std::fs::remove_file(&image).unwrap();
    mkfifo(&image);
    let picture = dir.path().join("p.png");
    let (ok, out) = run_bounded(
        "viz",
        &[
            "--data-dir",
            s(&training),
            "--id",
            "1",
            "--out",
            s(&picture),
        ],
        limit,
    );
    assert!(!ok && out.contains("not a regular file"), "{out}");
    for command in ["pseudo-points", "depth-complete"] {
        let out_dir = dir.path().join(command);
        let (ok, out) = run_bounded(
            command,
            &[
                "--data-dir",
                s(&training),
                "--ids",
                "1",
                "--out-dir",
                s(&out_dir),
            ],
            limit,
        );
        assert!(
            !ok && out.contains("not a regular file"),
            "{command}: {out}"
        );
    }
    // A pipe as a depth PNG.
    let sparse = dir.path().join("sparse.png");
    mkfifo(&sparse);
    let (ok, out) = run_bounded(
        "depth-complete",
        &[
            "--sparse",
            s(&sparse),
            "--out",
            s(&dir.path().join("dense.png")),
        ],
        limit,
    );
    assert!(!ok && out.contains("not a regular file"), "{out}");
}

#[test]
fn numbers_that_would_exhaust_memory_or_time_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let training = repo_root().join("data/kitti-sample/training");
    let picture = dir.path().join("p.png");
    for (forward, side) in [("1e-9", "1e-9"), ("40", "1e-9"), ("500", "1")] {
        assert_fails_with(
            "viz",
            &[
                "--data-dir",
                s(&training),
                "--id",
                "1",
                "--bev-forward",
                forward,
                "--bev-side",
                side,
                "--out",
                s(&picture),
            ],
            "--bev-",
        );
    }
    assert!(!picture.exists());
    assert_fails_with(
        "bench",
        &[
            "--checkpoint",
            "nothing.bpk",
            "--data",
            "nowhere",
            "--repeats",
            "100000000000",
        ],
        "--repeats must be in 1..=1000",
    );
    assert_fails_with(
        "simulate",
        &[
            "--indoor",
            "--out",
            s(&dir.path().join("rooms")),
            "--frames",
            "1",
            "--points",
            "1000000000000",
        ],
        "--points must be in 1..=",
    );
}

#[test]
fn a_wrong_sized_image_is_an_error_not_an_empty_result() {
    let dir = tempfile::tempdir().unwrap();
    let r = kitti_copy(dir.path());
    let training = r.join("training");
    image::RgbImage::new(8, 8)
        .save(training.join("image_2/000001.png"))
        .unwrap();
    for command in ["pseudo-points", "depth-complete"] {
        assert_fails_with(
            command,
            &[
                "--data-dir",
                s(&training),
                "--ids",
                "1",
                "--out-dir",
                s(&dir.path().join(command)),
            ],
            "no LiDAR point of the frame falls inside this 8×8 image",
        );
    }
}

#[test]
fn a_second_writer_of_a_directory_is_refused_and_stale_temporaries_go() {
    let dir = tempfile::tempdir().unwrap();
    let training = repo_root().join("data/kitti-sample/training");
    let out = dir.path().join("pseudo");
    std::fs::create_dir_all(&out).unwrap();
    // A killed write of this run's frame, and a file that is not ours.
    let stale = out.join(".000001.bin.x7Yq2a.tmp");
    std::fs::write(&stale, b"half").unwrap();
    std::fs::write(out.join("notes.tmp"), b"mine").unwrap();
    let args = [
        "--data-dir",
        s(&training),
        "--ids",
        "1",
        "--out-dir",
        s(&out),
    ];
    {
        let _held = fusiondet_kitti::atomic::lock_dir(&out, false)
            .unwrap()
            .expect("free");
        assert_fails_with("pseudo-points", &args, "is writing into this directory");
        assert!(stale.is_file());
    }
    let o = run("pseudo-points", &args);
    assert!(o.status.success(), "{}", all_output(&o));
    assert!(!stale.exists(), "the stale temporary file is still there");
    assert_eq!(std::fs::read(out.join("notes.tmp")).unwrap(), b"mine");
}

#[test]
fn shards_of_two_data_sets_never_share_a_directory() {
    let dir = tempfile::tempdir().unwrap();
    let a = kitti_copy(&dir.path().join("a"));
    let b = kitti_copy(&dir.path().join("b"));
    // The same split and frame names, another scan.
    let scan = b.join("training/velodyne/000001.bin");
    let mut bytes = std::fs::read(&scan).unwrap();
    bytes.truncate(bytes.len() - 16);
    std::fs::write(&scan, bytes).unwrap();
    let out = dir.path().join("maps");
    let shard = |data: &Path, i: &str| {
        run(
            "depth-complete",
            &[
                "--data-dir",
                s(&data.join("training")),
                "--ids",
                "0,1",
                "--out-dir",
                s(&out),
                "--shard",
                i,
            ],
        )
    };
    let o = shard(&a, "0/2");
    assert!(o.status.success(), "{}", all_output(&o));
    let o = shard(&b, "1/2");
    assert!(!o.status.success());
    assert!(
        all_output(&o).contains("holds the shards of another"),
        "{}",
        all_output(&o)
    );
}

#[test]
fn a_second_detect_into_one_directory_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let data = repo_root().join("data/kitti-sample");
    let out = dir.path().join("results");
    std::fs::create_dir_all(&out).unwrap();
    let checkpoint = repo_root().join("models/fconvnet-car.bpk");
    let args = [
        "--checkpoint",
        s(&checkpoint),
        "--data",
        s(&data),
        "--split",
        "val",
        "--out",
        s(&out),
    ];
    {
        // Another detect holding the directory, as when two run at once.
        let _held = fusiondet_kitti::atomic::lock_dir(&out, false)
            .unwrap()
            .expect("free");
        assert_fails_with(
            "detect",
            &args,
            "another detect is writing into this directory",
        );
        assert!(!out.join(fusiondet_kitti::results::MANIFEST_FILE).exists());
    }
    let o = run("detect", &args);
    assert!(o.status.success(), "{}", all_output(&o));
}
