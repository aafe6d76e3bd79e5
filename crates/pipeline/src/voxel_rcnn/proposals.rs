//! From per-anchor predictions to boxes: the best class per anchor, the top scores,
//! decoded with the residual coder and the direction bin, then rotated bird's-eye NMS.
//! Used for stage one's proposals and, with the RoI head's scores, for the final boxes.

use super::config::NmsConfig;
use fusiondet_kitti::ObjectClass;
use fusiondet_nn::place::Place;
use fusiondet_voxel::{Anchors, DirectionBins, LidarBox, Proposal, decode, iou_bev};

fn sigmoid(x: f32) -> f64 {
    1.0 / (1.0 + (-(x as f64)).exp())
}

/// Indices of the `max` highest scores, best first (ties: lower index first).
pub fn top_k(scores: &[f64], max: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    let by_score = |a: &usize, b: &usize| scores[*b].total_cmp(&scores[*a]).then(a.cmp(b));
    if order.len() > max {
        order.select_nth_unstable_by(max, by_score);
        order.truncate(max);
    }
    order.sort_by(by_score);
    order
}

/// Greedy rotated-BEV NMS over boxes already sorted best first: keeps a box unless it
/// overlaps a kept one by more than `iou`, until `max_keep` are kept. An axis-aligned
/// bound check skips the exact polygon overlap for the many pairs far apart.
pub fn nms_sorted(boxes: &[LidarBox], iou: f64, max_keep: usize) -> Vec<usize> {
    let bounds: Vec<[f64; 4]> = boxes
        .iter()
        .map(|b| {
            let c = b.bev_corners();
            let xs = c.map(|p| p[0]);
            let ys = c.map(|p| p[1]);
            [
                xs.iter().copied().fold(f64::INFINITY, f64::min),
                ys.iter().copied().fold(f64::INFINITY, f64::min),
                xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            ]
        })
        .collect();
    let mut keep: Vec<usize> = Vec::new();
    for i in 0..boxes.len() {
        if keep.len() >= max_keep {
            break;
        }
        let bi = bounds[i];
        let suppressed = keep.iter().any(|&k| {
            let bk = bounds[k];
            let apart = bi[0] >= bk[2] || bk[0] >= bi[2] || bi[1] >= bk[3] || bk[1] >= bi[3];
            !apart && iou_bev(&boxes[k], &boxes[i]) > iou
        });
        if !suppressed {
            keep.push(i);
        }
    }
    keep
}

/// An anchor's best class (the first of equal logits) and its score.
pub fn best_class(logits: &[f32]) -> (usize, f64) {
    let (c, &logit) = logits
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
        .expect("at least one class");
    (c, sigmoid(logit))
}

/// The box an anchor's residual `code` (7 values) and direction logits stand for.
pub fn decode_anchor(
    anchor: &LidarBox,
    code: &[f32],
    dir: &[f32],
    bins: &DirectionBins,
) -> LidarBox {
    let code: [f64; 7] = std::array::from_fn(|j| code[j] as f64);
    let mut b = decode(&code, anchor);
    let bin = (0..bins.bins)
        .max_by(|&a, &c| dir[a].total_cmp(&dir[c]).then(c.cmp(&a)))
        .unwrap_or(0);
    b.heading = bins.apply(b.heading, bin);
    b
}

