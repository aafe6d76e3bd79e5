//! AP_R40 (bev and 3d) broken down by distance, occlusion level and LiDAR point count.
//!
//! The official protocol has no such breakdown, so the filtering rule is ours, chosen so
//! that every ground-truth box and every false positive is counted in exactly one bin
//! (per axis) and nothing is counted twice:
//!
//! * **Ground truth**: a box outside the bin is treated like the devkit's ignored ground
//!   truth: neither a miss nor a hit, and a detection matched to it is dropped. Difficulty
//!   filtering applies as usual, so e.g. occlusion level 2 has ground truth only at hard.
//! * **Matched detections** count as true positives in the bin of their ground truth,
//!   wherever the detection itself lies.
//! * **Unmatched detections** (would-be false positives) are charged to the bin of the
//!   ground-truth box (evaluated class or its neighbour class) they overlap most in the
//!   measure being evaluated (overlap > 0; first box on ties), so a badly localised
//!   detection is charged where its object is. A detection overlapping no such box is
//!   charged by its own box: distance — its own centre range; LiDAR points — the points
//!   inside its own box; occlusion, which a detection does not have — every occlusion
//!   bin. In other bins it is not counted at all.
//!
//! Bins: distance [0, 20), [20, 40), [40, ∞) m, where distance is the range of the 3D
//! box centre in the rectified camera frame, √(x² + (y − h/2)² + z²) (KITTI's (x, y, z)
//! is the bottom-face centre and y points down); occlusion 0, 1, 2 (label field, level 3
//! "unknown" is in no bin); LiDAR points inside the box: [0, 100), [100, 200], (200, ∞).

use crate::engine::{self, BinMask, ClassFrame};
use crate::error::EvalError;
use crate::evaluate::{EvalConfig, tasks_for, validate};
use crate::frames::{FrameDet, FrameGt};
use crate::protocol::{Metric, is_evaluated, neighbour_class};
use crate::report::PrCurve;
use fusiondet_dataset::{DataError, scan_in_rect};
use fusiondet_geometry::count_points_in_box;
use fusiondet_kitti::{Box3d, FormatError, Object, ObjectClass};
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

/// What a breakdown groups by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BreakdownAxis {
    Distance,
    Occlusion,
    LidarPoints,
}

impl BreakdownAxis {
    pub const ALL: [BreakdownAxis; 3] = [
        BreakdownAxis::Distance,
        BreakdownAxis::Occlusion,
        BreakdownAxis::LidarPoints,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            BreakdownAxis::Distance => "distance",
            BreakdownAxis::Occlusion => "occlusion",
            BreakdownAxis::LidarPoints => "lidar_points",
        }
    }

    /// Bin labels, in bin order.
    pub fn bins(self) -> [&'static str; 3] {
        match self {
            BreakdownAxis::Distance => ["0-20m", "20-40m", "40m+"],
            BreakdownAxis::Occlusion => ["0", "1", "2"],
            BreakdownAxis::LidarPoints => ["<100", "100-200", ">200"],
        }
    }
}

/// Range of the 3D box centre from the camera origin (rectified frame), in metres.
pub fn box_centre_range(b: &Box3d) -> f64 {
    let yc = b.y - b.h / 2.0;
    (b.x * b.x + yc * yc + b.z * b.z).sqrt()
}

/// Distance bin: [0, 20), [20, 40), [40, ∞) m.
pub fn distance_bin(range: f64) -> usize {
    if range < 20.0 {
        0
    } else if range < 40.0 {
        1
    } else {
        2
    }
}

/// LiDAR point bin: [0, 100), [100, 200], (200, ∞).
pub fn points_bin(n: usize) -> usize {
    if n < 100 {
        0
    } else if n <= 200 {
        1
    } else {
        2
    }
}

/// LiDAR points inside each box of a frame, in object order (0 for boxes that no
/// evaluated class cares about, e.g. DontCare).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FramePoints {
    pub gt: Vec<usize>,
    pub det: Vec<usize>,
}

fn relevant(class: ObjectClass) -> bool {
    is_evaluated(class)
        || ObjectClass::EVALUATED
            .iter()
            .any(|&c| neighbour_class(c) == Some(class))
}

