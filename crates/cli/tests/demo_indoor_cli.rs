//! End-to-end: `fusiondet demo --indoor` from a binary copied away from the source tree,
//! run in an empty directory: simulated rooms, the tiny network trained on them, detection
//! and the indoor evaluation on the simulated val rooms and on the bundled real scene
//! 000017, pictures; a second run replaces its own output, a foreign directory is refused.

mod common;

use common::{all_output, assert_fails_with, repo_root, text};
use fusiondet_viz::style::GT;
use std::path::Path;
use std::process::{Command, Output};

fn demo(bin: &Path, cwd: &Path, args: &[&str]) -> Output {
    Command::new(bin)
        .current_dir(cwd)
        .args(["demo", "--indoor"])
        .args(args)
        .output()
        .unwrap()
}

/// The result lines of a file: SUN RGB-D's 13 fields, in front of the camera.
fn check_results(path: &Path) -> usize {
    let text = std::fs::read_to_string(path).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    for l in &lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!(f.len(), 13, "{}: {l}", path.display());
        let v: Vec<f64> = f[1..].iter().map(|x| x.parse().unwrap()).collect();
        assert!(v[1] > 0.0 && v[3] > 0.0 && v[4] > 0.0 && v[5] > 0.0, "{l}");
    }
    lines.len()
}

fn map25(json: &Path) -> f64 {
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    report["map"]["0.25"]
        .as_f64()
        .unwrap_or_else(|| panic!("{report}"))
}

#[test]
fn the_indoor_demo_runs_from_an_installed_binary() {
    let bin_dir = tempfile::tempdir().unwrap();
    let bin = bin_dir.path().join("fusiondet");
    std::fs::copy(env!("CARGO_BIN_EXE_fusiondet"), &bin).unwrap();
    let work = tempfile::tempdir().unwrap();
    let small = [
        "--frames", "6", "--epochs", "2", "--points", "4000", "--out", "d",
    ];
    let o = demo(&bin, work.path(), &small);
    let t = all_output(&o);
    assert!(o.status.success(), "{t}");
    let stdout = text(&o.stdout);
    for needle in [
        "simulated 6 rooms",
        "trained the tiny F-ConvNet",
        "real SUN RGB-D scene 000017",
        "AP@0.25",
        "night_stand",
        "mAP@0.25 / @0.5: simulated val",
        "indoor demo finished",
    ] {
        assert!(stdout.contains(needle), "`{needle}` missing:\n{t}");
    }
    let out = work.path().join("d");

    // The real scene is the fixture's, with 2D boxes from its labels (bed, night stand).
    let fixture = repo_root().join("crates/sunrgbd/tests/data");
    for f in [
        "points/000017.bin",
        "image/000017.jpg",
        "calib/000017.txt",
        "label/000017.txt",
    ] {
        assert_eq!(
            std::fs::read(out.join("real").join(f)).unwrap(),
            std::fs::read(fixture.join(f)).unwrap(),
            "{f}"
        );
    }
    let det2d = std::fs::read_to_string(out.join("real/det_2d/000017.txt")).unwrap();
    let det2d: Vec<&str> = det2d.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(det2d.len(), 2, "{det2d:?}");
    assert!(det2d[0].starts_with("night_stand ") && det2d[1].starts_with("bed "));
    assert!(check_results(&out.join("results/real/000017.txt")) <= 2);

    // Every simulated val room has a result file; the evaluations are written.
    let val = std::fs::read_to_string(out.join("sim/splits/val.txt")).unwrap();
    let val: Vec<&str> = val.lines().collect();
    assert!(!val.is_empty());
    let boxes: usize = val
        .iter()
        .map(|id| check_results(&out.join(format!("results/sim/{id}.txt"))))
        .sum();
    assert!(boxes > 0, "no boxes on the simulated val rooms:\n{t}");
    for json in ["eval-sim.json", "eval-real.json"] {
        let m = map25(&out.join(json));
        assert!((0.0..=100.0).contains(&m), "{json}: {m}");
    }

    // Pictures: the real scene at its image's width, its ground truth drawn.
    let picture =
        fusiondet_kitti::image::read_image(&out.join("pictures/real-000017.png")).unwrap();
    assert_eq!(picture.width(), 730);
    assert!(picture.pixels().filter(|p| **p == GT).count() > 400);
    for id in val.iter().take(2) {
        assert!(out.join(format!("pictures/sim-{id}.png")).is_file(), "{id}");
    }

    // A second run replaces its own output (here with fewer rooms), and the street
    // demo's evaluation where one had run before.
    std::fs::write(out.join("eval-kitti.json"), "{}").unwrap();
    let o = demo(
        &bin,
        work.path(),
        &[
            "--frames", "4", "--epochs", "1", "--points", "2000", "--out", "d",
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    assert!(text(&o.stdout).contains("simulated 4 rooms"));
    assert!(!out.join("sim/points/000005.bin").exists());
    assert!(!out.join("eval-kitti.json").exists());
    assert!(out.join("eval-real.json").is_file());

    // A directory the demo did not write is refused and left alone.
    let foreign = work.path().join("mine");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), "keep").unwrap();
    let o = demo(&bin, work.path(), &["--frames", "4", "--out", "mine"]);
    assert!(!o.status.success());
    assert!(
        all_output(&o).contains("not written by `fusiondet demo`"),
        "{}",
        all_output(&o)
    );
    assert_eq!(std::fs::read_dir(&foreign).unwrap().count(), 1);
}

#[test]
fn bad_indoor_demo_arguments_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("d");
    let out = out.to_str().unwrap();
    assert_fails_with(
        "demo",
        &["--indoor", "--frames", "3", "--out", out],
        "--frames",
    );
    assert_fails_with(
        "demo",
        &["--indoor", "--points", "10", "--out", out],
        "--points",
    );
    assert_fails_with(
        "demo",
        &["--indoor", "--model", "saf", "--out", out],
        "--model",
    );
    for points in ["5000", "20000"] {
        assert_fails_with(
            "demo",
            &["--points", points, "--out", out],
            "--points is for --indoor",
        );
    }
    assert!(!Path::new(out).exists());
}
