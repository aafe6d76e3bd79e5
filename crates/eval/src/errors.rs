//! True-positive error metrics: for detections matched to ground truth by centre distance
//! (nuScenes' rule: bird's-eye centre distance below 2 m, greedily by score), how far off they
//! are along depth, laterally, in height, in size and in heading. AP says *that* a model loses
//! boxes at IoU 0.7; these say *where*: along depth (a slicing problem) or in height and size
//! (a training problem).
//!
//! Per class, per difficulty (the ground truth of that level: KITTI's height, occlusion and
//! truncation limits) and per distance, occlusion and (given the scans) LiDAR-points bin of the
//! hard level.

use crate::breakdown::{FramePoints, box_centre_range, distance_bin, points_bin};
use crate::engine::gt_ignored;
use crate::frames::{FrameDet, FrameGt};
use crate::protocol::Difficulty;
use fusiondet_kitti::{Box3d, Object, ObjectClass};
use serde::Serialize;
use std::fmt::Write as _;

/// A ground-truth box with the LiDAR points inside it, when they were counted.
#[derive(Clone, Copy)]
struct Truth<'a> {
    object: &'a Object,
    points: Option<usize>,
}

/// A breakdown axis of the hard level: its name, a ground-truth box's bin (`None`: not
/// counted), the bin labels.
type BinAxis = (&'static str, fn(&Truth) -> Option<usize>, [&'static str; 3]);

/// The hard level's breakdown axes; LiDAR points only when they were counted.
const AXES: [BinAxis; 3] = [
    (
        "distance",
        |t| Some(distance_bin(box_centre_range(&t.object.box3d))),
        ["0-20m", "20-40m", "40m+"],
    ),
    (
        "occlusion",
        |t| Some(t.object.occlusion.clamp(0, 2) as usize),
        ["0", "1", "2"],
    ),
    (
        "lidar_points",
        |t| t.points.map(points_bin),
        ["<100", "100-200", ">200"],
    ),
];

/// Bird's-eye centre distance below which a detection matches a ground-truth box (metres).
pub const MATCH_DISTANCE: f64 = 2.0;

/// Median and mean of one error over the matched pairs (NaN when there are none).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    pub median: f64,
    pub mean: f64,
}

impl Spread {
    fn of(mut values: Vec<f64>) -> Spread {
        if values.is_empty() {
            return Spread {
                median: f64::NAN,
                mean: f64::NAN,
            };
        }
        values.sort_by(f64::total_cmp);
        let n = values.len();
        let median = if n % 2 == 1 {
            values[n / 2]
        } else {
            (values[n / 2 - 1] + values[n / 2]) / 2.0
        };
        Spread {
            median,
            mean: values.iter().sum::<f64>() / n as f64,
        }
    }
}

/// The errors of one group of matched pairs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrorRow {
    pub class: String,
    /// `easy`, `moderate`, `hard`, or a bin of the hard level (`distance 0-20m`, `occlusion 1`).
    pub group: String,
    /// Ground-truth boxes in the group, and how many a detection matched.
    pub ground_truth: usize,
    pub matched: usize,
    /// |Δ| along the camera's z axis (depth), metres.
    pub depth: Spread,
    /// |Δ| along x (lateral), metres.
    pub lateral: Spread,
    /// |Δ| of the box centre's height (y), metres.
    pub height: Spread,
    /// 1 − IoU of the two boxes with centre and heading aligned (size alone).
    pub size: Spread,
    /// Smallest angle between the headings, degrees.
    pub heading: Spread,
}

/// One matched pair's errors, in [`ErrorRow`]'s order.
fn pair_errors(det: &Box3d, gt: &Box3d) -> [f64; 5] {
    let centre_y = |b: &Box3d| b.y - b.h / 2.0;
    let aligned_inter = det.l.min(gt.l) * det.w.min(gt.w) * det.h.min(gt.h);
    let union = det.l * det.w * det.h + gt.l * gt.w * gt.h - aligned_inter;
    let mut dh = (det.ry - gt.ry).rem_euclid(std::f64::consts::TAU);
    if dh > std::f64::consts::PI {
        dh = std::f64::consts::TAU - dh;
    }
    [
        (det.z - gt.z).abs(),
        (det.x - gt.x).abs(),
        (centre_y(det) - centre_y(gt)).abs(),
        1.0 - aligned_inter / union,
        dh.to_degrees(),
    ]
}