/// Counts the LiDAR points (`velodyne_dir/ID.bin`, transformed with `calib_dir/ID.txt`)
/// inside every ground-truth and detection box.
pub fn count_lidar_points(
    gt: &[FrameGt],
    det: &[FrameDet],
    velodyne_dir: &Path,
    calib_dir: &Path,
) -> Result<Vec<FramePoints>, EvalError> {
    let counted: Vec<Result<FramePoints, EvalError>> = gt
        .par_iter()
        .zip(det.par_iter())
        .map(|(g, d)| {
            let calib_path = calib_dir.join(format!("{}.txt", g.id));
            let points = scan_in_rect(&velodyne_dir.join(format!("{}.bin", g.id)), &calib_path)
                .map_err(|e| match e {
                    DataError::Format(e) => EvalError::Breakdown(e),
                    DataError::Calib { message, .. } | DataError::Data(message) => {
                        EvalError::Breakdown(FormatError::file(&calib_path, message))
                    }
                })?;
            let count = |objects: &[Object]| {
                objects
                    .iter()
                    .map(|o| {
                        if relevant(o.class) {
                            count_points_in_box(&o.box3d, &points)
                        } else {
                            0
                        }
                    })
                    .collect()
            };
            Ok(FramePoints {
                gt: count(&g.objects),
                det: count(&d.objects),
            })
        })
        .collect();
    counted.into_iter().collect()
}

/// One breakdown row: AP_R40 of a class, measure and overlap setting within one bin.
#[derive(Debug, Clone, PartialEq)]
pub struct BreakdownRow {
    pub class: ObjectClass,
    /// Bev or ThreeD.
    pub metric: Metric,
    /// Index into the config's settings.
    pub setting: usize,
    pub min_overlap: f64,
    pub axis: BreakdownAxis,
    pub bin: &'static str,
    /// Non-ignored ground truth in the bin at easy, moderate, hard.
    pub n_gt: [usize; 3],
    /// AP_R40 in percent; `None` where the bin has no ground truth at that difficulty.
    pub ap40: [Option<f64>; 3],
    pub curves: [PrCurve; 3],
}

/// The bin of a box for an axis (None: in no bin).
fn gt_bin(axis: BreakdownAxis, o: &Object, points: Option<usize>) -> Option<usize> {
    match axis {
        BreakdownAxis::Distance => Some(distance_bin(box_centre_range(&o.box3d))),
        BreakdownAxis::Occlusion => (0..=2)
            .contains(&o.occlusion)
            .then_some(o.occlusion as usize),
        BreakdownAxis::LidarPoints => points.map(points_bin),
    }
}

/// Where an unmatched detection is charged: `Some(bin)`, or `None` for every bin.
#[derive(Clone, Copy, PartialEq)]
enum Charge {
    Bin(Option<usize>),
    Every,
}

fn mask_for(
    cf: &ClassFrame,
    g: &FrameGt,
    d: &FrameDet,
    pts: Option<&FramePoints>,
    axis: BreakdownAxis,
    bin: usize,
) -> BinMask {
    let gbin = |gi: usize| {
        let obj = cf.gt_obj[gi] as usize;
        gt_bin(axis, &g.objects[obj], pts.map(|p| p.gt[obj]))
    };
    let gt_out = (0..cf.n_gt()).map(|gi| gbin(gi) != Some(bin)).collect();
    let (ng, nd) = (cf.n_gt(), cf.n_det());
    let det_exempt = std::array::from_fn(|m| {
        // The ground-truth box each detection overlaps most, if any (the first in file
        // order of equals).
        let mut best_of = vec![(0.0, usize::MAX); nd];
        for gi in 0..ng {
            for &(j, ov) in cf.pairs_of(gi) {
                let best = &mut best_of[j as usize];
                if ov[m] > best.0 {
                    *best = (ov[m], gi);
                }
            }
        }
        (0..nd)
            .map(|j| {
                let best = best_of[j];
                let charge = if best.1 != usize::MAX {
                    Charge::Bin(gbin(best.1))
                } else {
                    let obj = cf.det_obj[j] as usize;
                    let o = &d.objects[obj];
                    match axis {
                        BreakdownAxis::Distance => {
                            Charge::Bin(Some(distance_bin(box_centre_range(&o.box3d))))
                        }
                        BreakdownAxis::LidarPoints => {
                            Charge::Bin(pts.map(|p| points_bin(p.det[obj])))
                        }
                        BreakdownAxis::Occlusion => Charge::Every,
                    }
                };
                charge != Charge::Every && charge != Charge::Bin(Some(bin))
            })
            .collect()
    });
    BinMask { gt_out, det_exempt }
}

