//! Realism against KITTI on a small generated set: points on cars by distance
//! within a factor of two of KITTI's curve, KITTI-like class mix, occlusion and
//! truncation shares, and the shape of the simulated 2D detector's output.

use fusiondet_sim::{DatasetStats, FrameStats, SimConfig, simulate_frame};
use rayon::prelude::*;

fn stats() -> DatasetStats {
    let cfg = SimConfig::default();
    let frames: Vec<FrameStats> = (0..24)
        .into_par_iter()
        .map(|i| FrameStats::from_frame(&simulate_frame(2024, i, &cfg)))
        .collect();
    DatasetStats::from_frames(&frames)
}

#[test]
fn simulated_data_looks_like_kitti() {
    let s = stats();
    eprintln!("{}", s.report());

    // Points inside unoccluded car boxes: within ×2 of KITTI's measured curve in every
    // populated bin where KITTI has measurements (13–58 m, plus the 10–13 m edge).
    let mut checked = 0;
    for b in s
        .points_per_car
        .iter()
        .filter(|b| b.depth_from >= 10.0 && b.depth_to <= 60.0)
    {
        if b.cars >= 4 {
            checked += 1;
            assert!(
                (0.5..=2.0).contains(&b.ratio),
                "{}–{} m: median {} points vs KITTI {} (ratio {})",
                b.depth_from,
                b.depth_to,
                b.median_points,
                b.kitti_points,
                b.ratio
            );
        }
    }
    assert!(checked >= 4, "only {checked} populated distance bins");

    // Full frames of ~100k–130k points, like KITTI's 113k–127k.
    assert!((95_000.0..135_000.0).contains(&s.points_per_frame_median));

    // Class mix: cars dominate, pedestrians and cyclists are rarer.
    let share = |c: &str| s.evaluated_class_share.get(c).copied().unwrap_or(0.0);
    assert!(
        (0.65..=0.9).contains(&share("Car")),
        "{:?}",
        s.evaluated_class_share
    );
    assert!(
        share("Pedestrian") > 0.04 && share("Cyclist") > 0.01,
        "{:?}",
        s.evaluated_class_share
    );
    assert!(share("Pedestrian") > share("Cyclist") * 0.8);

    // About half the cars are occluded; some are truncated; hard difficulty populated.
    assert!(
        (0.3..=0.7).contains(&s.car_occluded_share),
        "{}",
        s.car_occluded_share
    );
    assert!(
        (0.02..=0.3).contains(&s.car_truncated_share),
        "{}",
        s.car_truncated_share
    );
    let cars = &s.difficulty["Car"];
    assert!(cars.get("hard").copied().unwrap_or(0) >= 5, "{cars:?}");
    assert!(cars.get("moderate").copied().unwrap_or(0) >= 10, "{cars:?}");
    assert!(s.dontcare > 0);

    // The 2D detector: confident on most objects, a tail of low scores, false positives.
    let d = &s.detector;
    assert!(
        d.score_buckets[4] > 0.15 && d.score_buckets[0] > 0.08,
        "{:?}",
        d.score_buckets
    );
    assert!(
        (0.05..0.5).contains(&d.false_positive_share),
        "{}",
        d.false_positive_share
    );
    assert!(d.median_iou_matched > 0.8 && d.median_iou_matched < 0.97);
    let car = &d.recall["Car"];
    assert!(car["easy"] >= car.get("hard").copied().unwrap_or(0.0));
}
