//! A deliberately naive, line-by-line rendering of the devkit's cleanData /
//! computeStatistics / getThresholds / eval_class (every detection, every threshold,
//! overlaps recomputed each time), used only to check that the optimised engine makes
//! exactly the same decisions on large random data sets. Indexed loops on purpose: it
//! mirrors the C++.
#![allow(clippy::needless_range_loop)]

use crate::engine::{self, Counts, Task};
use crate::frames::{FrameDet, FrameGt};
use crate::protocol::{Difficulty, OverlapSetting, neighbour_class};
use crate::synthetic;
use fusiondet_geometry::{Normalization, overlap_2d, overlap_3d, overlap_bev};
use fusiondet_kitti::{Object, ObjectClass};

fn boxoverlap(m: usize, d: &Object, g: &Object, norm: Normalization) -> f64 {
    match m {
        0 => overlap_2d(&d.bbox, &g.bbox, norm),
        1 => overlap_bev(&d.box3d, &g.box3d, norm),
        _ => overlap_3d(&d.box3d, &g.box3d, norm),
    }
}

struct Clean<'a> {
    ignored_gt: Vec<i32>,
    dc: Vec<&'a Object>,
    ignored_det: Vec<i32>,
    n_gt: usize,
}

fn clean_data<'a>(
    class: ObjectClass,
    gt: &'a [Object],
    det: &[Object],
    diff: Difficulty,
) -> Clean<'a> {
    let mut c = Clean {
        ignored_gt: vec![],
        dc: vec![],
        ignored_det: vec![],
        n_gt: 0,
    };
    for g in gt {
        let height = g.bbox.y2 - g.bbox.y1;
        let valid_class = if g.class == class {
            1
        } else if Some(g.class) == neighbour_class(class) {
            0
        } else {
            -1
        };
        let ignore = g.occlusion > diff.max_occlusion()
            || g.truncation > diff.max_truncation()
            || height <= diff.min_height();
        if valid_class == 1 && !ignore {
            c.ignored_gt.push(0);
            c.n_gt += 1;
        } else if valid_class == 0 || (ignore && valid_class == 1) {
            c.ignored_gt.push(1);
        } else {
            c.ignored_gt.push(-1);
        }
    }
    c.dc = gt
        .iter()
        .filter(|g| g.class == ObjectClass::DontCare)
        .collect();
    for d in det {
        let valid_class = if d.class == class { 1 } else { -1 };
        let height = (d.bbox.y1 - d.bbox.y2).abs() as i32;
        if (height as f64) < diff.min_height() {
            c.ignored_det.push(1);
        } else if valid_class == 1 {
            c.ignored_det.push(0);
        } else {
            c.ignored_det.push(-1);
        }
    }
    c
}

#[derive(Default)]
struct Stat {
    tp: u64,
    fp: u64,
    fn_: u64,
    v: Vec<f64>,
    similarity: f64,
}

#[allow(clippy::too_many_arguments)]
fn compute_statistics(
    gt: &[Object],
    det: &[Object],
    c: &Clean,
    compute_fp: bool,
    m: usize,
    min: f64,
    aos: bool,
    thresh: f64,
) -> Stat {
    const NO_DETECTION: f64 = -10000000.0;
    let mut stat = Stat::default();
    let mut delta = vec![];
    let mut assigned = vec![false; det.len()];
    let ignored_threshold: Vec<bool> = det
        .iter()
        .map(|d| compute_fp && d.score.unwrap() < thresh)
        .collect();
    for i in 0..gt.len() {
        if c.ignored_gt[i] == -1 {
            continue;
        }
        let mut det_idx: i64 = -1;
        let mut valid_detection = NO_DETECTION;
        let mut max_iou = 0.0;
        let mut assigned_ignored_det = false;
        for j in 0..det.len() {
            if c.ignored_det[j] == -1 || assigned[j] || ignored_threshold[j] {
                continue;
            }
            let overlap = boxoverlap(m, &det[j], &gt[i], Normalization::Union);
            let score = det[j].score.unwrap();
            if !compute_fp && overlap > min && score > valid_detection {
                det_idx = j as i64;
                valid_detection = score;
            } else if compute_fp
                && overlap > min
                && (overlap > max_iou || assigned_ignored_det)
                && c.ignored_det[j] == 0
            {
                max_iou = overlap;
                det_idx = j as i64;
                valid_detection = 1.0;
                assigned_ignored_det = false;
            } else if compute_fp
                && overlap > min
                && valid_detection == NO_DETECTION
                && c.ignored_det[j] == 1
            {
                det_idx = j as i64;
                valid_detection = 1.0;
                assigned_ignored_det = true;
            }
        }
        if valid_detection == NO_DETECTION && c.ignored_gt[i] == 0 {
            stat.fn_ += 1;
        } else if valid_detection != NO_DETECTION
            && (c.ignored_gt[i] == 1 || c.ignored_det[det_idx as usize] == 1)
        {
            assigned[det_idx as usize] = true;
        } else if valid_detection != NO_DETECTION {
            stat.tp += 1;
            stat.v.push(det[det_idx as usize].score.unwrap());
            if aos {
                delta.push(gt[i].alpha - det[det_idx as usize].alpha);
            }
            assigned[det_idx as usize] = true;
        }
    }
    if compute_fp {
        for i in 0..det.len() {
            if !(assigned[i]
                || c.ignored_det[i] == -1
                || c.ignored_det[i] == 1
                || ignored_threshold[i])
            {
                stat.fp += 1;
            }
        }
        let mut nstuff = 0;
        for dc in &c.dc {
            for j in 0..det.len() {
                if assigned[j]
                    || c.ignored_det[j] == -1
                    || c.ignored_det[j] == 1
                    || ignored_threshold[j]
                {
                    continue;
                }
                if boxoverlap(m, &det[j], dc, Normalization::First) > min {
                    assigned[j] = true;
                    nstuff += 1;
                }
            }
        }
        stat.fp -= nstuff;
        if aos {
            stat.similarity = delta.iter().map(|d| (1.0 + d.cos()) / 2.0).sum();
        }
    }
    stat
}

