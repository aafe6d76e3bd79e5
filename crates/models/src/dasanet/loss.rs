//! DASANet's second-stage loss (Section 3.4.2, Eq. 16): L_RCNN = L_det + λ1 L_aux1 +
//! λ2 L_aux2. Every head's classification term is the binary cross-entropy of Voxel
//! R-CNN's IoU-guided targets; the detection head regresses with smooth-L1 on the
//! residuals plus the 3D GIoU of the decoded box and its ground truth ([`super::giou`],
//! in place of Voxel R-CNN's corner loss); the auxiliary heads with smooth-L1 only.
//! Stage one's loss (L_RPN) is Voxel R-CNN's, unchanged.

use super::DasanetRoiOutput;
use super::giou::giou_3d_loss;
use crate::voxel_rcnn::RoiPredictions;
use crate::voxel_rcnn::loss::{
    RoiLossTargets, VoxelRcnnLossConfig, canonical_corners, roi_confidence_loss, roi_residual_loss,
};
use burn::prelude::*;

/// One head's weighted (classification, regression) terms.
fn head_terms(
    pred: &RoiPredictions,
    targets: &RoiLossTargets,
    config: &VoxelRcnnLossConfig,
    weight: f64,
) -> (Tensor<1>, Option<(Tensor<1>, Tensor<2>)>) {
    let cls = roi_confidence_loss(pred, targets).mul_scalar(config.rcnn_cls_weight * weight);
    let reg = roi_residual_loss(pred, targets)
        .map(|(reg, code)| (reg.mul_scalar(config.rcnn_reg_weight * weight), code));
    (cls, reg)
}

/// The named, weighted terms of L_RCNN: the detection head's (cls, reg, GIoU) and, when
/// their predictions are present, each auxiliary head's (cls, reg) times λ1 or λ2.
pub fn rcnn_loss(
    output: &DasanetRoiOutput,
    targets: &RoiLossTargets,
    config: &VoxelRcnnLossConfig,
    giou_weight: f64,
    aux_weights: [f64; 2],
) -> Vec<(&'static str, Tensor<1>)> {
    let zero = || Tensor::<1>::zeros([1], &output.detection.cls.device());
    let (cls, reg) = head_terms(&output.detection, targets, config, 1.0);
    let (reg, giou) = match reg {
        Some((reg, code)) => {
            let corners = canonical_corners(code, targets.roi_sizes.clone());
            let giou = giou_3d_loss(corners, targets.gt_corners.clone()).mul_scalar(giou_weight);
            (reg, giou)
        }
        None => (zero(), zero()),
    };
    let mut terms = vec![("rcnn_cls", cls), ("rcnn_reg", reg), ("rcnn_giou", giou)];
    let aux = [
        (
            &output.aux_tdis,
            aux_weights[0],
            ["aux_tdis_cls", "aux_tdis_reg"],
        ),
        (
            &output.aux_stca,
            aux_weights[1],
            ["aux_stca_cls", "aux_stca_reg"],
        ),
    ];
    for (pred, weight, names) in aux {
        if let Some(pred) = pred {
            let (cls, reg) = head_terms(pred, targets, config, weight);
            terms.push((names[0], cls));
            terms.push((names[1], reg.map_or_else(zero, |(r, _)| r)));
        }
    }
    terms
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxel_rcnn::loss::box_corners;

    fn t2(v: Vec<f32>, shape: [usize; 2], d: &Device) -> Tensor<2> {
        Tensor::from_data(TensorData::new(v, shape), d)
    }

    fn scalar(t: &Tensor<1>) -> f64 {
        t.clone().into_scalar::<f32>() as f64
    }

    /// A perfect refinement costs only confidence; a wrong one costs GIoU on the
    /// detection head only; the auxiliary heads are weighted by λ.
    #[test]
    fn terms_by_hand() {
        let d = Device::flex();
        let sizes = t2(vec![3.9, 1.6, 1.56], [1, 3], &d);
        let zero3 = Tensor::<2>::zeros([1, 3], &d);
        let gt = box_corners(zero3.clone(), sizes.clone(), Tensor::zeros([1, 1], &d));
        let targets = RoiLossTargets {
            cls: t2(vec![1.0, 0.0], [2, 1], &d),
            fg_rows: Some(fusiondet_nn::gather::RowGather::new(&[0], 2, &d)),
            reg: Tensor::zeros([1, 7], &d),
            roi_sizes: sizes,
            gt_corners: gt.clone(),
            gt_corners_flipped: gt,
        };
        let perfect = RoiPredictions {
            cls: t2(vec![0.0, 0.0], [2, 1], &d),
            boxes: t2([[0.0f32; 7], [5.0; 7]].concat(), [2, 7], &d),
        };
        // Shifted along x by 0.1 of the diagonal: 0.4346 m of a 3.9 m box.
        let mut shifted_code = [[0.0f32; 7], [5.0; 7]].concat();
        shifted_code[0] = 0.1;
        let shifted = RoiPredictions {
            cls: perfect.cls.clone(),
            boxes: t2(shifted_code, [2, 7], &d),
        };
        let output = DasanetRoiOutput {
            detection: perfect.clone(),
            aux_tdis: Some(shifted.clone()),
            aux_stca: Some(perfect.clone()),
        };
        let config = VoxelRcnnLossConfig::default();
        let terms = rcnn_loss(&output, &targets, &config, 1.0, [0.5, 2.0]);
        let names: Vec<&str> = terms.iter().map(|t| t.0).collect();
        assert_eq!(
            names,
            [
                "rcnn_cls",
                "rcnn_reg",
                "rcnn_giou",
                "aux_tdis_cls",
                "aux_tdis_reg",
                "aux_stca_cls",
                "aux_stca_reg"
            ]
        );
        let v: Vec<f64> = terms.iter().map(|t| scalar(&t.1)).collect();
        let ln2 = 2f64.ln();
        assert!(
            (v[0] - ln2).abs() < 1e-6 && v[1].abs() < 1e-7 && v[2].abs() < 1e-5,
            "{v:?}"
        );
        // λ1 0.5: ln 2 / 2; smooth-L1 of 0.1 (below β = 1/9: 0.5 · 0.01 · 9) / 2.
        assert!((v[3] - 0.5 * ln2).abs() < 1e-6);
        assert!((v[4] - 0.5 * 0.045).abs() < 1e-6, "{}", v[4]);
        assert!((v[5] - 2.0 * ln2).abs() < 1e-6 && v[6].abs() < 1e-7);

        // The shifted box on the detection head: GIoU loss 1 − IoU (the hull is the union's
        // bounding box, both axis-aligned): IoU = (3.9 − s)/(3.9 + s), s = 0.1 · diagonal.
        let s = 0.1 * (3.9f64.powi(2) + 1.6f64.powi(2)).sqrt();
        let only = DasanetRoiOutput {
            detection: shifted,
            aux_tdis: None,
            aux_stca: None,
        };
        let terms = rcnn_loss(&only, &targets, &config, 1.0, [1.0, 1.0]);
        assert_eq!(terms.len(), 3);
        let giou = scalar(&terms[2].1);
        let expected = 1.0 - (3.9 - s) / (3.9 + s);
        assert!((giou - expected).abs() < 1e-4, "{giou} vs {expected}");
    }
}
