//! Matching and average precision, class by class, as VoteNet's `eval_det.py` does them
//! (module docs of [`crate::indoor`] for the rules and where we differ).

use super::iou::iou_3d;
use fusiondet_sunrgbd::{Object, SunClass, UprightBox};
use rayon::prelude::*;

/// The IoU thresholds indoor papers report (AP@0.25, AP@0.5).
pub const IOU_THRESHOLDS: [f64; 2] = [0.25, 0.5];

/// One scene's ground truth and detections. Objects of other classes than the ten are
/// ignored; every detection needs its score.
#[derive(Debug, Clone, PartialEq)]
pub struct IndoorScene {
    pub id: String,
    pub gt: Vec<Object>,
    pub det: Vec<Object>,
}

/// A detection without a score, which cannot be ranked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("scene `{scene}`: detection {index} has no score (result lines end with it, 13 fields)")]
pub struct MissingScore {
    pub scene: String,
    /// 0-based position among the scene's detections.
    pub index: usize,
}

/// The result of one class at one IoU threshold.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassResult {
    pub class: SunClass,
    pub iou: f64,
    /// Ground-truth boxes of the class over all scenes (the recall denominator).
    pub n_gt: usize,
    pub n_det: usize,
    /// Average precision in percent; `None` when the class has no ground truth.
    pub ap: Option<f64>,
    /// Recall and precision after each detection, in ranked order (VoteNet's `rec`, `prec`;
    /// recall 0 without ground truth, where VoteNet divides by 0).
    pub recall: Vec<f64>,
    pub precision: Vec<f64>,
}

/// Every class at every threshold, threshold by threshold in [`SunClass::ALL`] order.
#[derive(Debug, Clone, PartialEq)]
pub struct IndoorReport {
    pub scenes: usize,
    pub thresholds: Vec<f64>,
    pub results: Vec<ClassResult>,
}

impl IndoorReport {
    pub fn get(&self, class: SunClass, iou: f64) -> Option<&ClassResult> {
        self.results
            .iter()
            .find(|r| r.class == class && r.iou == iou)
    }

    /// The mean AP (percent) at `iou` over the classes with ground truth; `None` if none has.
    pub fn map(&self, iou: f64) -> Option<f64> {
        let aps: Vec<f64> = self
            .results
            .iter()
            .filter(|r| r.iou == iou)
            .filter_map(|r| r.ap)
            .collect();
        (!aps.is_empty()).then(|| aps.iter().sum::<f64>() / aps.len() as f64)
    }
}

/// Area under the precision envelope (VOC's all-points AP, as a fraction): recall runs from
/// 0 to 1 with precision 0 appended, precision is made non-increasing from the right, and
/// each rise in recall counts at the envelope's value after it.
pub fn voc_ap(recall: &[f64], precision: &[f64]) -> f64 {
    let mrec: Vec<f64> = std::iter::once(0.0)
        .chain(recall.iter().copied())
        .chain(std::iter::once(1.0))
        .collect();
    let mut mpre: Vec<f64> = std::iter::once(0.0)
        .chain(precision.iter().copied())
        .chain(std::iter::once(0.0))
        .collect();
    for i in (1..mpre.len()).rev() {
        mpre[i - 1] = mpre[i - 1].max(mpre[i]);
    }
    (0..mrec.len() - 1)
        .filter(|&i| mrec[i + 1] != mrec[i])
        .map(|i| (mrec[i + 1] - mrec[i]) * mpre[i + 1])
        .sum()
}

/// Evaluates every class of [`SunClass::ALL`] at each of `thresholds`.
pub fn evaluate_indoor(
    scenes: &[IndoorScene],
    thresholds: &[f64],
) -> Result<IndoorReport, MissingScore> {
    for scene in scenes {
        if let Some(index) = scene.det.iter().position(|d| d.score.is_none()) {
            return Err(MissingScore {
                scene: scene.id.clone(),
                index,
            });
        }
    }
    let per_class: Vec<Vec<ClassResult>> = SunClass::ALL
        .iter()
        .map(|&class| evaluate_class(scenes, class, thresholds))
        .collect();
    let results = (0..thresholds.len())
        .flat_map(|t| per_class.iter().map(move |rows| rows[t].clone()))
        .collect();
    Ok(IndoorReport {
        scenes: scenes.len(),
        thresholds: thresholds.to_vec(),
        results,
    })
}

