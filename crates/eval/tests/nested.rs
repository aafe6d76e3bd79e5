//! The one known, deliberate difference from the official devkit: nested boxes with collinear
//! edges, whose intersection Boost.Geometry 1.74 (the devkit's) finds empty. Our exact
//! overlaps score the detection a true positive; the devkit's numbers for this case are in
//! `data/devkit-nested-boxes/expected.json` (see its README).

use fusiondet_eval::{EvalConfig, Metric, evaluate_dirs};
use fusiondet_kitti::{ObjectClass, read_objects};
use std::path::PathBuf;

fn case() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/devkit-nested-boxes")
}

#[test]
fn nested_boxes_overlap_exactly() {
    let gt = read_objects(&case().join("gt/101385.txt")).unwrap();
    let det = read_objects(&case().join("det/101385.txt")).unwrap();
    let (a, b) = (&gt[0].box3d, &det[0].box3d);
    let bev = fusiondet_geometry::iou_bev(a, b);
    let iou3d = fusiondet_geometry::iou_3d(a, b);
    assert!((bev - 1.73 / 1.74).abs() < 1e-6, "BEV IoU {bev}");
    assert!((iou3d - 0.982725).abs() < 1e-6, "3D IoU {iou3d}");
}

#[test]
fn the_detection_is_a_true_positive_where_the_devkit_scores_a_false_one() {
    let dir = case();
    let (report, _) = evaluate_dirs(
        &dir.join("gt"),
        &dir.join("det"),
        Some(&dir.join("ids.txt")),
        &EvalConfig::default(),
    )
    .unwrap();
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("expected.json")).unwrap()).unwrap();
    let devkit = |metric: &str, key: &str| -> Vec<f64> {
        let row = expected["results"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["class"] == "Car" && r["metric"] == metric && r["min_overlap"] == 0.7)
            .unwrap();
        row[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    for (metric, name) in [(Metric::Bev, "bev"), (Metric::ThreeD, "3d")] {
        let ours = report.get(ObjectClass::Car, metric, 0).unwrap();
        // The exact answer: one true positive of one.
        for d in 0..3 {
            assert!(
                (ours.ap11[d] - 100.0 / 11.0).abs() < 1e-3,
                "{name} {ours:?}"
            );
            assert_eq!(ours.ap40[d], 0.0, "{name}");
        }
        // The devkit's: a false positive.
        assert_eq!(devkit(name, "ap11"), [0.0, 0.0, 0.0], "{name}");
    }
    // Where no polygon is intersected, we agree with the devkit.
    for (metric, name) in [(Metric::Bbox, "bbox"), (Metric::Aos, "aos")] {
        let ours = report.get(ObjectClass::Car, metric, 0).unwrap();
        for (got, want) in ours.ap11.iter().zip(devkit(name, "ap11")) {
            assert!((got - want).abs() < 0.01, "{name}: {got} vs {want}");
        }
    }
}
