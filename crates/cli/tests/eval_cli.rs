//! End-to-end tests of `fusiondet eval`: the devkit numbers of the mixed case through the
//! binary and its JSON, the breakdown on the bundled KITTI frames, and bad input.

mod common;

use common::{repo_root as root, s, text};
use std::path::{Path, PathBuf};
use std::process::Output;

fn mixed() -> PathBuf {
    root().join("crates/eval/tests/data/mixed")
}

fn run(args: &[&str]) -> Output {
    common::run("eval", args)
}

/// A writable copy of the mixed case.
fn copy_mixed(dir: &Path) -> (PathBuf, PathBuf) {
    let (gt, det) = (dir.join("gt"), dir.join("det"));
    for (from, to) in [(mixed().join("gt"), &gt), (mixed().join("det"), &det)] {
        std::fs::create_dir_all(to).unwrap();
        for entry in std::fs::read_dir(from).unwrap() {
            let path = entry.unwrap().path();
            std::fs::copy(&path, to.join(path.file_name().unwrap())).unwrap();
        }
    }
    (gt, det)
}

/// The mixed case's ground truth, results and split, then `extra`.
fn mixed_args<'a>(m: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "--label-dir",
        s_leak(m.join("gt")),
        "--result-dir",
        s_leak(m.join("det")),
        "--split",
        s_leak(m.join("ids.txt")),
    ];
    args.extend_from_slice(extra);
    args
}

/// A path as a `&str` that lives for the test process (tests are short-lived).
fn s_leak(p: PathBuf) -> &'static str {
    p.to_str().unwrap().to_string().leak()
}

#[test]
fn mixed_case_through_the_binary_matches_the_devkit() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("out/eval.json");
    std::fs::create_dir_all(json.parent().unwrap()).unwrap();
    let m = mixed();
    let out = run(&mixed_args(&m, &["--json", s(&json)]));
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("Car AP_R40@0.70, 0.70, 0.70:"), "{stdout}");
    assert!(
        stdout.contains("Pedestrian AP@0.50, 0.25, 0.25:"),
        "{stdout}"
    );
    assert!(
        stdout.contains("bbox AP:83.8387, 75.0528, 69.1702"),
        "{stdout}"
    );

    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let obj = got.as_object().unwrap();
    assert_eq!(obj.keys().collect::<Vec<_>>(), ["results"]);
    let rows = got["results"].as_array().unwrap();
    // 3 classes × 2 overlap settings × (bbox, bev, 3d, aos).
    assert_eq!(rows.len(), 24);
    for row in rows {
        let keys: Vec<_> = row.as_object().unwrap().keys().cloned().collect();
        // (serde_json's map sorts keys.)
        assert_eq!(keys, ["ap11", "ap40", "class", "metric", "min_overlap"]);
    }
    let loose_ped_bev = rows
        .iter()
        .find(|r| r["class"] == "Pedestrian" && r["metric"] == "bev" && r["min_overlap"] == 0.25)
        .expect("looser setting reported");
    assert_eq!(loose_ped_bev["ap40"].as_array().unwrap().len(), 3);

    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(m.join("expected.json")).unwrap()).unwrap();
    let mut worst = 0.0f64;
    for want in expected["results"].as_array().unwrap() {
        let ours = rows
            .iter()
            .find(|r| {
                r["class"] == want["class"]
                    && r["metric"] == want["metric"]
                    && r["min_overlap"] == want["min_overlap"]
            })
            .unwrap_or_else(|| panic!("no row for {want}"));
        for key in ["ap11", "ap40"] {
            for d in 0..3 {
                let diff = (ours[key][d].as_f64().unwrap() - want[key][d].as_f64().unwrap()).abs();
                worst = worst.max(diff);
            }
        }
    }
    println!("largest |AP difference| through the binary: {worst:.6}");
    assert!(worst < 0.01, "{worst}");
}

#[test]
fn true_positive_errors_in_the_table_and_the_json() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("e.json");
    let m = mixed();
    let out = run(&mixed_args(&m, &["--errors", "--json", s(&json)]));
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("True-positive errors"), "{stdout}");
    assert!(stdout.contains("distance 40m+"), "{stdout}");
    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = got["errors"].as_array().unwrap();
    // Three classes × (3 levels + 3 distance + 3 occlusion bins).
    assert_eq!(rows.len(), 27);
    let car_easy = &rows[0];
    assert_eq!(car_easy["class"], "Car");
    assert_eq!(car_easy["group"], "easy");
    assert!(car_easy["matched"].as_u64().unwrap() > 0);
    assert!(car_easy["depth"]["median"].as_f64().unwrap() >= 0.0);
}

