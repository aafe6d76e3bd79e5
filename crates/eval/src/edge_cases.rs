//! Hand-computed cases, each isolating one rule of the devkit protocol.
//!
//! Reminder of the arithmetic: with one recall sample point filled with precision p
//! (entry 0 of the 41), AP11 = p / 11 · 100 and AP40 = 0; with entries 0 and 1 filled
//! with p, AP11 = p / 11 · 100 and AP40 = p / 40 · 100.

use crate::frames::tests_support::{det, dontcare, gt};
use crate::{Difficulty, EvalConfig, EvalReport, FrameDet, FrameGt, Metric, evaluate};
use fusiondet_kitti::ObjectClass::{self, *};

const ONE_POINT: f64 = 100.0 / 11.0;

fn eval_frames(
    frames: Vec<(Vec<fusiondet_kitti::Object>, Vec<fusiondet_kitti::Object>)>,
) -> EvalReport {
    let (g, d): (Vec<_>, Vec<_>) = frames
        .into_iter()
        .enumerate()
        .map(|(i, (g, d))| {
            (
                FrameGt::new(format!("{i:06}"), g),
                FrameDet::new(format!("{i:06}"), d),
            )
        })
        .unzip();
    evaluate(&g, &d, &EvalConfig::default()).unwrap()
}

fn eval1(g: Vec<fusiondet_kitti::Object>, d: Vec<fusiondet_kitti::Object>) -> EvalReport {
    eval_frames(vec![(g, d)])
}

/// (AP11, AP40) of the official setting.
fn ap(r: &EvalReport, class: ObjectClass, metric: Metric) -> ([f64; 3], [f64; 3]) {
    let row = r.get(class, metric, 0).unwrap();
    (row.ap11, row.ap40)
}

fn close(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-9)
}

#[track_caller]
fn assert_ap(r: &EvalReport, class: ObjectClass, metric: Metric, ap11: [f64; 3], ap40: [f64; 3]) {
    let (a11, a40) = ap(r, class, metric);
    assert!(
        close(a11, ap11),
        "{class} {metric} AP11 {a11:?}, expected {ap11:?}"
    );
    assert!(
        close(a40, ap40),
        "{class} {metric} AP40 {a40:?}, expected {ap40:?}"
    );
}

const CAR: [f64; 4] = [100.0, 100.0, 200.0, 200.0];
const FAR: [f64; 4] = [600.0, 100.0, 700.0, 200.0];

#[test]
fn single_perfect_detection_gives_ap11_9_09_and_ap40_0() {
    let r = eval1(vec![gt(Car, CAR)], vec![det(Car, CAR, 0.9)]);
    for metric in Metric::ALL {
        assert_ap(&r, Car, metric, [ONE_POINT; 3], [0.0; 3]);
    }
    assert_eq!(r.n_gt(Car), [1, 1, 1]);
    let curve = r
        .get(Car, Metric::Bbox, 0)
        .unwrap()
        .curve(Difficulty::Moderate);
    assert_eq!(curve.thresholds, [0.9]);
    assert_eq!((curve.tp[0], curve.fp[0], curve.fn_[0]), (1, 0, 0));
    assert_eq!(curve.recall, [1.0]);
    // Same in the looser setting; other classes have nothing.
    assert_eq!(r.get(Car, Metric::Bev, 1).unwrap().ap11, [ONE_POINT; 3]);
    assert_ap(&r, Pedestrian, Metric::Bbox, [0.0; 3], [0.0; 3]);
}

