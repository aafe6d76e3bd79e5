//! The anchor head's training targets, with the semantics of OpenPCDet's
//! `AxisAlignedTargetAssigner` as the published configuration runs it.
//!
//! Each anchor class is matched only with ground truth of its class, by the IoU of
//! the two boxes' nearest axis-aligned bird's-eye rectangles (`MATCH_HEIGHT: False`):
//! - an anchor whose best IoU is ≥ `matched_iou` is positive for its best ground truth;
//! - for each ground truth, the anchors with its highest IoU (all of them when tied)
//!   are positive even below the threshold, so that no object goes without anchors (a
//!   ground truth that overlaps no anchor at all forces none);
//! - the other anchors are negative when their best IoU is < `unmatched_iou`, ignored
//!   in between;
//! - a positive anchor regresses towards its best ground truth (also when another
//!   ground truth forced it), as OpenPCDet's does.
//!
//! The published `POS_FRACTION: -1.0` switches the positive/negative sampling off, so
//! every labelled anchor counts (`SAMPLE_SIZE` is unused); `NORM_BY_NUM_EXAMPLES: False`
//! gives positives regression weight 1.
//!
//! Only the anchors near a ground truth can overlap it, so each ground truth visits
//! the feature-map cells its rectangle (grown by the largest anchor half-extent) covers,
//! not the 70,400 anchors.

use crate::anchors::Anchors;
use crate::boxes::{GtBox, LidarBox};
use crate::coder::{CODE_SIZE, DirectionBins, encode};
use crate::config::{AnchorConfig, VoxelConfig};
use crate::error::Result;

/// The targets of every anchor of one frame, in anchor order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AnchorTargets {
    /// Anchor class index + 1 for a positive anchor, 0 negative, −1 ignored.
    pub labels: Vec<i32>,
    /// The residual code of the matched ground truth (zeros unless positive).
    pub box_targets: Vec<[f32; CODE_SIZE]>,
    /// The direction bin of the matched ground truth's heading (of the anchor's own
    /// heading unless positive, as OpenPCDet computes it; only positives are weighed).
    pub dir_targets: Vec<u8>,
    /// Regression (and direction) loss weight: 1 for positives, else 0.
    pub reg_weights: Vec<f32>,
    /// The ground truth (index into the assigner's input) a positive anchor regresses to.
    pub matched_gt: Vec<Option<u32>>,
    pub num_positive: usize,
    pub num_negative: usize,
}

/// Anchors of a configuration and what their targets need, built once.
#[derive(Debug, Clone)]
pub struct AnchorAssigner {
    anchors: Anchors,
    config: AnchorConfig,
    dir: DirectionBins,
    /// Per anchor class: the largest half-extent of its snapped rectangles.
    reach: Vec<f64>,
}

impl AnchorAssigner {
    pub fn new(voxel: &VoxelConfig, config: &AnchorConfig) -> Result<AnchorAssigner> {
        let anchors = Anchors::generate(voxel, config)?;
        if config.num_dir_bins > u8::MAX as usize + 1 {
            return Err(crate::error::VoxelError::Config(format!(
                "`num_dir_bins` {} exceeds 256",
                config.num_dir_bins
            )));
        }
        let reach = config
            .classes
            .iter()
            .map(|c| c.size[0].max(c.size[1]) / 2.0)
            .collect();
        Ok(AnchorAssigner {
            anchors,
            config: config.clone(),
            dir: DirectionBins::from_config(config),
            reach,
        })
    }

    pub fn anchors(&self) -> &Anchors {
        &self.anchors
    }

    pub fn direction_bins(&self) -> DirectionBins {
        self.dir
    }