/// The pairs of one frame: detections of `class` by descending score, each matched to the
/// nearest unmatched ground truth in `gts` within [`MATCH_DISTANCE`].
fn match_frame<'a>(gts: &[Truth<'a>], dets: &[&'a Object]) -> Vec<(&'a Object, Truth<'a>)> {
    let mut order: Vec<&Object> = dets.to_vec();
    order.sort_by(|a, b| b.score.unwrap_or(0.0).total_cmp(&a.score.unwrap_or(0.0)));
    let mut taken = vec![false; gts.len()];
    let mut pairs = Vec::new();
    for det in order {
        let nearest = gts
            .iter()
            .enumerate()
            .filter(|(i, _)| !taken[*i])
            .map(|(i, g)| {
                let b = &g.object.box3d;
                (i, (b.x - det.box3d.x).hypot(b.z - det.box3d.z))
            })
            .filter(|(_, d)| *d < MATCH_DISTANCE)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((i, _)) = nearest {
            taken[i] = true;
            pairs.push((det, gts[i]));
        }
    }
    pairs
}

/// The error rows of `classes`: per difficulty, then per distance and occlusion bin of the
/// hard level, and per LiDAR-points bin when `points` (from
/// [`crate::breakdown::count_lidar_points`], frame by frame) is given.
pub fn true_positive_errors(
    gt: &[FrameGt],
    det: &[FrameDet],
    classes: &[ObjectClass],
    points: Option<&[FramePoints]>,
) -> Vec<ErrorRow> {
    // The ground truth of frame `f` of `class` at level `d`, with its point counts.
    let truths = |f: usize, class: ObjectClass, d: Difficulty| -> Vec<Truth<'_>> {
        let counts = points.map(|p| &p[f].gt);
        gt[f]
            .objects
            .iter()
            .enumerate()
            .filter(|(_, o)| o.class == class && !gt_ignored(o, d))
            .map(|(i, object)| Truth {
                object,
                points: counts.map(|c| c[i]),
            })
            .collect()
    };
    let axes = if points.is_some() {
        &AXES[..]
    } else {
        &AXES[..2]
    };
    let mut rows = Vec::new();
    for &class in classes {
        let mut hard_pairs = Vec::new();
        for d in Difficulty::ALL {
            let mut counted = 0;
            let mut pairs = Vec::new();
            for (f, p) in det.iter().enumerate().take(gt.len()) {
                let gts = truths(f, class, d);
                let dets: Vec<&Object> = p.objects.iter().filter(|o| o.class == class).collect();
                counted += gts.len();
                pairs.extend(match_frame(&gts, &dets));
            }
            rows.push(row(class, d.as_str().to_string(), counted, &pairs));
            hard_pairs = pairs;
        }
        let hard_gt: Vec<Truth> = (0..gt.len())
            .flat_map(|f| truths(f, class, Difficulty::Hard))
            .collect();
        for (axis, bin_of, labels) in axes {
            for (b, label) in labels.iter().enumerate() {
                let counted = hard_gt.iter().filter(|t| bin_of(t) == Some(b)).count();
                let pairs: Vec<(&Object, Truth)> = hard_pairs
                    .iter()
                    .filter(|(_, t)| bin_of(t) == Some(b))
                    .copied()
                    .collect();
                rows.push(row(class, format!("{axis} {label}"), counted, &pairs));
            }
        }
    }
    rows
}

fn row(
    class: ObjectClass,
    group: String,
    ground_truth: usize,
    pairs: &[(&Object, Truth)],
) -> ErrorRow {
    let errors: Vec<[f64; 5]> = pairs
        .iter()
        .map(|(d, g)| pair_errors(&d.box3d, &g.object.box3d))
        .collect();
    let column = |k: usize| Spread::of(errors.iter().map(|e| e[k]).collect());
    ErrorRow {
        class: class.to_string(),
        group,
        ground_truth,
        matched: pairs.len(),
        depth: column(0),
        lateral: column(1),
        height: column(2),
        size: column(3),
        heading: column(4),
    }
}