#[test]
fn false_positive_scored_above_the_true_positives() {
    // Two cars found at scores 0.8 and 0.7, a false positive at 0.9. Thresholds
    // [0.8, 0.7]; precision 1/2 then 2/3, made monotone: [2/3, 2/3].
    let second = [300.0, 100.0, 400.0, 200.0];
    let r = eval1(
        vec![gt(Car, CAR), gt(Car, second)],
        vec![
            det(Car, FAR, 0.9),
            det(Car, CAR, 0.8),
            det(Car, second, 0.7),
        ],
    );
    let p = 2.0 / 3.0;
    assert_ap(
        &r,
        Car,
        Metric::Bbox,
        [p / 11.0 * 100.0; 3],
        [p / 40.0 * 100.0; 3],
    );
    let curve = r.get(Car, Metric::Bbox, 0).unwrap().curve(Difficulty::Easy);
    assert_eq!(curve.precision, [0.5, p]);
    assert_eq!(&curve.interpolated[..3], &[p, p, 0.0]);
    // The false positive scored below both: precision 1 at both thresholds.
    let r = eval1(
        vec![gt(Car, CAR), gt(Car, second)],
        vec![
            det(Car, FAR, 0.1),
            det(Car, CAR, 0.8),
            det(Car, second, 0.7),
        ],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [2.5; 3]);
}