/// Evaluates bev and 3d AP_R40 per bin of each axis; the LiDAR-point axis needs
/// `points` (from [`count_lidar_points`]) and is skipped without it. See the module
/// documentation for the filtering rule.
pub fn evaluate_breakdown(
    gt: &[FrameGt],
    det: &[FrameDet],
    cfg: &EvalConfig,
    points: Option<&[FramePoints]>,
) -> Result<Vec<BreakdownRow>, EvalError> {
    validate(gt, det, cfg)?;
    if let Some(p) = points {
        let consistent = p.len() == gt.len()
            && p.iter()
                .zip(gt.iter().zip(det))
                .all(|(p, (g, d))| p.gt.len() == g.objects.len() && p.det.len() == d.objects.len());
        if !consistent {
            return Err(EvalError::Class(
                "LiDAR point counts do not match the frames (one count per object and frame)"
                    .into(),
            ));
        }
    }
    let metrics = [Metric::Bev, Metric::ThreeD];
    let (tasks, rows) = tasks_for(cfg, &metrics);
    let prepared = engine::prepare(gt, det, &cfg.classes)?;
    let mut out = Vec::new();
    for axis in BreakdownAxis::ALL {
        if axis == BreakdownAxis::LidarPoints && points.is_none() {
            continue;
        }
        for (bin, label) in axis.bins().into_iter().enumerate() {
            let masks: Vec<Vec<BinMask>> = prepared
                .frames
                .par_iter()
                .enumerate()
                .map(|(fi, classes)| {
                    let pts = points.map(|p| &p[fi]);
                    classes
                        .iter()
                        .map(|cf| mask_for(cf, &gt[fi], &det[fi], pts, axis, bin))
                        .collect()
                })
                .collect();
            let counts = engine::run(&prepared, &tasks, Some(&masks), false);
            for r in &rows {
                let (s, metric, ti) = (r.setting, r.metric, r.task);
                let class = cfg.classes[r.class_idx];
                let curves: [PrCurve; 3] =
                    std::array::from_fn(|d| PrCurve::from_counts(&counts[ti][d], false));
                out.push(BreakdownRow {
                    class,
                    metric,
                    setting: s,
                    min_overlap: cfg.settings[s]
                        .min_overlap(class, metric)
                        .expect("validated class"),
                    axis,
                    bin: label,
                    n_gt: std::array::from_fn(|d| curves[d].n_gt),
                    ap40: std::array::from_fn(|d| (curves[d].n_gt > 0).then(|| curves[d].ap40())),
                    curves,
                });
            }
        }
    }
    // Report grouped by class, setting, metric, then axis and bin.
    out.sort_by_key(|r| {
        (
            cfg.classes.iter().position(|&c| c == r.class),
            r.setting,
            r.metric,
            BreakdownAxis::ALL.iter().position(|&a| a == r.axis),
        )
    });
    Ok(out)
}

/// The breakdown as text, one line per row.
pub fn breakdown_table(rows: &[BreakdownRow]) -> String {
    let mut out = String::from(
        "Breakdown, AP_R40 in % (easy, moderate, hard; n = ground-truth boxes in the bin; - = none):\n",
    );
    for r in rows {
        let ap = r
            .ap40
            .map(|a| a.map_or("-".to_string(), |v| format!("{v:.4}")));
        out.push_str(&format!(
            "{} {:<3}@{:.2} {:<12} {:<8} AP:{}, {}, {}  (n = {} / {} / {})\n",
            r.class,
            r.metric.as_str(),
            r.min_overlap,
            r.axis.as_str(),
            r.bin,
            ap[0],
            ap[1],
            ap[2],
            r.n_gt[0],
            r.n_gt[1],
            r.n_gt[2]
        ));
    }
    out
}

#[derive(Serialize)]
pub(crate) struct JsonBreakdownRow {
    class: &'static str,
    metric: &'static str,
    min_overlap: f64,
    by: &'static str,
    bin: &'static str,
    n_gt: [usize; 3],
    ap40: [Option<f64>; 3],
}

impl From<&BreakdownRow> for JsonBreakdownRow {
    fn from(r: &BreakdownRow) -> Self {
        JsonBreakdownRow {
            class: r.class.as_str(),
            metric: r.metric.as_str(),
            min_overlap: r.min_overlap,
            by: r.axis.as_str(),
            bin: r.bin,
            n_gt: r.n_gt,
            ap40: r.ap40,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::tests_support::{det, gt};
    use crate::{Difficulty, evaluate, synthetic};
    use fusiondet_kitti::ObjectClass::Car;

    /// A 4 m × 1.6 m car at (x, z), 100 px high in the image at column `u`.
    fn at(mut o: Object, x: f64, z: f64) -> Object {
        o.box3d.x = x;
        o.box3d.z = z;
        o
    }

    fn frame() -> (FrameGt, FrameDet) {
        let bbox = |u: f64| [u, 100.0, u + 80.0, 200.0];
        let near = at(gt(Car, bbox(100.0)), 0.0, 10.0);
        let mut far = at(gt(Car, bbox(300.0)), 0.0, 30.0);
        far.occlusion = 1;
        let dets = vec![
            at(det(Car, bbox(100.0), 0.9), 0.0, 10.0),    // hits `near`
            at(det(Car, bbox(300.0), 0.8), 0.0, 30.0),    // hits `far`
            at(det(Car, bbox(500.0), 0.99), 2.5, 10.0), // BEV IoU 0.23 with `near`: a near false positive
            at(det(Car, bbox(700.0), 0.95), -15.0, 30.0), // overlaps nothing, 33.5 m away
        ];
        (
            FrameGt::new("000000", vec![near, far]),
            FrameDet::new("000000", dets),
        )
    }

    fn row<'a>(rows: &'a [BreakdownRow], axis: BreakdownAxis, bin: &str) -> &'a BreakdownRow {
        rows.iter()
            .find(|r| r.axis == axis && r.bin == bin && r.metric == Metric::Bev && r.setting == 0)
            .unwrap()
    }