#[test]
fn a_frame_listed_twice_in_the_split_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let split = tmp.path().join("ids.txt");
    let m = mixed();
    let ids = std::fs::read_to_string(m.join("ids.txt")).unwrap();
    let first = ids.lines().next().unwrap().to_string();
    std::fs::write(&split, format!("{ids}{first}\n")).unwrap();
    common::assert_fails_with(
        "eval",
        &[
            "--label-dir",
            s(&m.join("gt")),
            "--result-dir",
            s(&m.join("det")),
            "--split",
            s(&split),
        ],
        &format!("`{first}` is listed again (first on line 1)"),
    );
}

#[test]
fn a_reader_that_left_does_not_stop_the_json_being_written() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("eval.json");
    let m = mixed();
    let out = common::run_into_closed_pipe("eval", &mixed_args(&m, &["--json", s(&json)]));
    common::assert_quiet_on_closed_pipe(&out);
    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(got["results"].as_array().unwrap().len(), 24);
}

#[test]
fn breakdown_on_the_bundled_kitti_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let split = tmp.path().join("real.txt");
    std::fs::write(
        &split,
        "000000\n000001\n000002\n000003\n000004\n000005\n000134\n",
    )
    .unwrap();
    let json = tmp.path().join("b.json");
    let m = mixed();
    let sample = root().join("data/kitti-sample/training");
    let out = run(&[
        "--label-dir",
        s(&m.join("gt")),
        "--result-dir",
        s(&m.join("det")),
        "--split",
        s(&split),
        "--breakdown",
        "--velodyne-dir",
        s(&sample.join("velodyne")),
        "--calib-dir",
        s(&sample.join("calib")),
        "--errors",
        "--json",
        s(&json),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("lidar_points"));

    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // With the scans, the true-positive errors are also split by LiDAR points.
    let errors = got["errors"].as_array().unwrap();
    assert!(
        errors
            .iter()
            .any(|r| r["class"] == "Car" && r["group"] == "lidar_points <100"),
        "{errors:?}"
    );
    assert_eq!(got["results"].as_array().unwrap().len(), 24);
    let rows = got["breakdown"].as_array().unwrap();
    // 3 classes × 2 settings × (bev, 3d) × 9 bins.
    assert_eq!(rows.len(), 108);
    // Every hard Car box of these frames lies in exactly one distance and one point bin.
    let hard_cars = |by: &str| -> u64 {
        rows.iter()
            .filter(|r| {
                r["class"] == "Car"
                    && r["metric"] == "3d"
                    && r["min_overlap"] == 0.7
                    && r["by"] == by
            })
            .map(|r| r["n_gt"][2].as_u64().unwrap())
            .sum()
    };
    assert!(hard_cars("distance") > 0);
    assert_eq!(hard_cars("distance"), hard_cars("lidar_points"));
    assert_eq!(hard_cars("distance"), hard_cars("occlusion"));
}