#[test]
fn dontcare_region_suppresses_a_false_positive_in_the_image_only() {
    // The false positive lies wholly inside a large DontCare region: its overlap over its
    // own area is 1 (its IoU with the region is tiny), so it is not a false positive.
    let region = [500.0, 50.0, 1000.0, 300.0];
    let inside = [600.0, 100.0, 650.0, 160.0];
    let r = eval1(
        vec![gt(Car, CAR), dontcare(region)],
        vec![det(Car, inside, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
    // DontCare regions have no 3D extent (−1 sizes at −1000 m), so in BEV and 3D the same
    // detection stays a false positive, as in the devkit.
    assert_ap(&r, Car, Metric::Bev, [ONE_POINT / 2.0; 3], [0.0; 3]);
    assert_ap(&r, Car, Metric::ThreeD, [ONE_POINT / 2.0; 3], [0.0; 3]);
    // Without the region it is a false positive everywhere.
    let r = eval1(
        vec![gt(Car, CAR)],
        vec![det(Car, inside, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT / 2.0; 3], [0.0; 3]);
}

#[test]
fn van_is_an_ignored_neighbour_of_car() {
    let van = FAR;
    // A Car detection on a Van is dropped, neither hit nor false positive.
    let r = eval1(
        vec![gt(Car, CAR), gt(Van, van)],
        vec![det(Car, van, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
    assert_ap(&r, Car, Metric::ThreeD, [ONE_POINT; 3], [0.0; 3]);
    assert_eq!(r.n_gt(Car), [1, 1, 1]);
    // A Truck is not a neighbour: the same detection is a false positive.
    let r = eval1(
        vec![gt(Car, CAR), gt(Truck, van)],
        vec![det(Car, van, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT / 2.0; 3], [0.0; 3]);
    // A missed Van is not a missed Car, and a Van detection does not count for Car.
    let r = eval1(
        vec![gt(Car, CAR), gt(Van, van)],
        vec![det(Van, van, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
    // Person_sitting is Pedestrian's neighbour.
    let r = eval1(
        vec![gt(Pedestrian, CAR), gt(PersonSitting, van)],
        vec![det(Pedestrian, van, 0.9), det(Pedestrian, CAR, 0.5)],
    );
    assert_ap(&r, Pedestrian, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
}

#[test]
fn detection_matched_to_an_ignored_truncated_car_is_not_counted() {
    let mut truncated = gt(Car, FAR);
    truncated.truncation = 0.6; // above the hard limit 0.5: ignored at every difficulty
    let r = eval1(
        vec![gt(Car, CAR), truncated],
        vec![det(Car, FAR, 0.9), det(Car, CAR, 0.5)],
    );
    assert_eq!(r.n_gt(Car), [1, 1, 1]);
    for metric in Metric::ALL {
        assert_ap(&r, Car, metric, [ONE_POINT; 3], [0.0; 3]);
    }
    // Truncation 0.2 is too much for easy (0.15) only: there the detection is dropped, at
    // moderate and hard the car is found.
    let mut slightly = gt(Car, FAR);
    slightly.truncation = 0.2;
    let r = eval1(
        vec![gt(Car, CAR), slightly],
        vec![det(Car, FAR, 0.9), det(Car, CAR, 0.5)],
    );
    assert_eq!(r.n_gt(Car), [1, 2, 2]);
    // Moderate: 2 ground truth, both found (0.9 then 0.5): thresholds [0.9, 0.5], precision 1.
    assert_ap(
        &r,
        Car,
        Metric::Bbox,
        [ONE_POINT, ONE_POINT, ONE_POINT],
        [0.0, 2.5, 2.5],
    );
    // Occlusion works the same way: level 1 is ignored at easy only.
    let mut occluded = gt(Car, FAR);
    occluded.occlusion = 1;
    let r = eval1(
        vec![gt(Car, CAR), occluded],
        vec![det(Car, FAR, 0.9), det(Car, CAR, 0.5)],
    );
    assert_eq!(r.n_gt(Car), [1, 2, 2]);
}

#[test]
fn ground_truth_height_must_exceed_the_minimum() {
    // Exactly 40 px is ignored at easy (height <= 40), 40.5 px is not.
    let r = eval1(vec![gt(Car, [100.0, 100.0, 200.0, 140.0])], vec![]);
    assert_eq!(r.n_gt(Car), [0, 1, 1]);
    let r = eval1(vec![gt(Car, [100.0, 100.0, 200.0, 140.5])], vec![]);
    assert_eq!(r.n_gt(Car), [1, 1, 1]);
    let r = eval1(vec![gt(Car, [100.0, 100.0, 200.0, 125.0])], vec![]);
    assert_eq!(r.n_gt(Car), [0, 0, 0]);
}

#[test]
fn small_detections_are_ignored_with_the_height_truncated_to_whole_pixels() {
    // A false positive 25.9 px high counts as 25 px: below easy's 40, not below 25.
    let fp_25 = [600.0, 100.0, 650.0, 125.9];
    let r = eval1(
        vec![gt(Car, CAR)],
        vec![det(Car, fp_25, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(
        &r,
        Car,
        Metric::Bbox,
        [ONE_POINT, ONE_POINT / 2.0, ONE_POINT / 2.0],
        [0.0; 3],
    );
    // 24.9 px counts as 24: ignored at every difficulty.
    let fp_24 = [600.0, 100.0, 650.0, 124.9];
    let r = eval1(
        vec![gt(Car, CAR)],
        vec![det(Car, fp_24, 0.9), det(Car, CAR, 0.5)],
    );
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
}

#[test]
fn aos_uses_the_cosine_of_the_alpha_difference() {
    let mut flipped = det(Car, CAR, 0.9);
    flipped.alpha = std::f64::consts::PI;
    let r = eval1(vec![gt(Car, CAR)], vec![flipped.clone()]);
    // Perfect box, opposite heading: detection AP is full, orientation similarity 0.
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
    assert_ap(&r, Car, Metric::Aos, [0.0; 3], [0.0; 3]);
    // A quarter turn: similarity (1 + cos(pi/2)) / 2 = 1/2.
    flipped.alpha = std::f64::consts::FRAC_PI_2;
    let r = eval1(vec![gt(Car, CAR)], vec![flipped]);
    assert_ap(&r, Car, Metric::Aos, [ONE_POINT / 2.0; 3], [0.0; 3]);
    // A false positive adds 0 similarity but counts in the denominator.
    let mut good = det(Car, CAR, 0.5);
    good.alpha = 0.0;
    let r = eval1(vec![gt(Car, CAR)], vec![det(Car, FAR, 0.9), good]);
    assert_ap(&r, Car, Metric::Aos, [ONE_POINT / 2.0; 3], [0.0; 3]);
}

#[test]
fn alpha_minus_10_switches_aos_off() {
    let mut d = det(Car, CAR, 0.9);
    d.alpha = -10.0;
    let r = eval1(vec![gt(Car, CAR)], vec![d]);
    assert!(!r.aos_computed);
    assert!(r.get(Car, Metric::Aos, 0).is_none());
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
}

#[test]
fn no_ground_truth_of_a_class_gives_zero_without_panicking() {
    // Pedestrian detections, no pedestrian in the ground truth.
    let r = eval1(
        vec![gt(Car, CAR)],
        vec![det(Pedestrian, FAR, 0.9), det(Car, CAR, 0.9)],
    );
    assert_eq!(r.n_gt(Pedestrian), [0, 0, 0]);
    for metric in Metric::ALL {
        assert_ap(&r, Pedestrian, metric, [0.0; 3], [0.0; 3]);
        assert_ap(&r, Cyclist, metric, [0.0; 3], [0.0; 3]);
    }
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
    // Nothing at all.
    let r = eval1(vec![], vec![]);
    assert_ap(&r, Car, Metric::Bbox, [0.0; 3], [0.0; 3]);
    assert!(r.table().contains("AP is 0 where there is none"));
}

#[test]
fn frames_without_detections_count_their_cars_as_missed() {
    // Frame 0: one car found. Frame 1: one car, no detections. Recall 1/2 at the only
    // threshold, precision 1.
    let r = eval_frames(vec![
        (vec![gt(Car, CAR)], vec![det(Car, CAR, 0.9)]),
        (vec![gt(Car, CAR)], vec![]),
    ]);
    assert_ap(&r, Car, Metric::Bbox, [ONE_POINT; 3], [0.0; 3]);
    let c = r.get(Car, Metric::Bbox, 0).unwrap().curve(Difficulty::Hard);
    assert_eq!((c.tp[0], c.fn_[0]), (1, 1));
    assert_eq!(c.recall, [0.5]);
}

#[test]
fn greatest_overlap_wins_in_the_second_pass() {
    // Two detections on one car: the tighter one (lower score) is the match at the
    // threshold; the other becomes a false positive. First pass picks the higher score
    // (0.9), so the only threshold is 0.9 and at 0.9 only the loose one exists: TP.
    let loose = [105.0, 100.0, 205.0, 200.0]; // IoU 0.905
    let r = eval1(
        vec![gt(Car, CAR)],
        vec![det(Car, loose, 0.9), det(Car, CAR, 0.3)],
    );
    let c = r.get(Car, Metric::Bbox, 0).unwrap().curve(Difficulty::Easy);
    assert_eq!(c.thresholds, [0.9]);
    assert_eq!((c.tp[0], c.fp[0]), (1, 0));
}

#[test]
fn mismatched_frames_and_missing_scores_are_errors() {
    let g = [FrameGt::new("000001", vec![])];
    let d = [FrameDet::new("000002", vec![])];
    let err = evaluate(&g, &d, &EvalConfig::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("000001") && err.contains("000002"), "{err}");
    let d = [FrameDet::new("000001", vec![gt(Car, CAR)])];
    let err = evaluate(&g, &d, &EvalConfig::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("no score"), "{err}");
    let err = evaluate(&g, &[], &EvalConfig::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("1 ground-truth frames but 0"), "{err}");
    let cfg = EvalConfig {
        classes: vec![Van],
        ..EvalConfig::default()
    };
    let err = evaluate(&g, &[FrameDet::new("000001", vec![])], &cfg)
        .unwrap_err()
        .to_string();
    assert!(err.contains("`Van` is not evaluated"), "{err}");
}

#[test]
fn overlap_must_be_strictly_greater_than_the_minimum() {
    // Image IoU exactly 0.7 (7000 / 10000) is not a match for Car; the 3D boxes coincide.
    let r = eval1(
        vec![gt(Car, CAR)],
        vec![det(Car, [100.0, 100.0, 200.0, 170.0], 0.9)],
    );
    assert_ap(&r, Car, Metric::Bbox, [0.0; 3], [0.0; 3]);
    // Not even a candidate in the first pass: no score threshold at all.
    let c = r.get(Car, Metric::Bbox, 0).unwrap().curve(Difficulty::Easy);
    assert!(c.thresholds.is_empty(), "{:?}", c.thresholds);
    assert_ap(&r, Car, Metric::Bev, [ONE_POINT; 3], [0.0; 3]);
    // In the looser setting a pedestrian needs image IoU > 0.5: 0.7 is plenty.
    let r = eval1(
        vec![gt(Pedestrian, CAR)],
        vec![det(Pedestrian, [100.0, 100.0, 200.0, 170.0], 0.9)],
    );
    assert_eq!(
        r.get(Pedestrian, Metric::Bbox, 1).unwrap().ap11,
        [ONE_POINT; 3]
    );
}

/// A car 50 px high (valid at easy) and a detection 39.5 px high on it: truncated to 39 px
/// it is an ignored detection at easy (< 40) but a valid one at moderate and hard.
fn small_on_car() -> ([f64; 4], [f64; 4]) {
    ([100.0, 100.0, 200.0, 150.0], [100.0, 100.0, 200.0, 139.5])
}

#[test]
fn an_ignored_detection_can_absorb_a_ground_truth_box() {
    let (car, small) = small_on_car();
    // First pass takes the highest score, ignored or not: at easy the small detection
    // (0.9) takes the car, so there is no true-positive score and AP is 0, although a
    // valid detection (0.5, better overlap) exists. At moderate the small one is valid.
    let r = eval1(
        vec![gt(Car, car)],
        vec![
            det(Car, small, 0.9),
            det(Car, [95.0, 100.0, 200.0, 150.0], 0.5),
        ],
    );
    assert_ap(&r, Car, Metric::Bbox, [0.0, ONE_POINT, ONE_POINT], [0.0; 3]);
    // A car matched only by an ignored detection is not a miss either (the devkit's
    // recall then counts neither): here, frame 1's car at easy.
    let r = eval_frames(vec![
        (vec![gt(Car, CAR)], vec![det(Car, CAR, 0.9)]),
        (vec![gt(Car, car)], vec![det(Car, small, 0.9)]),
    ]);
    let c = r.get(Car, Metric::Bbox, 0).unwrap().curve(Difficulty::Easy);
    assert_eq!(c.n_gt, 2);
    assert_eq!((c.tp[0], c.fp[0], c.fn_[0]), (1, 0, 0));
}

#[test]
fn second_pass_prefers_a_valid_detection_over_an_ignored_one() {
    let (car, small) = small_on_car();
    let valid = [95.0, 100.0, 200.0, 150.0]; // IoU 0.95, the small one 0.79
    // Valid detection first, then the ignored one: the ignored one must not take over.
    for order in [[0, 1], [1, 0]] {
        let dets = [det(Car, valid, 0.3), det(Car, small, 0.3)];
        let r = eval_frames(vec![
            (vec![gt(Car, CAR)], vec![det(Car, CAR, 0.3)]),
            (
                vec![gt(Car, car)],
                order.iter().map(|&i| dets[i].clone()).collect(),
            ),
        ]);
        let c = r.get(Car, Metric::Bbox, 0).unwrap().curve(Difficulty::Easy);
        let last = c.thresholds.len() - 1;
        assert_eq!(
            (c.tp[last], c.fp[last], c.fn_[last]),
            (2, 0, 0),
            "order {order:?}"
        );
    }
}

/// A dense scene: one frame with 20,000 boxes and 20,000 detections (each on its own box).
/// The overlaps are kept for the pairs that touch only, so the frame is scored in memory
/// proportional to them (a dense matrix of three measures would take 9.6 GB) and every box
/// is found.
#[test]
fn twenty_thousand_boxes_in_one_frame_are_scored_in_bounded_memory() {
    let n = 20_000;
    let boxes: Vec<fusiondet_kitti::Object> = (0..n)
        .map(|i| {
            let (col, row) = ((i % 200) as f64, (i / 200) as f64);
            let mut o = gt(
                Car,
                [col * 60.0, row * 60.0, col * 60.0 + 50.0, row * 60.0 + 50.0],
            );
            o.box3d.x = col * 10.0;
            o.box3d.z = 10.0 + row * 10.0;
            o
        })
        .collect();
    let dets = boxes
        .iter()
        .enumerate()
        .map(|(i, o)| fusiondet_kitti::Object {
            score: Some(1.0 - i as f64 / n as f64),
            ..o.clone()
        })
        .collect();
    let r = eval1(boxes, dets);
    assert_eq!(r.n_gt(Car), [n, n, n]);
    assert_ap(&r, Car, Metric::ThreeD, [100.0; 3], [100.0; 3]);
}
