//! Greedy non-maximum suppression in 2D, bird's-eye view and 3D.

use crate::boxes::{Box2d, Box3d};
use crate::iou::{iou_2d, iou_3d, iou_bev};

/// Greedy NMS: visits items by descending score and keeps one unless it overlaps a
/// kept item by more than `threshold`. Returns kept indices, best first. Ties in
/// score keep the input order, so the result is deterministic.
pub fn nms_by<T>(
    items: &[T],
    scores: &[f64],
    threshold: f64,
    overlap: impl Fn(&T, &T) -> f64,
) -> Vec<usize> {
    assert_eq!(items.len(), scores.len(), "one score per item");
    let mut order: Vec<usize> = (0..items.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    let mut keep: Vec<usize> = Vec::new();
    for i in order {
        if keep
            .iter()
            .all(|&k| overlap(&items[k], &items[i]) <= threshold)
        {
            keep.push(i);
        }
    }
    keep
}

pub fn nms_2d(boxes: &[Box2d], scores: &[f64], threshold: f64) -> Vec<usize> {
    nms_by(boxes, scores, threshold, iou_2d)
}

pub fn nms_bev(boxes: &[Box3d], scores: &[f64], threshold: f64) -> Vec<usize> {
    nms_by(boxes, scores, threshold, iou_bev)
}

pub fn nms_3d(boxes: &[Box3d], scores: &[f64], threshold: f64) -> Vec<usize> {
    nms_by(boxes, scores, threshold, iou_3d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suppresses_overlaps_and_keeps_separate_boxes() {
        let b = |x: f64| Box3d {
            h: 1.5,
            w: 1.6,
            l: 3.9,
            x,
            y: 1.0,
            z: 20.0,
            ry: 0.0,
        };
        let boxes = [b(0.0), b(0.2), b(10.0)];
        let keep = nms_3d(&boxes, &[0.5, 0.9, 0.4], 0.1);
        assert_eq!(keep, [1, 2]);
        assert_eq!(nms_bev(&boxes, &[0.5, 0.9, 0.4], 0.99), [1, 0, 2]);
    }

    #[test]
    fn nms_2d_keeps_best_first() {
        let a = Box2d {
            x1: 0.0,
            y1: 0.0,
            x2: 10.0,
            y2: 10.0,
        };
        let b = Box2d {
            x1: 1.0,
            y1: 0.0,
            x2: 11.0,
            y2: 10.0,
        };
        assert_eq!(nms_2d(&[a, b], &[0.2, 0.3], 0.5), [1]);
        assert!(nms_2d(&[], &[], 0.5).is_empty());
    }
}