    /// (tp, fp) at the last threshold, hard difficulty.
    fn tp_fp(r: &BreakdownRow) -> (u64, u64) {
        let c = &r.curves[Difficulty::Hard.index()];
        let last = c.thresholds.len() - 1;
        (c.tp[last], c.fp[last])
    }

    #[test]
    fn false_positives_are_charged_to_one_bin() {
        let (g, d) = frame();
        let cfg = EvalConfig {
            classes: vec![Car],
            ..EvalConfig::default()
        };
        let points = [FramePoints {
            gt: vec![50, 150],
            det: vec![50, 150, 40, 300],
        }];
        let rows = evaluate_breakdown(&[g], &[d], &cfg, Some(&points)).unwrap();
        // Distance: the badly placed detection goes with the car it overlaps, the stray
        // one by its own range (33.5 m).
        assert_eq!(tp_fp(row(&rows, BreakdownAxis::Distance, "0-20m")), (1, 1));
        assert_eq!(tp_fp(row(&rows, BreakdownAxis::Distance, "20-40m")), (1, 1));
        let empty = row(&rows, BreakdownAxis::Distance, "40m+");
        assert_eq!((empty.n_gt, empty.ap40), ([0; 3], [None; 3]));
        // Occlusion: the far car (level 1) exists from moderate on; the stray detection
        // has no level and counts in every bin.
        let occ0 = row(&rows, BreakdownAxis::Occlusion, "0");
        let occ1 = row(&rows, BreakdownAxis::Occlusion, "1");
        assert_eq!((occ0.n_gt, occ1.n_gt), ([1, 1, 1], [0, 1, 1]));
        assert_eq!(tp_fp(occ0), (1, 2));
        assert_eq!(tp_fp(occ1), (1, 1));
        // LiDAR points: the stray detection has 300 points of its own: bin >200, which has
        // no ground truth; the two cars' bins see only the overlapping false positive.
        assert_eq!(
            tp_fp(row(&rows, BreakdownAxis::LidarPoints, "<100")),
            (1, 1)
        );
        assert_eq!(
            tp_fp(row(&rows, BreakdownAxis::LidarPoints, "100-200")),
            (1, 0)
        );
        assert_eq!(row(&rows, BreakdownAxis::LidarPoints, ">200").n_gt, [0; 3]);
    }

    #[test]
    fn every_ground_truth_box_is_in_exactly_one_bin() {
        let (g, d) = synthetic::generate(300, 3);
        let cfg = EvalConfig::default();
        let report = evaluate(&g, &d, &cfg).unwrap();
        let rows = evaluate_breakdown(&g, &d, &cfg, None).unwrap();
        assert!(rows.iter().all(|r| r.axis != BreakdownAxis::LidarPoints));
        for &class in &cfg.classes {
            for axis in [BreakdownAxis::Distance, BreakdownAxis::Occlusion] {
                let mut sum = [0; 3];
                for r in rows.iter().filter(|r| {
                    r.class == class
                        && r.axis == axis
                        && r.metric == Metric::ThreeD
                        && r.setting == 1
                }) {
                    for (acc, n) in sum.iter_mut().zip(r.n_gt) {
                        *acc += n;
                    }
                }
                assert_eq!(sum, report.n_gt(class), "{class} {axis:?}");
            }
        }
    }

    #[test]
    fn range_and_bins() {
        let b = Box3d {
            h: 2.0,
            w: 1.0,
            l: 1.0,
            x: 3.0,
            y: 1.0,
            z: 4.0,
            ry: 0.0,
        };
        // Centre (3, 0, 4).
        assert!((box_centre_range(&b) - 5.0).abs() < 1e-12);
        assert_eq!(
            [distance_bin(19.99), distance_bin(20.0), distance_bin(40.0)],
            [0, 1, 2]
        );
        assert_eq!(
            [
                points_bin(99),
                points_bin(100),
                points_bin(200),
                points_bin(201)
            ],
            [0, 1, 1, 2]
        );
    }
}