/// The rows as a text table: median / mean of each error.
pub fn errors_table(rows: &[ErrorRow]) -> String {
    let mut out = String::from(
        "True-positive errors (detections within 2 m of a ground-truth centre; median / mean):\n",
    );
    let _ = writeln!(
        out,
        "{:<10} {:<18} {:>13} {:>15} {:>15} {:>15} {:>15} {:>15}",
        "class",
        "group",
        "matched/gt",
        "depth m",
        "lateral m",
        "height m",
        "size 1-IoU",
        "heading deg"
    );
    for r in rows {
        let cell = |s: &Spread| format!("{:.3} / {:.3}", s.median, s.mean);
        let _ = writeln!(
            out,
            "{:<10} {:<18} {:>13} {:>15} {:>15} {:>15} {:>15} {:>15}",
            r.class,
            r.group,
            format!("{}/{}", r.matched, r.ground_truth),
            cell(&r.depth),
            cell(&r.lateral),
            cell(&r.height),
            cell(&r.size),
            cell(&r.heading)
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_kitti::Box2d;

    fn car(b: Box3d, score: Option<f64>, occlusion: i32) -> Object {
        Object {
            class: ObjectClass::Car,
            truncation: 0.0,
            occlusion,
            alpha: 0.0,
            bbox: Box2d {
                x1: 100.0,
                y1: 100.0,
                x2: 200.0,
                y2: 160.0,
            },
            box3d: b,
            score,
        }
    }

    fn at(x: f64, z: f64) -> Box3d {
        Box3d {
            h: 1.5,
            w: 1.6,
            l: 4.0,
            x,
            y: 1.6,
            z,
            ry: 0.0,
        }
    }

    #[test]
    fn hand_made_pairs_give_their_errors() {
        let gt = vec![FrameGt::new(
            "0",
            vec![car(at(0.0, 10.0), None, 0), car(at(5.0, 30.0), None, 1)],
        )];
        // One 0.5 m too far and 0.2 m to the side, 10 % too long, turned by 10°; one 3 m away
        // from anything (a false positive, unmatched); the second car missed.
        let mut off = at(0.2, 10.5);
        off.l = 4.4;
        off.ry = 10f64.to_radians();
        let det = vec![FrameDet::new(
            "0",
            vec![car(off, Some(0.9), 0), car(at(-3.0, 10.0), Some(0.95), 0)],
        )];
        let rows = true_positive_errors(&gt, &det, &[ObjectClass::Car], None);
        let easy = &rows[0];
        assert_eq!(
            (easy.group.as_str(), easy.ground_truth, easy.matched),
            ("easy", 1, 1)
        );
        assert!((easy.depth.median - 0.5).abs() < 1e-12);
        assert!((easy.lateral.mean - 0.2).abs() < 1e-12);
        assert!(easy.height.median.abs() < 1e-12);
        // Aligned: the shorter box inside the longer, IoU 4.0 / 4.4.
        assert!((easy.size.median - (1.0 - 4.0 / 4.4)).abs() < 1e-12);
        assert!((easy.heading.median - 10.0).abs() < 1e-9);
        let hard = &rows[2];
        assert_eq!((hard.ground_truth, hard.matched), (2, 1));
        let occluded = rows.iter().find(|r| r.group == "occlusion 1").unwrap();
        assert_eq!((occluded.ground_truth, occluded.matched), (1, 0));
        assert!(occluded.depth.median.is_nan());
        let far = rows.iter().find(|r| r.group == "distance 20-40m").unwrap();
        assert_eq!(far.ground_truth, 1);
        assert!(!rows.iter().any(|r| r.group.starts_with("lidar_points")));
        // With point counts: the matched car has 150 points, the missed one 40.
        let points = [FramePoints {
            gt: vec![150, 40],
            det: vec![0, 0],
        }];
        let rows = true_positive_errors(&gt, &det, &[ObjectClass::Car], Some(&points));
        let mid = rows
            .iter()
            .find(|r| r.group == "lidar_points 100-200")
            .unwrap();
        assert_eq!((mid.ground_truth, mid.matched), (1, 1));
        let few = rows
            .iter()
            .find(|r| r.group == "lidar_points <100")
            .unwrap();
        assert_eq!((few.ground_truth, few.matched), (1, 0));
    }

    #[test]
    fn the_higher_score_takes_the_nearer_truth_first_and_headings_wrap() {
        let gt = vec![FrameGt::new("0", vec![car(at(0.0, 10.0), None, 0)])];
        let mut flipped = at(0.5, 10.0);
        flipped.ry = std::f64::consts::PI - 0.1;
        let mut turned = at(0.1, 10.0);
        turned.ry = -std::f64::consts::PI + 0.05;
        let det = vec![FrameDet::new(
            "0",
            vec![car(flipped, Some(0.8), 0), car(turned, Some(0.3), 0)],
        )];
        let rows = true_positive_errors(&gt, &det, &[ObjectClass::Car], None);
        // The 0.8 detection matches although the 0.3 one is nearer.
        assert!((rows[0].lateral.median - 0.5).abs() < 1e-12);
        assert!((rows[0].heading.median - (180.0 - 0.1f64.to_degrees())).abs() < 1e-9);
        assert!(
            (pair_errors(&turned, &at(0.0, 10.0))[4] - (180.0 - 0.05f64.to_degrees())).abs() < 1e-9
        );
        assert!(errors_table(&rows).contains("matched/gt"));
    }
}
