//! End-to-end tests of `fusiondet eval --dataset sunrgbd`: a small hand-made SUN RGB-D case
//! whose APs are worked out below, through the binary, its table and its JSON; and bad input.

mod common;

use common::{all_output, s, text};
use std::path::{Path, PathBuf};

fn run(args: &[&str]) -> std::process::Output {
    common::run("eval", args)
}

/// Writes `lines` (after the prepared files' header comment) to `dir/<id>.txt`.
fn write(dir: &Path, id: &str, lines: &[&str]) {
    std::fs::create_dir_all(dir).unwrap();
    let mut text = String::from("# class cx cy cz dx dy dz yaw x1 y1 x2 y2\n");
    for line in lines {
        text.push_str(line);
        text.push('\n');
    }
    std::fs::write(dir.join(format!("{id}.txt")), text).unwrap();
}

/// Four scenes (2D boxes are not used by the evaluation):
/// * bed: A in 000001, B in 000002; found: A 0.9 (hit), A again 0.8 (duplicate), a bed in
///   000003 0.7 (none there), B 0.6 (hit): precision 1, 1/2, 1/3, 1/2 at recall 1/2, 1/2,
///   1/2, 1 → AP = 1/2 · 1 + 1/2 · 1/2 = 75 % at both thresholds;
/// * chair in 000002, found shifted by half its side: IoU 1/3, so 100 % at 0.25, 0 at 0.5;
/// * toilet in 000001, found with its heading flipped: the same box, 100 %;
/// * sofa in 000004, which has no result file: 0 %;
/// * table found in 000003 but nowhere in the ground truth: no AP (null), not in the mean;
/// * a lamp in both files of 000003: not one of the ten, ignored.
///
/// Means over bed, sofa, chair, toilet: (75 + 0 + 100 + 100) / 4 = 68.75 at 0.25 and
/// (75 + 0 + 0 + 100) / 4 = 43.75 at 0.5.
fn case(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (gt, det) = (dir.join("label"), dir.join("result"));
    let bed_a = "bed 0 3 -0.5 2 1.6 1 0.4 10 10 200 200";
    let bed_b = "bed -1 5 -0.5 2.2 1.5 1.1 -1.2 10 10 200 200";
    write(
        &gt,
        "000001",
        &[bed_a, "toilet 1.5 2 -0.6 0.7 0.45 0.75 0.3 0 0 50 50"],
    );
    write(&gt, "000002", &[bed_b, "chair 2 4 -0.6 1 1 1 0 0 0 50 50"]);
    write(&gt, "000003", &["lamp 0 3 0 0.3 0.3 0.5 0 0 0 5 5"]);
    write(&gt, "000004", &["sofa 0 3 -0.6 1.9 0.9 0.8 0 0 0 80 40"]);
    write(
        &det,
        "000001",
        &[
            &format!("{bed_a} 0.8"),
            &format!(
                "toilet 1.5 2 -0.6 0.7 0.45 0.75 {} 0 0 50 50 0.3",
                0.3 + std::f64::consts::PI
            ),
            &format!("{bed_a} 0.9"),
        ],
    );
    write(
        &det,
        "000002",
        &[
            "chair 2.5 4 -0.6 1 1 1 0 0 0 50 50 0.5",
            &format!("{bed_b} 0.6"),
        ],
    );
    write(
        &det,
        "000003",
        &[
            "bed 1 2 0 2 1.5 1 0 0 0 10 10 0.7",
            "table 0 3 0 1 1 1 0 0 0 10 10 0.4",
            "lamp 0 3 0 0.3 0.3 0.5 0 0 0 5 5 0.99",
        ],
    );
    let split = dir.join("val.txt");
    std::fs::write(&split, "000001\n000002\n000003\n000004\n").unwrap();
    (gt, det, split)
}

/// The JSON the case must produce, to the byte.
fn expected_json() -> String {
    let ap = |class: &str, iou: f64| -> Option<f64> {
        match (class, iou) {
            ("bed", _) => Some(75.0),
            ("chair", 0.25) | ("toilet", _) => Some(100.0),
            ("chair", _) | ("sofa", _) => Some(0.0),
            _ => None,
        }
    };
    let classes = [
        "bed",
        "table",
        "sofa",
        "chair",
        "toilet",
        "desk",
        "dresser",
        "night_stand",
        "bookshelf",
        "bathtub",
    ];
    let mut rows = Vec::new();
    for iou in [0.25, 0.5] {
        for class in classes {
            let value = ap(class, iou).map_or("null".to_string(), |v| format!("{v:?}"));
            rows.push(format!(
                "    {{\n      \"class\": \"{class}\",\n      \"iou\": {iou:?},\n      \"ap\": {value}\n    }}"
            ));
        }
    }
    format!(
        "{{\n  \"results\": [\n{}\n  ],\n  \"map\": {{\n    \"0.25\": 68.75,\n    \"0.5\": 43.75\n  }}\n}}\n",
        rows.join(",\n")
    )
}