/// Stage one's boxes of one frame: `cls` [anchors × classes] logits, `boxes` [anchors × 7]
/// residuals, `dir` [anchors × bins] logits, all in anchor order.
pub fn decode_proposals(
    anchors: &Anchors,
    classes: &[ObjectClass],
    bins: &DirectionBins,
    cls: &[f32],
    boxes: &[f32],
    dir: &[f32],
    nms: &NmsConfig,
) -> Vec<Proposal> {
    let k = classes.len();
    let nb = bins.bins;
    let n = anchors.len();
    let (best, scores): (Vec<usize>, Vec<f64>) =
        (0..n).map(|i| best_class(&cls[i * k..(i + 1) * k])).unzip();
    let order = top_k(&scores, nms.pre_max);
    let decoded: Vec<LidarBox> = order
        .iter()
        .map(|&i| {
            decode_anchor(
                &anchors.boxes[i],
                &boxes[i * 7..(i + 1) * 7],
                &dir[i * nb..(i + 1) * nb],
                bins,
            )
        })
        .collect();
    nms_sorted(&decoded, nms.iou, nms.post_max)
        .into_iter()
        .map(|j| Proposal {
            bbox: decoded[j],
            score: scores[order[j]],
            class: classes[best[order[j]]],
        })
        .collect()
}

/// Proposals of anchors kept elsewhere (the device's NMS), in their order: each anchor
/// with its prediction row, class logits then the 7 residuals then the direction logits,
/// decoded as [`decode_proposals`] decodes (the same values for the same anchor).
pub fn proposals_of_rows<'a>(
    anchors: &Anchors,
    classes: &[ObjectClass],
    bins: &DirectionBins,
    kept: impl IntoIterator<Item = (usize, &'a [f32])>,
) -> Vec<Proposal> {
    let k = classes.len();
    kept.into_iter()
        .map(|(anchor, row)| {
            let (class, score) = best_class(&row[..k]);
            Proposal {
                bbox: decode_anchor(&anchors.boxes[anchor], &row[k..k + 7], &row[k + 7..], bins),
                score,
                class: classes[class],
            }
        })
        .collect()
}

/// Where stage one's proposals are chosen: decoded, ranked and suppressed on the host from
/// every anchor's predictions read back; on a GPU backend's device with only the kept
/// anchors' rows read back (`fusiondet_models::voxel_rcnn::proposals_device`); or both, the
/// host's used and each frame's differences reported on stderr.
pub type ProposalPlace = Place;

/// Where stage one's proposals are chosen on `device`: the host on the CPU; on a CubeCL
/// device `FUSIONDET_PROPOSALS` (`host`, `device` or `check`) where set, else the device.
pub fn proposal_place(device: &burn::prelude::Device) -> ProposalPlace {
    static READ: std::sync::OnceLock<Option<Place>> = std::sync::OnceLock::new();
    Place::for_device(device, "FUSIONDET_PROPOSALS", &READ)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car(x: f64, y: f64, heading: f64) -> LidarBox {
        LidarBox {
            x,
            y,
            z: -1.0,
            dx: 4.0,
            dy: 2.0,
            dz: 1.5,
            heading,
        }
    }

    #[test]
    fn top_k_is_ordered_and_stable() {
        assert_eq!(top_k(&[0.1, 0.9, 0.5, 0.9, 0.2], 3), vec![1, 3, 2]);
        assert_eq!(top_k(&[0.3, 0.1], 5), vec![0, 1]);
    }

    #[test]
    fn nms_suppresses_overlaps_only_and_caps_the_count() {
        // 0 and 1 overlap by IoU 3/5 (shifted 1 m along a 4 m box); 2 is far; 3 crosses 0.
        let boxes = [
            car(0.0, 0.0, 0.0),
            car(1.0, 0.0, 0.0),
            car(20.0, 0.0, 0.0),
            car(0.0, 0.0, 1.2),
        ];
        assert_eq!(nms_sorted(&boxes, 0.5, 10), vec![0, 2, 3]);
        assert_eq!(nms_sorted(&boxes, 0.7, 10), vec![0, 1, 2, 3]);
        assert_eq!(nms_sorted(&boxes, 0.7, 2), vec![0, 1]);
        // Crossing boxes overlap (IoU about 0.37) though their bounds are not apart.
        assert_eq!(nms_sorted(&[boxes[0], boxes[3]], 0.3, 10), vec![0]);
        assert_eq!(nms_sorted(&[boxes[0], boxes[3]], 0.4, 10), vec![0, 1]);
    }
}