#[test]
fn missing_result_files_are_counted_and_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let (gt, det) = copy_mixed(tmp.path());
    std::fs::remove_file(det.join("000001.txt")).unwrap();
    std::fs::remove_file(det.join("100010.txt")).unwrap();
    let out = run(&["--label-dir", s(&gt), "--result-dir", s(&det)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(err.contains("2 of 307 frames have no result file"), "{err}");
    assert!(err.contains("000001, 100010"), "{err}");

    // An empty result directory is refused rather than scored as zeros.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = run(&["--label-dir", s(&gt), "--result-dir", s(&empty)]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("holds no result files"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn malformed_result_line_names_file_line_and_field() {
    let tmp = tempfile::tempdir().unwrap();
    let (gt, det) = copy_mixed(tmp.path());
    let path = det.join("000003.txt");
    let body = std::fs::read_to_string(&path).unwrap();
    let mut lines: Vec<String> = body.lines().map(String::from).collect();
    let mut cols: Vec<&str> = lines[1].split(' ').collect();
    cols[5] = "12,5";
    lines[1] = cols.join(" ");
    std::fs::write(&path, lines.join("\n")).unwrap();
    let out = run(&["--label-dir", s(&gt), "--result-dir", s(&det)]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("000003.txt:2: field `bbox_top`"), "{err}");
    assert!(err.contains("results"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn result_line_without_score_and_bad_ground_truth_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let (gt, det) = copy_mixed(tmp.path());
    // Drop the score of the first detection of 000004.
    let path = det.join("000004.txt");
    let body = std::fs::read_to_string(&path).unwrap();
    let first = body.lines().next().unwrap();
    let without = first.rsplit_once(' ').unwrap().0;
    std::fs::write(&path, body.replacen(first, without, 1)).unwrap();
    let out = run(&["--label-dir", s(&gt), "--result-dir", s(&det)]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("000004.txt:1: field `score`"), "{err}");

    // A ground-truth line cut short.
    std::fs::copy(mixed().join("det/000004.txt"), &path).unwrap();
    std::fs::write(gt.join("000002.txt"), "Car 0.00 0 1.0 1 2 3\n").unwrap();
    let out = run(&["--label-dir", s(&gt), "--result-dir", s(&det)]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("ground truth") && err.contains("000002.txt:1"),
        "{err}"
    );
}

#[test]
fn bad_options_are_clear_errors() {
    let m = mixed();
    let (gt, det) = (m.join("gt"), m.join("det"));
    let dirs = ["--label-dir", s(&gt), "--result-dir"];
    let with = |extra: &[&str]| run(&[&dirs[..], extra].concat());
    let out = with(&[s(&det), "--classes", "Car,Bus"]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("unknown class `Bus`"),
        "{}",
        text(&out.stderr)
    );

    let out = with(&[s(&det), "--breakdown"]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("--breakdown needs both --velodyne-dir and --calib-dir"));

    let out = with(&["/no/such/results"]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("/no/such/results"),
        "{}",
        text(&out.stderr)
    );

    let out = with(&[s(&det), "--split", "/no/such/split.txt"]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("/no/such/split.txt"));

    // The breakdown rule is documented in --help.
    let out = run(&["--help"]);
    let help = text(&out.stdout);
    assert!(
        help.contains("Filtering rule") && help.contains("sqrt(x^2 + (y - h/2)^2 + z^2)"),
        "{help}"
    );
}

#[test]
fn a_baseline_gets_the_difference_with_its_bootstrap_interval() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, det) = copy_mixed(tmp.path());
    // The baseline: the same results with every tenth frame's detections gone.
    let baseline = tmp.path().join("baseline");
    std::fs::create_dir_all(&baseline).unwrap();
    let mut names: Vec<_> = std::fs::read_dir(&det)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    names.sort();
    for (i, name) in names.iter().enumerate() {
        let text = std::fs::read_to_string(det.join(name)).unwrap();
        std::fs::write(baseline.join(name), if i % 10 == 0 { "" } else { &text }).unwrap();
    }
    let json = tmp.path().join("eval.json");
    let m = mixed();
    let args = mixed_args(
        &m,
        &[
            "--baseline",
            s(&baseline),
            "--resamples",
            "200",
            "--seed",
            "5",
            "--json",
            s(&json),
        ],
    );
    let out = run(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("95% interval over 200 resamples of the frames (seed 5)"),
        "{stdout}"
    );
    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = got["baseline"]["rows"].as_array().unwrap();
    // Per class: bbox, bev and 3d at the official overlaps, bev and 3d at the looser ones
    // (the looser setting's bbox overlap is the official one, reported once).
    assert_eq!(rows.len(), 3 * 5, "{rows:?}");
    let car_3d = rows
        .iter()
        .find(|r| r["class"] == "Car" && r["metric"] == "3d" && r["min_overlap"] == 0.7)
        .unwrap();
    let at = |key: &str| car_3d[key][1].as_f64().unwrap();
    // The results' own AP is the one the main table reports.
    let main = got["results"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["class"] == "Car" && r["metric"] == "3d" && r["min_overlap"] == 0.7)
        .unwrap();
    assert_eq!(at("ap40"), main["ap40"][1].as_f64().unwrap());
    // Dropping frames' detections can only lose AP here; the interval holds the difference.
    assert!(at("difference") > 0.0, "{car_3d}");
    assert!(at("interval_low") <= at("difference") && at("difference") <= at("interval_high"));
    assert!(at("ahead") > 0.5, "{car_3d}");

    // Against itself: no difference on any resample.
    let args = mixed_args(&m, &["--baseline", s(&det), "--resamples", "20"]);
    let out = run(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("+0.00  [ +0.00,  +0.00]  ahead in   0.0%"),
        "{}",
        text(&out.stdout)
    );

    // Too few resamples and resampling options without a baseline are refused.
    let out = run(&mixed_args(
        &m,
        &["--baseline", s(&det), "--resamples", "1"],
    ));
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("at least 2"),
        "{}",
        text(&out.stderr)
    );
    let out = run(&mixed_args(&m, &["--resamples", "100"]));
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("--baseline"),
        "{}",
        text(&out.stderr)
    );
}
