//! The `mixed` case: 307 frames (7 real KITTI frames plus generated ones with Van,
//! Person_sitting, Truck, Misc and DontCare) whose devkit numbers are in expected.json.
//! Every one of them must be reproduced within 0.01 AP.

use fusiondet_eval::{EvalConfig, Metric, evaluate_dirs};
use fusiondet_kitti::ObjectClass;
use std::path::PathBuf;

fn case() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mixed")
}

#[test]
fn mixed_case_matches_the_official_devkit() {
    let dir = case();
    let (report, frames) = evaluate_dirs(
        &dir.join("gt"),
        &dir.join("det"),
        Some(&dir.join("ids.txt")),
        &EvalConfig::default(),
    )
    .unwrap();
    assert_eq!(report.frames, 307);
    assert!(frames.missing_results.is_empty());
    assert!(report.aos_computed);

    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("expected.json")).unwrap()).unwrap();
    let rows = expected["results"].as_array().unwrap();
    assert_eq!(rows.len(), 12);
    let mut worst = (0.0f64, String::new());
    for row in rows {
        let class = ObjectClass::parse(row["class"].as_str().unwrap()).unwrap();
        let metric = match row["metric"].as_str().unwrap() {
            "bbox" => Metric::Bbox,
            "bev" => Metric::Bev,
            "3d" => Metric::ThreeD,
            "aos" => Metric::Aos,
            m => panic!("unexpected metric {m}"),
        };
        // expected.json holds the official (strict) setting, our setting 0.
        let ours = report.get(class, metric, 0).expect("row present");
        assert_eq!(ours.min_overlap, row["min_overlap"].as_f64().unwrap());
        for (name, got) in [("ap11", ours.ap11), ("ap40", ours.ap40)] {
            let want = row[name].as_array().unwrap();
            for d in 0..3 {
                let diff = (got[d] - want[d].as_f64().unwrap()).abs();
                if diff >= worst.0 {
                    worst = (
                        diff,
                        format!(
                            "{class} {metric} {name}[{d}]: ours {} devkit {}",
                            got[d], want[d]
                        ),
                    );
                }
            }
        }
    }
    println!(
        "largest |AP difference| vs the devkit: {:.6} ({})",
        worst.0, worst.1
    );
    assert!(
        worst.0 < 0.01,
        "largest AP difference {} at {}",
        worst.0,
        worst.1
    );
}

#[test]
fn without_a_split_every_label_file_is_evaluated() {
    let dir = case();
    let (with_split, _) = evaluate_dirs(
        &dir.join("gt"),
        &dir.join("det"),
        Some(&dir.join("ids.txt")),
        &EvalConfig::default(),
    )
    .unwrap();
    let (all, _) = evaluate_dirs(
        &dir.join("gt"),
        &dir.join("det"),
        None,
        &EvalConfig::default(),
    )
    .unwrap();
    // ids.txt lists every label file, so the two runs agree.
    assert_eq!(all.frames, 307);
    assert_eq!(all.results.len(), with_split.results.len());
    for (a, b) in all.results.iter().zip(&with_split.results) {
        assert_eq!(
            (a.class, a.metric, a.setting),
            (b.class, b.metric, b.setting)
        );
        assert_eq!(
            (a.ap11, a.ap40),
            (b.ap11, b.ap40),
            "{} {}",
            a.class,
            a.metric
        );
    }
}
