//! End-to-end: `train` the tiny SUN RGB-D config on a prepared SUN RGB-D directory (the
//! real scene 000017 copied from the `sunrgbd` fixture, with 2D detections added), `detect`
//! its val split into SUN RGB-D result files, `eval --dataset sunrgbd` them; and bad input.

mod common;

use common::{all_output, assert_fails_with, repo_root, s, text};
use std::path::{Path, PathBuf};

/// The fixture's scene in a directory of its own, with `det_2d/` (the label boxes as
/// detections, and a lamp, which no model detects) and train/val splits.
fn prepared(dir: &Path) -> PathBuf {
    let root = dir.join("sunrgbd");
    let fixture = repo_root().join("crates/sunrgbd/tests/data");
    for (sub, ext) in [
        ("points", "bin"),
        ("calib", "txt"),
        ("label", "txt"),
        ("image", "jpg"),
    ] {
        std::fs::create_dir_all(root.join(sub)).unwrap();
        std::fs::copy(
            fixture.join(format!("{sub}/000017.{ext}")),
            root.join(format!("{sub}/000017.{ext}")),
        )
        .unwrap();
    }
    std::fs::create_dir_all(root.join("splits")).unwrap();
    for split in ["train", "val"] {
        std::fs::write(root.join(format!("splits/{split}.txt")), "000017\n").unwrap();
    }
    std::fs::create_dir_all(root.join("det_2d")).unwrap();
    std::fs::write(
        root.join("det_2d/000017.txt"),
        "night_stand 54.94983 233.0936 187.00673 360.719 0.9\n\
         bed 176.3712 147.1237 637.0 521.0 0.8\n\
         lamp 10 10 40 60 0.7\n",
    )
    .unwrap();
    root
}

#[test]
fn train_detect_and_evaluate_a_sun_rgbd_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let data = prepared(tmp.path());
    let config = repo_root().join("configs/tiny-sunrgbd.toml");
    let run = tmp.path().join("run");
    let o = common::run(
        "train",
        &["--config", s(&config), "--data", s(&data), "--out", s(&run)],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let model = run.join("model.bpk");
    assert!(model.is_file());

    let results = tmp.path().join("results");
    let o = common::run(
        "detect",
        &[
            "--checkpoint",
            s(&model),
            "--data",
            s(&data),
            "--split",
            "val",
            "--out",
            s(&results),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    // One box per wanted 2D detection at most, as SUN RGB-D result lines (13 fields).
    let lines = fusiondet_lines(&results.join("000017.txt"));
    assert!(!lines.is_empty() && lines.len() <= 2, "{lines:?}");
    for l in &lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!(f.len(), 13, "{l}");
        assert!(f[0] == "bed" || f[0] == "night_stand", "{l}");
        let v: Vec<f64> = f[1..].iter().map(|x| x.parse().unwrap()).collect();
        // In upright depth: in front of the camera (y forward), sizes positive.
        assert!(v[1] > 0.0 && v[3] > 0.0 && v[4] > 0.0 && v[5] > 0.0, "{l}");
    }

    let json = tmp.path().join("eval.json");
    let o = common::run(
        "eval",
        &[
            "--dataset",
            "sunrgbd",
            "--label-dir",
            s(&data.join("label")),
            "--result-dir",
            s(&results),
            "--split",
            s(&data.join("splits/val.txt")),
            "--json",
            s(&json),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(report["map"]["0.25"].is_number(), "{report}");

    // A second detect into the same directory needs --force; a KITTI directory is named.
    assert_fails_with(
        "detect",
        &[
            "--checkpoint",
            s(&model),
            "--data",
            s(&data),
            "--split",
            "val",
            "--out",
            s(&results),
        ],
        "--force",
    );
    let kitti = repo_root().join("data/kitti-sample");
    assert_fails_with(
        "detect",
        &[
            "--checkpoint",
            s(&model),
            "--data",
            s(&kitti),
            "--split",
            "val",
            "--out",
            s(&tmp.path().join("k")),
        ],
        "KITTI",
    );
    // A KITTI model on SUN RGB-D data.
    let kitti_model = repo_root().join("models/fconvnet-car.bpk");
    let o = common::run(
        "detect",
        &[
            "--checkpoint",
            s(&kitti_model),
            "--data",
            s(&data),
            "--split",
            "val",
            "--detections",
            s(&kitti.join("rgb_detections/rgb_detection_val.txt")),
            "--out",
            s(&tmp.path().join("k2")),
        ],
    );
    assert!(!o.status.success());
    let out = all_output(&o);
    assert!(
        out.contains("SUN RGB-D") && !out.contains("panicked"),
        "{out}"
    );
    assert!(!text(&o.stderr).contains("panicked"), "{out}");
}

/// Trained long enough to learn its one scene by heart, the tiny model must find the bed
/// and the night stand where the labels put them: a box or heading convention mixed up
/// anywhere between upright depth, the camera frame and back would miss them.
#[test]
fn a_model_that_learnt_the_scene_finds_its_objects() {
    let tmp = tempfile::tempdir().unwrap();
    let data = prepared(tmp.path());
    let text = std::fs::read_to_string(repo_root().join("configs/tiny-sunrgbd.toml"))
        .unwrap()
        .replace("epochs = 2", "epochs = 80")
        .replace("milestones = [3]", "milestones = [70]");
    let config = tmp.path().join("overfit.toml");
    std::fs::write(&config, text).unwrap();
    let run = tmp.path().join("run");
    let o = common::run(
        "train",
        &["--config", s(&config), "--data", s(&data), "--out", s(&run)],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let results = tmp.path().join("results");
    let o = common::run(
        "detect",
        &[
            "--checkpoint",
            s(&run.join("model.bpk")),
            "--data",
            s(&data),
            "--split",
            "val",
            "--detections",
            s(&data.join("det_2d")),
            "--out",
            s(&results),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let json = tmp.path().join("eval.json");
    let o = common::run(
        "eval",
        &[
            "--dataset",
            "sunrgbd",
            "--label-dir",
            s(&data.join("label")),
            "--result-dir",
            s(&results),
            "--json",
            s(&json),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["map"]["0.25"].as_f64(), Some(100.0), "{report}");
}

#[test]
fn a_class_outside_sun_rgbd_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let data = prepared(tmp.path());
    let text = std::fs::read_to_string(repo_root().join("configs/tiny-sunrgbd.toml"))
        .unwrap()
        .replace("\"bathtub\"]", "\"bathtub\", \"Car\"]");
    let config = tmp.path().join("bad.toml");
    std::fs::write(&config, text).unwrap();
    assert_fails_with(
        "train",
        &[
            "--config",
            s(&config),
            "--data",
            s(&data),
            "--out",
            s(&tmp.path().join("run")),
        ],
        "unknown class `Car`",
    );
}

fn fusiondet_lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}