/// One class at every threshold.
fn evaluate_class(scenes: &[IndoorScene], class: SunClass, thresholds: &[f64]) -> Vec<ClassResult> {
    let of_class = |o: &&Object| o.sun_class() == Some(class);
    let gt: Vec<Vec<&UprightBox>> = scenes
        .iter()
        .map(|s| s.gt.iter().filter(of_class).map(|o| &o.box3d).collect())
        .collect();
    let n_gt: usize = gt.iter().map(Vec::len).sum();
    // Scene order, then file order; the sort is stable, so equal scores keep that order.
    let mut dets: Vec<(usize, &UprightBox, f64)> = scenes
        .iter()
        .enumerate()
        .flat_map(|(s, scene)| {
            scene
                .det
                .iter()
                .filter(of_class)
                .map(move |o| (s, &o.box3d, o.score.expect("checked above")))
        })
        .collect();
    dets.sort_by(|a, b| b.2.total_cmp(&a.2));
    // Each detection's best ground-truth box in its scene, over all of them, matched or not:
    // the first of equal IoUs. It does not depend on the threshold.
    let best: Vec<Option<(usize, f64)>> = dets
        .par_iter()
        .map(|&(s, det, _)| {
            let mut best: Option<(usize, f64)> = None;
            for (j, g) in gt[s].iter().enumerate() {
                let iou = iou_3d(det, g);
                if best.is_none_or(|(_, b)| iou > b) {
                    best = Some((j, iou));
                }
            }
            best
        })
        .collect();
    thresholds
        .iter()
        .map(|&threshold| {
            let mut matched: Vec<Vec<bool>> = gt.iter().map(|g| vec![false; g.len()]).collect();
            let (mut tp, mut fp) = (0.0, 0.0);
            let mut recall = Vec::with_capacity(dets.len());
            let mut precision = Vec::with_capacity(dets.len());
            for (&(s, _, _), best) in dets.iter().zip(&best) {
                match best {
                    Some((j, iou)) if *iou > threshold && !matched[s][*j] => {
                        matched[s][*j] = true;
                        tp += 1.0;
                    }
                    // Below the threshold, or its best box is taken: a duplicate.
                    _ => fp += 1.0,
                }
                recall.push(if n_gt > 0 { tp / n_gt as f64 } else { 0.0 });
                precision.push(tp / f64::max(tp + fp, f64::EPSILON));
            }
            let ap = (n_gt > 0).then(|| 100.0 * voc_ap(&recall, &precision));
            ClassResult {
                class,
                iou: threshold,
                n_gt,
                n_det: dets.len(),
                ap,
                recall,
                precision,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_geometry::Box2d;
    use std::f64::consts::PI;

    fn obj(class: &str, centre: [f64; 3], size: [f64; 3], yaw: f64, score: Option<f64>) -> Object {
        Object {
            class: class.into(),
            box3d: UprightBox { centre, size, yaw },
            bbox: Box2d::default(),
            score,
        }
    }

    fn gt(class: &str, x: f64) -> Object {
        obj(class, [x, 3.0, 0.0], [2.0, 2.0, 2.0], 0.4, None)
    }

    fn det(class: &str, x: f64, score: f64) -> Object {
        Object {
            score: Some(score),
            ..gt(class, x)
        }
    }

    fn scene(id: &str, gt: Vec<Object>, det: Vec<Object>) -> IndoorScene {
        IndoorScene {
            id: id.into(),
            gt,
            det,
        }
    }

    fn eval(scenes: &[IndoorScene]) -> IndoorReport {
        evaluate_indoor(scenes, &IOU_THRESHOLDS).unwrap()
    }

    fn ap(r: &IndoorReport, class: SunClass, iou: f64) -> Option<f64> {
        r.get(class, iou).unwrap().ap
    }

    fn close(a: Option<f64>, b: f64) -> bool {
        a.is_some_and(|a| (a - b).abs() < 1e-9)
    }

    #[test]
    fn the_envelope_area_by_hand() {
        // Recall 0.5 at precision 1, then 0.5 more at the envelope's 2/3.
        let ap = voc_ap(&[0.5, 0.5, 1.0], &[1.0, 0.5, 2.0 / 3.0]);
        assert!((ap - (0.5 + 0.5 * 2.0 / 3.0)).abs() < 1e-15);
        // Recall never reaching 1: the rest counts at precision 0.
        assert_eq!(voc_ap(&[0.25], &[1.0]), 0.25);
        assert_eq!(voc_ap(&[], &[]), 0.0);
    }

    #[test]
    fn one_box_found_exactly() {
        let r = eval(&[scene("1", vec![gt("bed", 0.0)], vec![det("bed", 0.0, 0.9)])]);
        for t in IOU_THRESHOLDS {
            assert_eq!(ap(&r, SunClass::Bed, t), Some(100.0));
            assert_eq!(r.map(t), Some(100.0));
            assert_eq!(ap(&r, SunClass::Chair, t), None);
        }
        assert_eq!(r.results.len(), 20);
        assert_eq!(r.results[10].class, SunClass::Bed);
        assert_eq!(r.results[10].iou, 0.5);
    }

    #[test]
    fn a_duplicate_is_a_false_positive() {
        // Two beds; the first is found twice, the second once, ranked 0.9, 0.8, 0.7:
        // precision 1, 1/2, 2/3 at recall 1/2, 1/2, 1 → AP = 1/2 + 1/2 · 2/3.
        let r = eval(&[scene(
            "1",
            vec![gt("bed", 0.0), gt("bed", 10.0)],
            vec![
                det("bed", 10.0, 0.7),
                det("bed", 0.0, 0.9),
                det("bed", 0.0, 0.8),
            ],
        )]);
        let expected = 100.0 * (0.5 + 0.5 * 2.0 / 3.0);
        assert!(close(ap(&r, SunClass::Bed, 0.25), expected));
        let row = r.get(SunClass::Bed, 0.5).unwrap();
        assert_eq!(row.recall, [0.5, 0.5, 1.0]);
        assert_eq!(row.precision, [1.0, 0.5, 2.0 / 3.0]);
    }

    #[test]
    fn a_wrong_class_finds_nothing() {
        let r = eval(&[scene(
            "1",
            vec![gt("bed", 0.0)],
            vec![det("table", 0.0, 0.9)],
        )]);
        assert_eq!(ap(&r, SunClass::Bed, 0.25), Some(0.0));
        // The table has detections but no ground truth: no AP, and not in the mean
        // (VoteNet's would be NaN, and its mean with it).
        assert_eq!(ap(&r, SunClass::Table, 0.25), None);
        assert_eq!(r.get(SunClass::Table, 0.25).unwrap().n_det, 1);
        assert_eq!(r.map(0.25), Some(0.0));
    }

    #[test]
    fn a_flipped_heading_is_the_same_box() {
        let mut flipped = det("bed", 0.0, 0.9);
        flipped.box3d.yaw += PI;
        let r = eval(&[scene("1", vec![gt("bed", 0.0)], vec![flipped])]);
        assert_eq!(ap(&r, SunClass::Bed, 0.5), Some(100.0));
    }

    #[test]
    fn a_third_overlap_counts_at_one_threshold_only() {
        // Shifted by half its side along its own x axis: IoU 1/3.
        let g = gt("sofa", 0.0);
        let (s, c) = g.box3d.yaw.sin_cos();
        let mut d = det("sofa", 0.0, 0.3);
        d.box3d.centre[0] += c;
        d.box3d.centre[1] += s;
        let r = eval(&[scene("1", vec![g], vec![d])]);
        assert_eq!(ap(&r, SunClass::Sofa, 0.25), Some(100.0));
        assert_eq!(ap(&r, SunClass::Sofa, 0.5), Some(0.0));
        assert_eq!(r.map(0.5), Some(0.0));
    }

    #[test]
    fn other_class_names_are_ignored() {
        let r = eval(&[scene(
            "1",
            vec![gt("lamp", 0.0), gt("chair", 5.0)],
            vec![det("lamp", 0.0, 0.99), det("chair", 5.0, 0.5)],
        )]);
        assert_eq!(ap(&r, SunClass::Chair, 0.25), Some(100.0));
        assert_eq!(r.map(0.25), Some(100.0));
        assert!(
            r.results
                .iter()
                .all(|row| row.class == SunClass::Chair || row.n_det == 0)
        );
    }

    #[test]
    fn the_best_box_taken_makes_a_duplicate() {
        // Boxes A (x = 0) and B (x = 1.2) overlap. The second detection (x = 0.5) overlaps A
        // by 0.6 and B by 0.48: its best box A is taken, so it is a false positive although
        // B is free and above 0.25 (VOC's and VoteNet's rule).
        let a = obj("desk", [0.0, 0.0, 0.0], [2.0, 2.0, 2.0], 0.0, None);
        let b = obj("desk", [1.2, 0.0, 0.0], [2.0, 2.0, 2.0], 0.0, None);
        let d1 = Object {
            score: Some(0.9),
            ..a.clone()
        };
        let d2 = obj("desk", [0.5, 0.0, 0.0], [2.0, 2.0, 2.0], 0.0, Some(0.8));
        let r = eval(&[scene("1", vec![a, b], vec![d1, d2])]);
        assert_eq!(ap(&r, SunClass::Desk, 0.25), Some(50.0));
    }

    #[test]
    fn equal_scores_keep_scene_then_file_order() {
        // Scene 1's detection misses, scene 2's hits, both scored 0.5.
        let miss = scene("1", vec![], vec![det("toilet", 0.0, 0.5)]);
        let hit = scene("2", vec![gt("toilet", 0.0)], vec![det("toilet", 0.0, 0.5)]);
        // Miss first: precision 0 then 1/2 at recall 1 → AP 50; hit first → AP 100.
        let r = eval(&[miss.clone(), hit.clone()]);
        assert_eq!(ap(&r, SunClass::Toilet, 0.25), Some(50.0));
        let r = eval(&[hit.clone(), miss.clone()]);
        assert_eq!(ap(&r, SunClass::Toilet, 0.25), Some(100.0));
        // Within a scene, file order.
        let mut both = hit.clone();
        both.det.insert(0, det("toilet", 20.0, 0.5));
        assert_eq!(
            ap(&eval(&[both.clone()]), SunClass::Toilet, 0.25),
            Some(50.0)
        );
        both.det.swap(0, 1);
        assert_eq!(ap(&eval(&[both]), SunClass::Toilet, 0.25), Some(100.0));
    }

    #[test]
    fn no_ground_truth_at_all_has_no_mean() {
        let r = eval(&[scene("1", vec![], vec![])]);
        assert!(r.results.iter().all(|row| row.ap.is_none()));
        assert_eq!(r.map(0.25), None);
    }

    #[test]
    fn a_detection_without_score_is_refused() {
        let mut d = det("bed", 0.0, 0.9);
        d.score = None;
        let err = evaluate_indoor(
            &[scene("000005", vec![], vec![det("bed", 0.0, 0.9), d])],
            &IOU_THRESHOLDS,
        )
        .unwrap_err();
        assert_eq!(
            err,
            MissingScore {
                scene: "000005".into(),
                index: 1
            }
        );
    }
}
