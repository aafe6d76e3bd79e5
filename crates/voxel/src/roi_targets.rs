//! The second stage's training RoIs and targets (OpenPCDet's `ProposalTargetLayer` and
//! the canonical transformation of its `RoIHeadTemplate.assign_targets`).
//!
//! Each proposal is matched to the ground truth of its class with the highest 3D IoU.
//! `rois_per_frame` RoIs are then sampled: up to `fg_fraction` of them foreground
//! (IoU ≥ min(`reg_fg_iou`, `cls_fg_iou`), drawn without repetition), the rest
//! background, `hard_bg_fraction` of it "hard" (IoU in [`hard_bg_min_iou`, `reg_fg_iou`))
//! and the remainder "easy" (below), both drawn with repetition. When a frame has
//! only foreground, or only background, all RoIs come from what there is.
//!
//! Targets per RoI:
//! - classification: the IoU mapped to 0 below `cls_bg_iou`, 1 above `cls_fg_iou`,
//!   linear in between (`CLS_SCORE_TYPE: roi_iou`);
//! - regression (valid when IoU > `reg_fg_iou`): the ground truth in the RoI's frame
//!   (centre offset rotated by −heading, heading difference folded into [−π/2, π/2]
//!   by turning it by π when the two face apart: a box is the same box reversed),
//!   encoded with the residual coder against the RoI's size at the origin;
//! - the ground truth itself in the LiDAR frame, for the corner loss.

use crate::boxes::{GtBox, LidarBox, iou_3d, rotate_z};
use crate::coder::{CODE_SIZE, decode, encode};
use crate::config::RoiTargetConfig;
use crate::error::{Result, VoxelError};
use fusiondet_dataset::rng::Sampler;
use fusiondet_kitti::ObjectClass;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// A first-stage box: what the RoI head refines.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Proposal {
    pub bbox: LidarBox,
    pub score: f64,
    pub class: ObjectClass,
}

/// The sampled RoIs of one frame and their targets, fg first, then hard and easy bg.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RoiTargets {
    /// Which proposal each RoI is (a proposal may be drawn more than once).
    pub proposal: Vec<usize>,
    pub rois: Vec<LidarBox>,
    pub scores: Vec<f64>,
    pub classes: Vec<ObjectClass>,
    /// 3D IoU with the matched ground truth (0 when none).
    pub ious: Vec<f64>,
    /// The matched ground truth (index into the input), `None` when the frame has no
    /// ground truth of the RoI's class.
    pub gt_index: Vec<Option<usize>>,
    /// The matched ground truth in the LiDAR frame (zeros when none): the corner loss.
    pub gt_boxes: Vec<LidarBox>,
    /// The matched ground truth in the RoI's frame, heading folded (zeros when none).
    pub canonical_gt: Vec<LidarBox>,
    /// Classification target in [0, 1].
    pub cls_targets: Vec<f32>,
    /// Whether the RoI regresses (IoU > `reg_fg_iou`).
    pub reg_valid: Vec<bool>,
    /// The residual code of `canonical_gt` (zeros when none).
    pub reg_targets: Vec<[f32; CODE_SIZE]>,
    /// RoIs sampled as foreground (the first `num_fg`).
    pub num_fg: usize,
}

impl RoiTargets {
    pub fn len(&self) -> usize {
        self.rois.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rois.is_empty()
    }
}

/// The ground truth in the frame of `roi`: centre relative to the RoI's, rotated by
/// −heading; heading relative, turned by π when it points more than π/2 away, so it
/// lies in [−π/2, π/2]. Sizes unchanged.
pub fn canonical_gt(roi: &LidarBox, gt: &LidarBox) -> LidarBox {
    let roi_heading = roi.heading.rem_euclid(TAU);
    let [x, y] = rotate_z([gt.x - roi.x, gt.y - roi.y], -roi_heading);
    let mut h = (gt.heading - roi_heading).rem_euclid(TAU);
    if h > FRAC_PI_2 && h < 1.5 * PI {
        h = (h + PI).rem_euclid(TAU);
    }
    if h > PI {
        h -= TAU;
    }
    LidarBox {
        x,
        y,
        z: gt.z - roi.z,
        heading: h.clamp(-FRAC_PI_2, FRAC_PI_2),
        ..*gt
    }
}

