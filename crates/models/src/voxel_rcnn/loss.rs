//! Voxel R-CNN's losses, as OpenPCDet computes them for `voxel_rcnn_car.yaml`.
//!
//! Stage one (per anchor; targets from the voxel crate's anchor assigner):
//! - sigmoid focal loss (α 0.25, γ 2) over cared anchors (labels ≥ 0), each weighted by
//!   1 / (positives of its frame);
//! - smooth-L1 (β 1/9) on the 7 residuals of positive anchors, the heading compared as
//!   sin(p − t) = sin p cos t − cos p sin t (so a box and its reverse cost the same);
//! - cross-entropy of the direction bin on positive anchors;
//!
//! each summed and divided by the batch size; weights 1, 2, 0.2.
//!
//! Stage two (per sampled RoI; targets from the proposal target layer):
//! - binary cross-entropy of the IoU-guided confidence target, mean over RoIs;
//! - smooth-L1 (β 1/9) on the canonical residuals of foreground RoIs, summed over the
//!   code and divided by the foreground count;
//! - the corner loss: smooth-L1 (β 1) on the distance of each of the 8 corners of the
//!   decoded box to the ground truth's, the smaller of the box's and its reverse's,
//!   mean over foreground RoIs and corners. Computed in the RoI's frame (distances do
//!   not change under the rigid motion to the LiDAR frame).

use super::anchor_head::AnchorPredictions;
use super::roi_head::RoiPredictions;
use burn::prelude::*;
use burn::tensor::activation::{log_softmax, relu, sigmoid};
use fusiondet_nn::gather::RowGather;
use fusiondet_nn::reduce::sum_all;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VoxelRcnnLossConfig {
    pub focal_alpha: f64,
    pub focal_gamma: f64,
    pub cls_weight: f64,
    pub loc_weight: f64,
    pub dir_weight: f64,
    pub rcnn_cls_weight: f64,
    pub rcnn_reg_weight: f64,
    pub rcnn_corner_weight: f64,
}

impl Default for VoxelRcnnLossConfig {
    fn default() -> Self {
        Self {
            focal_alpha: 0.25,
            focal_gamma: 2.0,
            cls_weight: 1.0,
            loc_weight: 2.0,
            dir_weight: 0.2,
            rcnn_cls_weight: 1.0,
            rcnn_reg_weight: 1.0,
            rcnn_corner_weight: 1.0,
        }
    }
}

/// Stage one's targets as tensors (built by the caller from the anchor assigner).
#[derive(Debug, Clone)]
pub struct AnchorLossTargets {
    /// [B, A, classes] one-hot class of positive anchors (zeros elsewhere).
    pub cls_onehot: Tensor<3>,
    /// [B, A] focal-loss weight: 1 / positives of the frame for cared anchors, else 0.
    pub cls_weights: Tensor<2>,
    /// [B, A] regression and direction weight: 1 / positives for positive anchors.
    pub reg_weights: Tensor<2>,
    /// [B, A, 7] residual targets (any value where the weight is 0).
    pub box_targets: Tensor<3>,
    /// [B, A, bins] one-hot direction bin.
    pub dir_onehot: Tensor<3>,
}

/// Stage two's targets for the sampled RoIs.
#[derive(Debug, Clone)]
pub struct RoiLossTargets {
    /// [R, 1] confidence targets in [0, 1].
    pub cls: Tensor<2>,
    /// The foreground (regressed) RoIs' [F] rows of the R; `None` when there are none. A
    /// `RowGather`, so that on a GPU their gradients go back by their readers rather than
    /// through burn's `select_assign` (seven threads walking every row).
    pub fg_rows: Option<RowGather>,
    /// [F, 7] canonical residual targets of those rows.
    pub reg: Tensor<2>,
    /// [F, 3] the RoIs' sizes (dx, dy, dz), for decoding.
    pub roi_sizes: Tensor<2>,
    /// [F, 8, 3] ground-truth corners in the RoI's frame, and of the reversed box.
    pub gt_corners: Tensor<3>,
    pub gt_corners_flipped: Tensor<3>,
}