fn get_thresholds(v: &mut [f64], n: usize) -> Vec<f64> {
    v.sort_by(|a, b| b.partial_cmp(a).unwrap());
    let mut t = vec![];
    let mut current = 0.0;
    for i in 0..v.len() {
        let l = (i + 1) as f64 / n as f64;
        let r = if i < v.len() - 1 {
            (i + 2) as f64 / n as f64
        } else {
            l
        };
        if (r - current) < (current - l) && i < v.len() - 1 {
            continue;
        }
        t.push(v[i]);
        current += 1.0 / (41.0 - 1.0);
    }
    t
}

fn eval_class(
    gt: &[FrameGt],
    det: &[FrameDet],
    class: ObjectClass,
    diff: Difficulty,
    m: usize,
    min: f64,
) -> Counts {
    let aos = m == 0;
    let mut n_gt = 0;
    let mut v = vec![];
    let mut cleaned = vec![];
    for (g, d) in gt.iter().zip(det) {
        let c = clean_data(class, &g.objects, &d.objects, diff);
        n_gt += c.n_gt;
        v.extend(compute_statistics(&g.objects, &d.objects, &c, false, m, min, false, 0.0).v);
        cleaned.push(c);
    }
    let thresholds = get_thresholds(&mut v, n_gt);
    let mut out = Counts {
        n_gt,
        thresholds: thresholds.clone(),
        tp: vec![0; thresholds.len()],
        fp: vec![0; thresholds.len()],
        fn_: vec![0; thresholds.len()],
        similarity: vec![0.0; thresholds.len()],
    };
    for ((g, d), c) in gt.iter().zip(det).zip(&cleaned) {
        for (t, &th) in thresholds.iter().enumerate() {
            let s = compute_statistics(&g.objects, &d.objects, c, true, m, min, aos, th);
            out.tp[t] += s.tp;
            out.fp[t] += s.fp;
            out.fn_[t] += s.fn_;
            out.similarity[t] += s.similarity;
        }
    }
    out
}

#[test]
fn optimised_engine_makes_the_devkits_decisions() {
    let classes = ObjectClass::EVALUATED;
    for seed in [1, 2, 3] {
        let (gt, det) = synthetic::generate(150, seed);
        let prepared = engine::prepare(&gt, &det, &classes).unwrap();
        let mut tasks = vec![];
        for (ci, &class) in classes.iter().enumerate() {
            for setting in [OverlapSetting::STRICT, OverlapSetting::LOOSE] {
                for (m, metric) in crate::Metric::OVERLAPS.into_iter().enumerate() {
                    tasks.push(Task {
                        class_idx: ci,
                        overlap: m,
                        min_overlap: setting.min_overlap(class, metric).unwrap(),
                    });
                }
            }
        }
        let fast = engine::run(&prepared, &tasks, None, true);
        for (task, counts) in tasks.iter().zip(&fast) {
            for diff in Difficulty::ALL {
                let slow = eval_class(
                    &gt,
                    &det,
                    classes[task.class_idx],
                    diff,
                    task.overlap,
                    task.min_overlap,
                );
                let ours = &counts[diff.index()];
                let what = format!("seed {seed} {task:?} {diff:?}");
                assert!(
                    !slow.thresholds.is_empty(),
                    "{what}: the data set exercises nothing"
                );
                assert_eq!(ours.n_gt, slow.n_gt, "{what}");
                assert_eq!(ours.thresholds, slow.thresholds, "{what}");
                assert_eq!(
                    (&ours.tp, &ours.fp, &ours.fn_),
                    (&slow.tp, &slow.fp, &slow.fn_),
                    "{what}"
                );
                if task.overlap == 0 {
                    for (a, b) in ours.similarity.iter().zip(&slow.similarity) {
                        assert!((a - b).abs() < 1e-9, "{what}: {a} vs {b}");
                    }
                }
            }
        }
    }
}