/// The regression target of `gt` for `roi`: its canonical box encoded against the
/// RoI's size at the origin with heading 0.
pub fn roi_reg_target(roi: &LidarBox, gt: &LidarBox) -> [f64; CODE_SIZE] {
    let reference = LidarBox {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        heading: 0.0,
        ..*roi
    };
    encode(&canonical_gt(roi, gt), &reference)
}

/// The box an RoI-head output stands for: decoded against the RoI's size and heading
/// at the origin, rotated by the heading and moved to the RoI's centre.
pub fn decode_roi(code: &[f64; CODE_SIZE], roi: &LidarBox) -> LidarBox {
    let local = decode(
        code,
        &LidarBox {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            ..*roi
        },
    );
    let [x, y] = rotate_z([local.x, local.y], roi.heading);
    LidarBox {
        x: x + roi.x,
        y: y + roi.y,
        z: local.z + roi.z,
        ..local
    }
}

/// Samples the training RoIs of one frame from its proposals and ground truth.
/// Fails only when there is no proposal at all.
pub fn sample_rois(
    proposals: &[Proposal],
    gts: &[GtBox],
    config: &RoiTargetConfig,
    sampler: &mut Sampler,
) -> Result<RoiTargets> {
    if proposals.is_empty() {
        return Err(VoxelError::Input(
            "RoI sampling needs at least one proposal; the first stage gave none".into(),
        ));
    }
    // Best 3D IoU and its first ground truth per proposal.
    let matches: Vec<(f64, Option<usize>)> = proposals
        .iter()
        .map(|p| {
            let mut best = (0.0, None);
            for (j, g) in gts.iter().enumerate() {
                if config.sample_by_class && g.class != p.class {
                    continue;
                }
                let iou = iou_3d(&p.bbox, &g.bbox);
                if best.1.is_none() || iou > best.0 {
                    best = (iou, Some(j));
                }
            }
            best
        })
        .collect();
    let by = |keep: &dyn Fn(f64) -> bool| -> Vec<usize> {
        (0..proposals.len())
            .filter(|&i| keep(matches[i].0))
            .collect()
    };
    let fg_iou = config.fg_iou();
    let mut fg = by(&|iou| iou >= fg_iou);
    let easy = by(&|iou| iou < config.hard_bg_min_iou);
    let hard = by(&|iou| iou >= config.hard_bg_min_iou && iou < config.reg_fg_iou);
    let total = config.rois_per_frame;
    let fg_wanted = (config.fg_fraction * total as f64).round() as usize;

    let with_repetition = |from: &[usize], count: usize, s: &mut Sampler| -> Vec<usize> {
        (0..count).map(|_| from[s.below(from.len())]).collect()
    };
    let background = |count: usize, s: &mut Sampler| -> Vec<usize> {
        match (hard.is_empty(), easy.is_empty()) {
            (false, false) => {
                let n_hard = ((count as f64 * config.hard_bg_fraction) as usize).min(hard.len());
                let mut out = with_repetition(&hard, n_hard, s);
                out.extend(with_repetition(&easy, count - n_hard, s));
                out
            }
            (false, true) => with_repetition(&hard, count, s),
            (true, false) => with_repetition(&easy, count, s),
            (true, true) => Vec::new(),
        }
    };
    let has_bg = !(hard.is_empty() && easy.is_empty());
    let (chosen_fg, chosen_bg) = if !fg.is_empty() && has_bg {
        sampler.shuffle(&mut fg);
        fg.truncate(fg_wanted.min(fg.len()));
        let bg = background(total - fg.len(), sampler);
        (fg, bg)
    } else if !fg.is_empty() {
        (with_repetition(&fg, total, sampler), Vec::new())
    } else {
        (Vec::new(), background(total, sampler))
    };

    let mut out = RoiTargets {
        num_fg: chosen_fg.len(),
        ..RoiTargets::default()
    };
    for i in chosen_fg.into_iter().chain(chosen_bg) {
        let p = &proposals[i];
        let (iou, gt_index) = matches[i];
        let gt = gt_index.map(|j| gts[j].bbox);
        out.proposal.push(i);
        out.rois.push(p.bbox);
        out.scores.push(p.score);
        out.classes.push(p.class);
        out.ious.push(iou);
        out.gt_index.push(gt_index);
        out.gt_boxes.push(gt.unwrap_or_default());
        out.canonical_gt
            .push(gt.map_or(LidarBox::default(), |g| canonical_gt(&p.bbox, &g)));
        out.reg_targets.push(gt.map_or([0.0; CODE_SIZE], |g| {
            roi_reg_target(&p.bbox, &g).map(|v| v as f32)
        }));
        out.reg_valid.push(iou > config.reg_fg_iou);
        let cls = if iou > config.cls_fg_iou {
            1.0
        } else if iou < config.cls_bg_iou {
            0.0
        } else {
            (iou - config.cls_bg_iou) / (config.cls_fg_iou - config.cls_bg_iou)
        };
        out.cls_targets.push(cls as f32);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boxes::limit_period;

    fn car_at(x: f64) -> LidarBox {
        LidarBox {
            x,
            y: 0.0,
            z: -1.0,
            dx: 4.0,
            dy: 2.0,
            dz: 1.5,
            heading: 0.0,
        }
    }

    fn proposal(bbox: LidarBox, class: ObjectClass) -> Proposal {
        Proposal {
            bbox,
            score: 0.5,
            class,
        }
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    /// One car at x = 10; proposals shifted along its length by δ overlap it by
    /// (4 − δ) / (4 + δ).
    fn scene() -> (Vec<Proposal>, Vec<GtBox>) {
        let car = ObjectClass::Car;
        let mut p: Vec<Proposal> = [0.0, 0.5, 1.0, 2.0, 3.0, 3.5, 30.0]
            .iter()
            .map(|d| proposal(car_at(10.0 + d), car))
            .collect();
        // A pedestrian proposal on the car: another class, so IoU 0.
        p.push(proposal(car_at(10.0), ObjectClass::Pedestrian));
        (
            p,
            vec![GtBox {
                bbox: car_at(10.0),
                class: car,
            }],
        )
    }

    #[test]
    fn sampling_by_hand() {
        let (props, gts) = scene();
        let config = RoiTargetConfig {
            rois_per_frame: 8,
            ..Default::default()
        };
        let t = sample_rois(&props, &gts, &config, &mut Sampler::new(5)).unwrap();
        assert_eq!(t.len(), 8);
        // 4 foreground wanted, 3 exist (IoU 1, 7/9, 3/5): each drawn once.
        assert_eq!(t.num_fg, 3);
        let mut fg = t.proposal[..3].to_vec();
        fg.sort();
        assert_eq!(fg, [0, 1, 2]);
        // 5 background: min(⌊5 · 0.8⌋, 2 hard) = 2 hard (IoU 1/3, 1/7), 3 easy.
        assert!(t.proposal[3..5].iter().all(|i| [3, 4].contains(i)));
        assert!(t.proposal[5..].iter().all(|i| [5, 6, 7].contains(i)));
        for k in 0..8 {
            let i = t.proposal[k];
            let iou = [
                1.0,
                3.5 / 4.5,
                0.6,
                2.0 / 6.0,
                1.0 / 7.0,
                0.5 / 7.5,
                0.0,
                0.0,
            ][i];
            assert!(close(t.ious[k], iou), "{i}: {} vs {iou}", t.ious[k]);
            let cls = [1.0, 1.0, 0.7, (2.0 / 6.0 - 0.25) / 0.5, 0.0, 0.0, 0.0, 0.0][i];
            assert!((t.cls_targets[k] as f64 - cls).abs() < 1e-6, "{i}");
            assert_eq!(t.reg_valid[k], i < 3);
            assert_eq!(t.gt_index[k], if i == 7 { None } else { Some(0) });
        }
        // Regression of the proposal 0.5 m ahead: Δx −0.5 over the diagonal √20.
        let k = t.proposal.iter().position(|&i| i == 1).unwrap();
        assert!((t.reg_targets[k][0] as f64 + 0.5 / 20f64.sqrt()).abs() < 1e-6);
        assert_eq!(t.gt_boxes[k], car_at(10.0));
        // The same seed samples the same RoIs; a frame's draw depends on nothing else.
        let again = sample_rois(&props, &gts, &config, &mut Sampler::new(5)).unwrap();
        assert_eq!(again, t);
    }

    #[test]
    fn one_sided_frames_fill_from_what_there_is() {
        let (props, gts) = scene();
        let config = RoiTargetConfig {
            rois_per_frame: 6,
            ..Default::default()
        };
        // Only foreground: all 6 drawn (with repetition) from it.
        let t = sample_rois(&props[..2], &gts, &config, &mut Sampler::new(1)).unwrap();
        assert_eq!((t.len(), t.num_fg), (6, 6));
        assert!(t.proposal.iter().all(|&i| i < 2));
        // No ground truth: every RoI is easy background with no match.
        let t = sample_rois(&props, &[], &config, &mut Sampler::new(1)).unwrap();
        assert_eq!((t.len(), t.num_fg), (6, 0));
        assert!(t.gt_index.iter().all(|g| g.is_none()));
        assert!(t.cls_targets.iter().all(|&c| c == 0.0));
        assert!(t.reg_targets.iter().all(|r| *r == [0.0; 7]));
        // Only hard background.
        let t = sample_rois(&props[3..5], &gts, &config, &mut Sampler::new(1)).unwrap();
        assert!(t.proposal.iter().all(|&i| i < 2) && t.num_fg == 0);
        let err = sample_rois(&[], &gts, &config, &mut Sampler::new(1)).unwrap_err();
        assert!(err.to_string().contains("proposal"), "{err}");
    }

    #[test]
    fn canonical_frame_by_hand() {
        let roi = LidarBox {
            x: 10.0,
            y: 5.0,
            z: -1.0,
            heading: FRAC_PI_2,
            ..car_at(0.0)
        };
        // 2 m along the RoI's heading (LiDAR +y), 0.5 m up, turned 0.1 further.
        let gt = LidarBox {
            x: 10.0,
            y: 7.0,
            z: -0.5,
            heading: FRAC_PI_2 + 0.1,
            dx: 4.2,
            ..car_at(0.0)
        };
        let c = canonical_gt(&roi, &gt);
        assert!(
            close(c.x, 2.0) && close(c.y, 0.0) && close(c.z, 0.5),
            "{c:?}"
        );
        assert!(close(c.heading, 0.1) && c.dx == 4.2);
        // Facing the other way is the same box turned by π.
        let reversed = LidarBox {
            heading: -FRAC_PI_2 + 0.1,
            ..gt
        };
        assert!(close(canonical_gt(&roi, &reversed).heading, 0.1));
        let right = LidarBox {
            heading: FRAC_PI_2 - 0.2,
            ..gt
        };
        assert!(close(canonical_gt(&roi, &right).heading, -0.2));
        // A negative RoI heading is the same frame as its 2π complement.
        let roi_neg = LidarBox {
            heading: -3.0 * FRAC_PI_2,
            ..roi
        };
        let c2 = canonical_gt(&roi_neg, &gt);
        assert!(close(c2.x, 2.0) && close(c2.y, 0.0) && close(c2.heading, 0.1));
    }

    #[test]
    fn decoding_a_target_gives_the_ground_truth_back() {
        let roi = LidarBox {
            x: 20.0,
            y: -3.0,
            z: -0.8,
            dx: 3.8,
            dy: 1.7,
            dz: 1.5,
            heading: 2.5,
        };
        for heading in [2.4, 2.5 + PI - 0.05, -1.0, 0.3] {
            let gt = LidarBox {
                x: 20.4,
                y: -2.7,
                z: -0.9,
                dx: 4.1,
                dy: 1.6,
                dz: 1.45,
                heading,
            };
            let back = decode_roi(&roi_reg_target(&roi, &gt), &roi);
            for (a, b) in [
                (back.x, gt.x),
                (back.y, gt.y),
                (back.z, gt.z),
                (back.dx, gt.dx),
                (back.dy, gt.dy),
                (back.dz, gt.dz),
            ] {
                assert!(close(a, b), "{back:?} vs {gt:?}");
            }
            // The heading comes back modulo π (the fold turns reversed boxes).
            assert!(limit_period(back.heading - gt.heading, 0.5, PI).abs() < 1e-9);
        }
    }
}