/// Named loss terms (weighted) and their sum.
#[derive(Debug, Clone)]
pub struct VoxelRcnnLoss {
    pub total: Tensor<1>,
    pub terms: Vec<(&'static str, Tensor<1>)>,
}

/// Smooth-L1 with transition `beta` (elementwise).
pub fn smooth_l1<const D: usize>(diff: Tensor<D>, beta: f64) -> Tensor<D> {
    let a = diff.abs();
    let small = a.clone().lower_elem(beta);
    let quadratic = a.clone().powi_scalar(2).mul_scalar(0.5 / beta);
    let linear = a.sub_scalar(0.5 * beta);
    linear.mask_where(small, quadratic)
}

/// Stage one's three terms, weighted: (cls, loc, dir).
pub fn anchor_loss(
    pred: &AnchorPredictions,
    targets: &AnchorLossTargets,
    config: &VoxelRcnnLossConfig,
) -> [Tensor<1>; 3] {
    let [b, _, _] = pred.cls.dims();
    let batch = b as f64;
    // Sigmoid focal loss.
    let x = pred.cls.clone();
    let t = targets.cls_onehot.clone();
    let p = sigmoid(x.clone());
    let alpha = t.clone().mul_scalar(config.focal_alpha)
        + t.clone()
            .neg()
            .add_scalar(1.0)
            .mul_scalar(1.0 - config.focal_alpha);
    let pt = t.clone() * p.clone().neg().add_scalar(1.0) + t.clone().neg().add_scalar(1.0) * p;
    let bce = relu(x.clone()) - x.clone() * t + x.abs().neg().exp().log1p();
    let focal = alpha * pt.powf_scalar(config.focal_gamma) * bce;
    let cls = sum_all(focal * targets.cls_weights.clone().unsqueeze_dim::<3>(2))
        .div_scalar(batch)
        .mul_scalar(config.cls_weight);

    // Box residuals with the heading as a sine difference.
    let pb = pred.boxes.clone();
    let tb = targets.box_targets.clone();
    let [_, a, _] = pb.dims();
    let (p6, t6) = (pb.clone().slice_dim(2, 6..7), tb.clone().slice_dim(2, 6..7));
    let p_sin = p6.clone().sin() * t6.clone().cos();
    let t_sin = p6.cos() * t6.sin();
    let diff = Tensor::cat(
        vec![pb.slice_dim(2, 0..6) - tb.slice_dim(2, 0..6), p_sin - t_sin],
        2,
    );
    let loc = sum_all(smooth_l1(diff, 1.0 / 9.0) * targets.reg_weights.clone().reshape([b, a, 1]))
        .div_scalar(batch)
        .mul_scalar(config.loc_weight);

    // Direction bins.
    let ce = (log_softmax(pred.direction.clone(), 2) * targets.dir_onehot.clone())
        .sum_dim(2)
        .neg()
        .reshape([b, a]);
    let dir = sum_all(ce * targets.reg_weights.clone())
        .div_scalar(batch)
        .mul_scalar(config.dir_weight);
    [cls, loc, dir]
}

/// Corners [N, 8, 3] of boxes given by centres [N, 3], sizes [N, 3] and headings [N, 1].
pub fn box_corners(centres: Tensor<2>, sizes: Tensor<2>, headings: Tensor<2>) -> Tensor<3> {
    let [n, _] = centres.dims();
    let device = centres.device();
    if n == 0 {
        // No box (a batch without foreground RoIs): no operation on empty tensors, which
        // burn's GPU kernels do not all take (a debug build's overflow check in burn-cubecl).
        return Tensor::zeros([0, 8, 3], &device);
    }
    // Unit-box corner signs, as (x, y, z) ± 0.5.
    let signs: Vec<f32> = (0..8)
        .flat_map(|k| {
            [
                if k & 1 == 0 { 0.5 } else { -0.5 },
                if k & 2 == 0 { 0.5 } else { -0.5 },
                if k & 4 == 0 { 0.5 } else { -0.5 },
            ]
        })
        .collect();
    let signs = Tensor::<3>::from_data(TensorData::new(signs, [1, 8, 3]), &device);
    let local = signs * sizes.reshape([n, 1, 3]); // [N, 8, 3]
    let (lx, ly, lz) = (
        local.clone().slice_dim(2, 0..1),
        local.clone().slice_dim(2, 1..2),
        local.slice_dim(2, 2..3),
    );
    let (s, c) = (
        headings.clone().sin().reshape([n, 1, 1]),
        headings.cos().reshape([n, 1, 1]),
    );
    let x = lx.clone() * c.clone() - ly.clone() * s.clone();
    let y = lx * s + ly * c;
    Tensor::cat(vec![x, y, lz], 2) + centres.reshape([n, 1, 3])
}

/// Corners [F, 8, 3] of refined boxes decoded in their RoIs' frames: residual codes
/// [F, 7] against reference boxes of the RoIs' sizes [F, 3] at the origin.
pub fn canonical_corners(code: Tensor<2>, roi_sizes: Tensor<2>) -> Tensor<3> {
    let sizes = roi_sizes;
    let diagonal = (sizes.clone().slice_dim(1, 0..1).powi_scalar(2)
        + sizes.clone().slice_dim(1, 1..2).powi_scalar(2))
    .sqrt();
    let centres = Tensor::cat(
        vec![
            code.clone().slice_dim(1, 0..1) * diagonal.clone(),
            code.clone().slice_dim(1, 1..2) * diagonal,
            code.clone().slice_dim(1, 2..3) * sizes.clone().slice_dim(1, 2..3),
        ],
        1,
    );
    let box_sizes = code.clone().slice_dim(1, 3..6).exp() * sizes;
    box_corners(centres, box_sizes, code.slice_dim(1, 6..7))
}

/// Binary cross-entropy of the IoU-guided confidence targets, mean over RoIs (unweighted).
pub fn roi_confidence_loss(pred: &RoiPredictions, targets: &RoiLossTargets) -> Tensor<1> {
    let x = pred.cls.clone();
    let t = targets.cls.clone();
    (relu(x.clone()) - x.clone() * t + x.abs().neg().exp().log1p()).mean()
}

/// Smooth-L1 (β 1/9) of the foreground RoIs' residuals, summed over the code and divided
/// by the foreground count (unweighted), with those rows' predicted codes [F, 7]; `None`
/// without foreground.
pub fn roi_residual_loss(
    pred: &RoiPredictions,
    targets: &RoiLossTargets,
) -> Option<(Tensor<1>, Tensor<2>)> {
    let rows = targets.fg_rows.as_ref()?;
    let [f] = rows.index().dims();
    let code = rows.gather(pred.boxes.clone()); // [F, 7]
    let reg =
        sum_all(smooth_l1(code.clone() - targets.reg.clone(), 1.0 / 9.0)).div_scalar(f as f64);
    Some((reg, code))
}

/// Stage two's three terms, weighted: (cls, reg, corner).
pub fn roi_loss(
    pred: &RoiPredictions,
    targets: &RoiLossTargets,
    config: &VoxelRcnnLossConfig,
) -> [Tensor<1>; 3] {
    let cls = roi_confidence_loss(pred, targets).mul_scalar(config.rcnn_cls_weight);
    let Some((reg, code)) = roi_residual_loss(pred, targets) else {
        let zero = Tensor::<1>::zeros([1], &pred.cls.device());
        return [cls, zero.clone(), zero];
    };
    let reg = reg.mul_scalar(config.rcnn_reg_weight);
    let corners = canonical_corners(code, targets.roi_sizes.clone());
    let distance = |gt: &Tensor<3>| {
        (corners.clone() - gt.clone())
            .powi_scalar(2)
            .sum_dim(2)
            .sqrt()
    }; // [F, 8, 1]
    let nearest = distance(&targets.gt_corners).min_pair(distance(&targets.gt_corners_flipped));
    let corner = smooth_l1(nearest, 1.0)
        .mean()
        .mul_scalar(config.rcnn_corner_weight);
    [cls, reg, corner]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scalar(t: Tensor<1>) -> f32 {
        t.into_scalar::<f32>()
    }

    fn t3(v: Vec<f32>, shape: [usize; 3], d: &Device) -> Tensor<3> {
        Tensor::from_data(TensorData::new(v, shape), d)
    }

    #[test]
    fn smooth_l1_has_both_branches() {
        let d = Device::flex();
        let x = Tensor::<1>::from_data(TensorData::new(vec![0.05f32, -0.5, 2.0], [3]), &d);
        let v: Vec<f32> = smooth_l1(x, 0.1).into_data().try_to_vec::<f32>().unwrap();
        let expected = [0.5 * 0.0025 / 0.1, 0.5 - 0.05, 2.0 - 0.05];
        for (a, e) in v.iter().zip(expected) {
            assert!((a - e).abs() < 1e-6, "{v:?}");
        }
    }

    /// One frame, two anchors: a positive (class 0, bin 1) and a negative, by hand.
    #[test]
    fn anchor_terms_by_hand() {
        let d = Device::flex();
        let pred = AnchorPredictions {
            cls: t3(vec![0.0, 2.0], [1, 2, 1], &d),
            boxes: t3(
                vec![
                    0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0,
                ],
                [1, 2, 7],
                &d,
            ),
            direction: t3(vec![0.0, 0.0, 5.0, -5.0], [1, 2, 2], &d),
        };
        let targets = AnchorLossTargets {
            cls_onehot: t3(vec![1.0, 0.0], [1, 2, 1], &d),
            cls_weights: Tensor::from_data(TensorData::new(vec![1.0f32, 1.0], [1, 2]), &d),
            reg_weights: Tensor::from_data(TensorData::new(vec![1.0f32, 0.0], [1, 2]), &d),
            box_targets: t3(vec![0.0; 14], [1, 2, 7], &d),
            dir_onehot: t3(vec![0.0, 1.0, 1.0, 0.0], [1, 2, 2], &d),
        };
        let [cls, loc, dir] = anchor_loss(&pred, &targets, &VoxelRcnnLossConfig::default());
        // Positive at logit 0: α 0.25 · (1 − 0.5)² · ln 2. Negative at logit 2:
        // 0.75 · σ(2)² · (2 + ln(1 + e⁻²)).
        let s2 = 1.0 / (1.0 + (-2.0f64).exp());
        let expected_cls =
            0.25 * 0.25 * 2f64.ln() + 0.75 * s2 * s2 * (2.0 + (1.0 + (-2.0f64).exp()).ln());
        assert!((scalar(cls) as f64 - expected_cls).abs() < 1e-5);
        // 0.1 → 0.5·0.01·9 = 0.045 (below β = 1/9); heading sin(0.3) → linear branch.
        let expected_loc = 2.0 * (0.045 + (0.3f64.sin() - 0.5 / 9.0));
        assert!(
            (scalar(loc) as f64 - expected_loc).abs() < 1e-5,
            "{expected_loc}"
        );
        // Bin 1 at logits (0, 0): ln 2, weight 0.2; the negative anchor does not count.
        assert!((scalar(dir) as f64 - 0.2 * 2f64.ln()).abs() < 1e-6);
    }

    #[test]
    fn corners_of_a_turned_box() {
        let d = Device::flex();
        let c = box_corners(
            Tensor::from_data(TensorData::new(vec![1.0f32, 2.0, 3.0], [1, 3]), &d),
            Tensor::from_data(TensorData::new(vec![4.0f32, 2.0, 1.0], [1, 3]), &d),
            Tensor::from_data(
                TensorData::new(vec![std::f32::consts::FRAC_PI_2], [1, 1]),
                &d,
            ),
        );
        let v: Vec<f32> = c.into_data().try_to_vec::<f32>().unwrap();
        // Corner 0 = local (+2, +1, +0.5) turned 90°: (−1, +2, +0.5) + centre.
        let expected = [0.0, 4.0, 3.5];
        for (a, e) in v[..3].iter().zip(expected) {
            assert!((a - e).abs() < 1e-5, "{:?}", &v[..3]);
        }
    }

    #[test]
    fn a_perfect_refinement_costs_only_its_confidence() {
        let d = Device::flex();
        let sizes = Tensor::<2>::from_data(TensorData::new(vec![3.9f32, 1.6, 1.56], [1, 3]), &d);
        let zero = Tensor::<2>::zeros([1, 3], &d);
        let gt = box_corners(zero.clone(), sizes.clone(), Tensor::zeros([1, 1], &d));
        let flipped = box_corners(
            zero,
            sizes.clone(),
            Tensor::full([1, 1], std::f32::consts::PI, &d),
        );
        let targets = RoiLossTargets {
            cls: Tensor::from_data(TensorData::new(vec![1.0f32, 0.0], [2, 1]), &d),
            fg_rows: Some(RowGather::new(&[0], 2, &d)),
            reg: Tensor::zeros([1, 7], &d),
            roi_sizes: sizes,
            gt_corners: gt,
            gt_corners_flipped: flipped,
        };
        let pred = RoiPredictions {
            cls: Tensor::from_data(TensorData::new(vec![0.0f32, 0.0], [2, 1]), &d),
            boxes: Tensor::from_data(
                TensorData::new([[0.0f32; 7], [5.0; 7]].concat(), [2, 7]),
                &d,
            ),
        };
        let [cls, reg, corner] = roi_loss(&pred, &targets, &VoxelRcnnLossConfig::default());
        assert!((scalar(cls) as f64 - 2f64.ln()).abs() < 1e-6);
        assert!(
            scalar(reg).abs() < 1e-7,
            "the background row does not regress"
        );
        assert!(scalar(corner).abs() < 1e-5);
        // A box turned by π matches the flipped corners: the corner loss does not care.
        let turned = RoiPredictions {
            cls: pred.cls.clone(),
            boxes: Tensor::from_data(
                TensorData::new(
                    [
                        [0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, std::f32::consts::PI],
                        [5.0; 7],
                    ]
                    .concat(),
                    [2, 7],
                ),
                &d,
            ),
        };
        let [_, _, corner] = roi_loss(&turned, &targets, &VoxelRcnnLossConfig::default());
        assert!(scalar(corner).abs() < 1e-5);
    }
}