#[test]
fn hand_made_case_through_the_binary() {
    let tmp = tempfile::tempdir().unwrap();
    let (gt, det, split) = case(tmp.path());
    let json = tmp.path().join("out/indoor.json");
    std::fs::create_dir_all(json.parent().unwrap()).unwrap();
    let out = run(&[
        "--dataset",
        "sunrgbd",
        "--label-dir",
        s(&gt),
        "--result-dir",
        s(&det),
        "--split",
        s(&split),
        "--json",
        s(&json),
    ]);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(std::fs::read_to_string(&json).unwrap(), expected_json());
    assert!(
        stderr.contains("1 of 4 scenes have no result file") && stderr.contains("000004"),
        "{stderr}"
    );
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("SUN RGB-D 3D detection: 4 scenes, 5 ground-truth boxes of the 10 classes"),
        "{stdout}"
    );
    // The first line says which scenes and classes; then the papers' column order
    // (alphabetical), the mean last.
    assert!(
        stdout.starts_with("evaluating 4 scenes (split "),
        "{stdout}"
    );
    let header = stdout.lines().nth(2).unwrap();
    let columns: Vec<&str> = header.split_whitespace().collect();
    assert_eq!(
        columns,
        [
            "bathtub",
            "bed",
            "bookshelf",
            "chair",
            "desk",
            "dresser",
            "night_stand",
            "sofa",
            "table",
            "toilet",
            "mAP"
        ]
    );
    let row = |name: &str| -> Vec<String> {
        let line = stdout.lines().find(|l| l.starts_with(name)).unwrap();
        line.split_whitespace().skip(1).map(String::from).collect()
    };
    assert_eq!(
        row("AP@0.25"),
        [
            "-", "75.00", "-", "100.00", "-", "-", "-", "0.00", "-", "100.00", "68.75"
        ]
    );
    assert_eq!(
        row("AP@0.5"),
        [
            "-", "75.00", "-", "0.00", "-", "-", "-", "0.00", "-", "100.00", "43.75"
        ]
    );
    assert_eq!(
        row("GT"),
        ["0", "2", "0", "1", "0", "0", "0", "1", "0", "1"]
    );
}

#[test]
fn every_label_file_without_a_split() {
    let tmp = tempfile::tempdir().unwrap();
    let (gt, det, _) = case(tmp.path());
    let json = tmp.path().join("all.json");
    let out = run(&[
        "--dataset",
        "sunrgbd",
        "--label-dir",
        s(&gt),
        "--result-dir",
        s(&det),
        "--json",
        s(&json),
    ]);
    assert!(out.status.success(), "{}", all_output(&out));
    assert_eq!(std::fs::read_to_string(&json).unwrap(), expected_json());
}

#[test]
fn bad_input_is_refused_naming_file_line_and_field() {
    let tmp = tempfile::tempdir().unwrap();
    let (gt, det, split) = case(tmp.path());
    let base = [
        "--dataset",
        "sunrgbd",
        "--label-dir",
        s(&gt),
        "--result-dir",
        s(&det),
    ];
    let with = |extra: &[&str]| -> Vec<String> {
        base.iter().chain(extra).map(|a| a.to_string()).collect()
    };
    let fails = |args: Vec<String>, needle: &str| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        common::assert_fails_with("eval", &args, needle);
    };
    // A result line without its score.
    write(&det, "000003", &["bed 1 2 0 2 1.5 1 0 0 0 10 10"]);
    fails(
        with(&["--split", s(&split)]),
        "000003.txt:2: field `score`: missing",
    );
    write(&det, "000003", &[]);
    // A negative size in the ground truth.
    write(&gt, "000003", &["bed 1 2 0 2 -1.5 1 0 0 0 10 10"]);
    fails(
        with(&["--split", s(&split)]),
        "000003.txt:2: field `dy`: size -1.5 is not positive",
    );
    write(&gt, "000003", &[]);
    // An id of the split without a label file.
    let split5 = tmp.path().join("five.txt");
    std::fs::write(&split5, "000001\n000005\n").unwrap();
    fails(with(&["--split", s(&split5)]), "000005.txt");
    // KITTI's options.
    fails(with(&["--breakdown"]), "--breakdown is for --dataset kitti");
    fails(
        with(&["--classes", "Car"]),
        "--classes is for --dataset kitti",
    );
    // The JSON may not replace an input.
    fails(
        with(&["--json", s(&gt.join("000001.txt"))]),
        "would overwrite an input in --label-dir",
    );
    fails(
        vec![
            "--dataset".into(),
            "nyu".into(),
            "--label-dir".into(),
            s(&gt).into(),
            "--result-dir".into(),
            s(&det).into(),
        ],
        "invalid value 'nyu'",
    );
}