    /// The targets of every anchor for one frame's ground truth. Ground truth of a
    /// class without anchors is ignored.
    pub fn assign(&self, gts: &[GtBox]) -> AnchorTargets {
        let n = self.anchors.len();
        let per = self.anchors.per_location;
        let mut t = AnchorTargets {
            labels: vec![-1; n],
            box_targets: vec![[0.0; CODE_SIZE]; n],
            dir_targets: vec![0; n],
            reg_weights: vec![0.0; n],
            matched_gt: vec![None; n],
            num_positive: 0,
            num_negative: 0,
        };
        // Best IoU and its (first) ground truth per anchor; anchors no ground truth
        // reaches keep 0, which is below any unmatched threshold but an exact 0 IoU.
        let mut best = vec![0.0f64; n];
        let mut best_gt: Vec<Option<u32>> = vec![None; n];
        let mut forced = vec![false; n];
        // The nonzero overlaps (anchor, IoU) of the current ground truth.
        let mut overlaps: Vec<(usize, f64)> = Vec::new();
        for (k, class) in self.config.classes.iter().enumerate() {
            let slots: Vec<usize> = (0..per)
                .filter(|&s| self.anchors.slot_class[s] == k)
                .collect();
            let mut any_gt = false;
            for (j, gt) in gts.iter().enumerate() {
                if gt.class != class.class {
                    continue;
                }
                any_gt = true;
                let rect = gt.bbox.nearest_bev();
                let r = self.reach[k];
                let (xs, ys) =
                    self.anchors
                        .cells_within(rect.x1 - r, rect.x2 + r, rect.y1 - r, rect.y2 + r);
                let mut gt_best = 0.0f64;
                overlaps.clear();
                for iy in ys {
                    for ix in xs.clone() {
                        for &s in &slots {
                            let a = self.anchors.index(ix, iy, s);
                            let iou = self.anchors.boxes[a].nearest_bev().iou(&rect);
                            if iou <= 0.0 {
                                continue;
                            }
                            overlaps.push((a, iou));
                            gt_best = gt_best.max(iou);
                            // Strictly greater: the first ground truth keeps a tie.
                            if iou > best[a] {
                                best[a] = iou;
                                best_gt[a] = Some(j as u32);
                            }
                        }
                    }
                }
                for &(a, iou) in &overlaps {
                    if iou == gt_best {
                        forced[a] = true;
                    }
                }
            }
            for iy in 0..self.anchors.feature_map_size[1] {
                for ix in 0..self.anchors.feature_map_size[0] {
                    for &s in &slots {
                        let a = self.anchors.index(ix, iy, s);
                        let label = if !any_gt {
                            0
                        } else if forced[a] || best[a] >= class.matched_iou {
                            k as i32 + 1
                        } else if best[a] < class.unmatched_iou {
                            0
                        } else {
                            -1
                        };
                        t.labels[a] = label;
                    }
                }
            }
        }
        for (a, (anchor, best_gt)) in self.anchors.boxes.iter().zip(best_gt).enumerate() {
            let matched = best_gt.filter(|_| t.labels[a] > 0);
            let heading = match matched {
                Some(j) => {
                    let gt: &LidarBox = &gts[j as usize].bbox;
                    t.box_targets[a] = encode(gt, anchor).map(|v| v as f32);
                    t.reg_weights[a] = 1.0;
                    t.matched_gt[a] = Some(j);
                    t.num_positive += 1;
                    gt.heading
                }
                None => anchor.heading,
            };
            if t.labels[a] == 0 {
                t.num_negative += 1;
            }
            t.dir_targets[a] = self.dir.target(heading) as u8;
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boxes::nearest_bev_iou;
    use crate::config::AnchorClass;
    use fusiondet_dataset::rng::Sampler;
    use fusiondet_kitti::ObjectClass;
    use std::f64::consts::FRAC_PI_2;

    /// An 8 m × 8 m map of 1 m cells, anchors 2 × 1 at the cell centres (0.5 … 7.5),
    /// headings 0 and π/2.
    fn small() -> AnchorAssigner {
        let voxel = VoxelConfig {
            point_range: [0.0, 0.0, -3.0, 8.0, 8.0, 1.0],
            voxel_size: [1.0, 1.0, 4.0],
            ..Default::default()
        };
        let config = AnchorConfig {
            classes: vec![AnchorClass {
                size: [2.0, 1.0, 1.5],
                bottom_z: -1.75,
                rotations: vec![0.0, FRAC_PI_2],
                ..AnchorClass::car()
            }],
            feature_map_stride: 1,
            align_center: true,
            ..Default::default()
        };
        AnchorAssigner::new(&voxel, &config).unwrap()
    }

    fn gt(x: f64, y: f64, dx: f64, dy: f64, heading: f64, class: ObjectClass) -> GtBox {
        GtBox {
            bbox: LidarBox {
                x,
                y,
                z: -1.0,
                dx,
                dy,
                dz: 1.5,
                heading,
            },
            class,
        }
    }

    #[test]
    fn hand_made_scene() {
        let a = small();
        let car = ObjectClass::Car;
        let gts = [
            // A: 2.5 × 1.5 rectangle [2.75, 5.25] × [2.75, 4.25]. The heading-0 anchors
            // at x 3.5 and 4.5 (y 3.5) both overlap it by 1.75 × 1 over a union of 4:
            // 0.4375 < 0.45, yet they are its best, so both are forced positive.
            gt(4.0, 3.5, 2.5, 1.5, 0.0, car),
            // B: exactly the π/2 anchor at cell (1, 6): IoU 1.
            gt(1.5, 6.5, 2.0, 1.0, FRAC_PI_2, car),
            // C: [4.75, 6.75] × [1, 2]. Anchor x 5.5: 1.75 / 2.25 = 0.78, positive;
            // anchor x 6.5: 1.25 / 2.75 = 0.4545, ignored.
            gt(5.75, 1.5, 2.0, 1.0, 0.0, car),
            // A pedestrian: no pedestrian anchors, so it changes nothing.
            gt(6.5, 6.5, 0.8, 0.6, 0.0, ObjectClass::Pedestrian),
        ];
        let t = a.assign(&gts);
        let anchors = a.anchors();
        let positives: Vec<(usize, Option<u32>)> = (0..anchors.len())
            .filter(|&i| t.labels[i] == 1)
            .map(|i| (i, t.matched_gt[i]))
            .collect();
        assert_eq!(
            positives,
            vec![
                (anchors.index(5, 1, 0), Some(2)),
                (anchors.index(3, 3, 0), Some(0)),
                (anchors.index(4, 3, 0), Some(0)),
                (anchors.index(1, 6, 1), Some(1)),
            ]
        );
        let ignored: Vec<usize> = (0..anchors.len()).filter(|&i| t.labels[i] == -1).collect();
        assert_eq!(ignored, vec![anchors.index(6, 1, 0)]);
        assert_eq!(t.num_positive, 4);
        assert_eq!(t.num_negative, anchors.len() - 5);
        // A's regression from the anchor at x 3.5: Δx 0.5 over the diagonal √5, sizes
        // ln(2.5 / 2) and ln(1.5 / 1).
        let code = t.box_targets[anchors.index(3, 3, 0)];
        let want = [
            0.5 / 5f64.sqrt(),
            0.0,
            0.0,
            1.25f64.ln(),
            1.5f64.ln(),
            0.0,
            0.0,
        ];
        for k in 0..CODE_SIZE {
            assert!((code[k] as f64 - want[k]).abs() < 1e-6, "{code:?}");
        }
        assert!((t.box_targets[anchors.index(4, 3, 0)][0] as f64 + 0.5 / 5f64.sqrt()).abs() < 1e-6);
        // B sits exactly on its anchor.
        assert_eq!(t.box_targets[anchors.index(1, 6, 1)], [0.0; 7]);
        // Direction bins (offset π/4): heading 0 → 1, π/2 → 0.
        assert_eq!(t.dir_targets[anchors.index(3, 3, 0)], 1);
        assert_eq!(t.dir_targets[anchors.index(1, 6, 1)], 0);
        assert_eq!(t.reg_weights.iter().sum::<f32>(), 4.0);
        assert_eq!(t.reg_weights[anchors.index(6, 1, 0)], 0.0);
    }

    #[test]
    fn no_ground_truth_makes_every_anchor_negative() {
        let a = small();
        for gts in [
            vec![],
            vec![gt(4.0, 4.0, 0.8, 0.6, 0.0, ObjectClass::Cyclist)],
        ] {
            let t = a.assign(&gts);
            assert!(t.labels.iter().all(|&l| l == 0));
            assert_eq!((t.num_positive, t.num_negative), (0, a.anchors().len()));
            assert!(t.box_targets.iter().all(|c| *c == [0.0; 7]));
        }
        // A ground truth out of every anchor's reach forces nothing.
        let t = a.assign(&[gt(40.0, 4.0, 2.0, 1.0, 0.0, ObjectClass::Car)]);
        assert_eq!(t.num_positive, 0);
    }

    #[test]
    fn positives_of_kitti_frames_decode_to_their_ground_truth() {
        let a = AnchorAssigner::new(&VoxelConfig::default(), &AnchorConfig::default()).unwrap();
        let mut cars = 0;
        for id in ["000000", "000001", "000002", "000003", "000004", "000005"] {
            let frame = crate::scene::tests::kitti_frame(id);
            let mut scene = crate::scene::Scene::from_frame(&frame, true);
            scene.keep_targets(&[ObjectClass::Car], &VoxelConfig::default());
            let t = a.assign(&scene.gts);
            cars += scene.gts.len();
            // Every car in range has a positive anchor, and each positive's code
            // decodes back to its car.
            for j in 0..scene.gts.len() as u32 {
                assert!(t.matched_gt.contains(&Some(j)), "{id}: car {j}");
            }
            for (i, m) in t.matched_gt.iter().enumerate() {
                let Some(j) = m else { continue };
                let code = t.box_targets[i].map(|v| v as f64);
                let back = crate::coder::decode(&code, &a.anchors().boxes[i]);
                let (p, q) = (back.to_array(), scene.gts[*j as usize].bbox.to_array());
                assert!(
                    (0..7).all(|k| (p[k] - q[k]).abs() < 1e-4),
                    "{back:?} vs {q:?}"
                );
            }
        }
        assert!(cars > 0);
    }

    /// The assignment written over the full anchor × ground-truth matrix, as OpenPCDet
    /// computes it: the windowed version must agree with it everywhere.
    fn brute_force_labels(anchors: &Anchors, gts: &[LidarBox], hi: f64, lo: f64) -> Vec<i32> {
        let n = anchors.len();
        let iou: Vec<Vec<f64>> = anchors
            .boxes
            .iter()
            .map(|a| gts.iter().map(|g| nearest_bev_iou(a, g)).collect())
            .collect();
        let gt_max: Vec<f64> = (0..gts.len())
            .map(|j| {
                let m = (0..n).map(|i| iou[i][j]).fold(0.0, f64::max);
                if m == 0.0 { -1.0 } else { m }
            })
            .collect();
        (0..n)
            .map(|i| {
                let best = iou[i].iter().copied().fold(0.0, f64::max);
                let forced = (0..gts.len()).any(|j| iou[i][j] == gt_max[j]);
                if forced || best >= hi {
                    1
                } else if best < lo {
                    0
                } else {
                    -1
                }
            })
            .collect()
    }

    #[test]
    fn windowed_assignment_matches_the_full_matrix_on_the_published_anchors() {
        let a = AnchorAssigner::new(&VoxelConfig::default(), &AnchorConfig::default()).unwrap();
        let mut s = Sampler::new(11);
        let gts: Vec<GtBox> = (0..20)
            .map(|_| GtBox {
                bbox: LidarBox {
                    x: s.range(-2.0, 72.0),
                    y: s.range(-41.0, 41.0),
                    z: s.range(-1.5, -0.5),
                    dx: s.range(3.2, 4.8),
                    dy: s.range(1.4, 1.9),
                    dz: s.range(1.3, 1.8),
                    heading: s.range(-3.2, 3.2),
                },
                class: ObjectClass::Car,
            })
            .collect();
        let t = a.assign(&gts);
        let boxes: Vec<LidarBox> = gts.iter().map(|g| g.bbox).collect();
        let want = brute_force_labels(a.anchors(), &boxes, 0.6, 0.45);
        assert_eq!(t.labels, want);
        assert!(t.num_positive >= 20, "{}", t.num_positive);
    }
}
