//! F-ConvNet's first-stage loss.
//!
//! `total = focal + box_weight · (centre + heading_cls + size_cls
//!          + heading_residual_weight · heading_res + size_residual_weight · size_res
//!          + corner_weight · corner)`
//!
//! - focal: softmax focal loss (α = 0.25 on positives, 1 − α on negatives, γ = 2) over the
//!   non-ignored positions, summed and divided by the number of positives (at least 1);
//! - the box terms are means over the positive positions (zero when there is none):
//!   centre: Huber(δ = 3) of the distance between (position centre + predicted offset) and
//!   the ground-truth centre; heading and size cross-entropies; Huber(δ = 1) of the GT bin's
//!   normalised heading residual error and of the distance between the GT cluster's
//!   normalised size residuals; corner: Huber(δ = 1) of the mean corner distance between the
//!   predicted box (GT bin and cluster, predicted residuals) and the ground truth or its
//!   π-flipped twin, whichever is closer.

use crate::boxes::{CORNER_SIGNS, flip_corners};
use crate::config::{LossConfig, ModelConfig};
use crate::error::ModelError;
use crate::heads::RegressionLayout;
use crate::model::FConvNetOutput;
use burn::prelude::*;
use burn::tensor::activation::log_softmax;
use fusiondet_frustum::FrustumBatch;
use fusiondet_nn::reduce::sum_all;

/// A batch's targets as tensors, prepared on the host.
#[derive(Debug, Clone)]
pub struct LossTargets {
    layout: RegressionLayout,
    bin_width: f32,
    positions: usize,
    num_positives: usize,
    num_kept: usize,
    /// Non-ignored flat positions (b · P + p) with their labels and focal α.
    kept: Tensor<1, Int>,
    kept_labels: Tensor<2, Int>,
    kept_alpha: Tensor<2>,
    /// Positive flat positions and the per-positive targets.
    positive: Tensor<1, Int>,
    position_centers: Tensor<2>,
    center: Tensor<2>,
    heading_bin: Tensor<2, Int>,
    heading_bin_f: Tensor<2>,
    /// Heading residual over half the bin width, [Np, 1].
    heading_residual: Tensor<2>,
    size_cluster: Tensor<2, Int>,
    size_index: Tensor<3, Int>,
    size_residual: Tensor<2>,
    mean_size: Tensor<2>,
    corners: Tensor<3>,
    corners_flipped: Tensor<3>,
    /// For the positives whose ground truth projects in front of the camera (rows into the
    /// positives [Nv]): frustum frame → pixels [Nv, 3, 4] and the GT's projected 2D box as
    /// (centre u, centre v, width, height) [Nv, 4]; present when the PL term is on and
    /// some positive projects.
    projection: Option<(Tensor<1, Int>, Tensor<3>, Tensor<2>)>,
}

impl LossTargets {
    pub fn new(
        batch: &FrustumBatch,
        model: &ModelConfig,
        loss: &LossConfig,
        device: &Device,
    ) -> Result<Self, ModelError> {
        let bad = |msg: String| Err(ModelError::Batch(format!("targets: {msg}")));
        let Some(t) = &batch.targets else {
            return bad("the batch has no targets".into());
        };
        let b = batch.batch_size;
        let Some(out) = batch.scales.get(batch.output_scale) else {
            return bad("no output scale".into());
        };
        let p = out.slices_per_frustum;
        let (nh, ns) = (model.num_heading_bins, model.size_clusters.len());
        if t.labels.len() != b * p {
            return bad(format!("{} labels, expected {b} × {p}", t.labels.len()));
        }
        if out.slice_centers.len() != b * p * 3 {
            return bad("output scale slice_centers has the wrong length".into());
        }
        let lens = [
            ("center", t.center.len(), 3),
            ("heading_bin", t.heading_bin.len(), 1),
            ("heading_residual", t.heading_residual.len(), 1),
            ("size_cluster", t.size_cluster.len(), 1),
            ("size_residual", t.size_residual.len(), 3),
            ("corners", t.corners.len(), 24),
        ];
        for (name, len, per) in lens {
            if len != b * per {
                return bad(format!("{name} has {len} values, expected {b} × {per}"));
            }
        }
        if let Some(l) = t.labels.iter().find(|l| !(-1..=1).contains(*l)) {
            return bad(format!("label {l} is not -1, 0 or 1"));
        }
        if let Some(h) = t.heading_bin.iter().find(|h| !(0..nh as i64).contains(*h)) {
            return bad(format!("heading bin {h} outside 0..{nh}"));
        }
        if let Some(s) = t.size_cluster.iter().find(|s| !(0..ns as i64).contains(*s)) {
            return bad(format!("size cluster {s} outside 0..{ns}"));
        }

        let bin_width = model.heading_bin_width();
        let (mut kept, mut kept_labels, mut kept_alpha) = (vec![], vec![], vec![]);
        let mut positive = vec![];
        let (mut pc, mut center, mut hb, mut hbf, mut hr) =
            (vec![], vec![], vec![], vec![], vec![]);
        let (mut sc, mut si, mut sr, mut ms, mut corners, mut flipped) =
            (vec![], vec![], vec![], vec![], vec![], vec![]);
        let use_projection = loss.projection_weight > 0.0;
        if use_projection && batch.image_projection.len() != b * 12 {
            return bad(format!(
                "the projection loss needs a 3 × 4 image projection per frustum; the batch has {} values for {b} frustums",
                batch.image_projection.len()
            ));
        }
        let (mut proj, mut gt_box, mut proj_rows) = (vec![], vec![], vec![]);
        for (flat, &label) in t.labels.iter().enumerate() {
            if label < 0 {
                continue;
            }
            kept.push(flat as i64);
            kept_labels.push(label);
            kept_alpha.push(if label == 1 {
                loss.focal_alpha
            } else {
                1.0 - loss.focal_alpha
            });
            if label != 1 {
                continue;
            }
            let f = flat / p;
            positive.push(flat as i64);
            pc.extend_from_slice(&out.slice_centers[flat * 3..flat * 3 + 3]);
            let c: [f32; 3] = t.center[f * 3..f * 3 + 3].try_into().unwrap();
            center.extend_from_slice(&c);
            hb.push(t.heading_bin[f]);
            hbf.push(t.heading_bin[f] as f32);
            hr.push(t.heading_residual[f] / (bin_width / 2.0));
            let cluster = t.size_cluster[f] as usize;
            sc.push(cluster as i64);
            si.extend_from_slice(&[cluster as i64; 3]);
            sr.extend_from_slice(&t.size_residual[f * 3..f * 3 + 3]);
            ms.extend_from_slice(&model.size_clusters[cluster]);
            let gt: [[f32; 3]; 8] = std::array::from_fn(|k| {
                t.corners[f * 24 + k * 3..f * 24 + k * 3 + 3]
                    .try_into()
                    .unwrap()
            });
            corners.extend(gt.iter().flatten());
            flipped.extend(flip_corners(&gt, c).iter().flatten());
            if use_projection {
                let m: [f32; 12] = batch.image_projection[f * 12..f * 12 + 12]
                    .try_into()
                    .unwrap();
                // A box reaching behind the camera plane (a car alongside) has no 2D box:
                // it takes no part in the projection term.
                if let Some(b2) = projected_box(&gt, &m) {
                    proj_rows.push((positive.len() - 1) as i64);
                    proj.extend_from_slice(&m);
                    gt_box.extend_from_slice(&b2);
                }
            }
        }
        let (nk, np) = (kept.len(), positive.len());
        let f2 = |v: Vec<f32>, cols: usize| {
            Tensor::<2>::from_data(TensorData::new(v, [np, cols]), device)
        };
        let f3 = |v: Vec<f32>| Tensor::<3>::from_data(TensorData::new(v, [np, 8, 3]), device);
        let i2 = |v: Vec<i64>, rows: usize| {
            Tensor::<2, Int>::from_data(TensorData::new(v, [rows, 1]), device)
        };
        Ok(Self {
            layout: RegressionLayout::new(model),
            bin_width,
            positions: p,
            num_positives: np,
            num_kept: nk,
            kept: Tensor::from_data(TensorData::new(kept, [nk]), device),
            kept_labels: i2(kept_labels, nk),
            kept_alpha: Tensor::from_data(TensorData::new(kept_alpha, [nk, 1]), device),
            positive: Tensor::from_data(TensorData::new(positive, [np]), device),
            position_centers: f2(pc, 3),
            center: f2(center, 3),
            heading_bin: i2(hb, np),
            heading_bin_f: f2(hbf, 1),
            heading_residual: f2(hr, 1),
            size_cluster: i2(sc, np),
            size_index: Tensor::from_data(TensorData::new(si, [np, 1, 3]), device),
            size_residual: f2(sr, 3),
            mean_size: f2(ms, 3),
            corners: f3(corners),
            corners_flipped: f3(flipped),
            projection: (use_projection && !proj_rows.is_empty()).then(|| {
                let nv = proj_rows.len();
                (
                    Tensor::from_data(TensorData::new(proj_rows, [nv]), device),
                    Tensor::from_data(TensorData::new(proj, [nv, 3, 4]), device),
                    Tensor::from_data(TensorData::new(gt_box, [nv, 4]), device),
                )
            }),
        })
    }

    pub fn num_positives(&self) -> usize {
        self.num_positives
    }
}

/// The loss values of one batch, read back to the host (for logging).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LossComponents {
    pub total: f32,
    pub cls: f32,
    pub center: f32,
    pub heading_cls: f32,
    pub heading_res: f32,
    pub size_cls: f32,
    pub size_res: f32,
    pub corner: f32,
    /// SAF's projection term (0 when off).
    pub projection: f32,
    pub num_positives: usize,
}

impl LossComponents {
    /// (name, value) pairs in a fixed order.
    pub fn named(&self) -> [(&'static str, f32); 9] {
        [
            ("total", self.total),
            ("cls", self.cls),
            ("center", self.center),
            ("heading_cls", self.heading_cls),
            ("heading_res", self.heading_res),
            ("size_cls", self.size_cls),
            ("size_res", self.size_res),
            ("corner", self.corner),
            ("projection", self.projection),
        ]
    }
}

/// The differentiable total and its components.
#[derive(Debug, Clone)]
pub struct LossOutput {
    /// [1]; call `backward()` on it.
    pub total: Tensor<1>,
    pub components: LossComponents,
}

/// Huber loss of each element: 0.5 q² + δ (|e| − q) with q = min(|e|, δ).
pub fn huber<const D: usize>(error: Tensor<D>, delta: f32) -> Tensor<D> {
    let abs = error.abs();
    let q = abs.clone().clamp_max(delta);
    q.clone().square().mul_scalar(0.5) + (abs - q).mul_scalar(delta)
}

/// Euclidean norm over the last dimension, kept differentiable at zero.
fn norm_last<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    x.square().sum_dim(D - 1).add_scalar(1e-12).sqrt()
}

/// Softmax focal loss over rows of `logits` ([K, 2]) with integer labels [K, 1] and
/// per-row α [K, 1]; summed and divided by `normaliser`.
pub fn focal_loss(
    logits: Tensor<2>,
    labels: Tensor<2, Int>,
    alpha: Tensor<2>,
    gamma: f32,
    normaliser: f32,
) -> Tensor<1> {
    let log_pt = log_softmax(logits, 1).gather(1, labels); // [K, 1]
    let pt = log_pt.clone().exp();
    let modulator = pt.neg().add_scalar(1.0).clamp_min(0.0).powf_scalar(gamma);
    sum_all(alpha * modulator * log_pt)
        .neg()
        .div_scalar(normaliser)
}

/// Corners [N, 8, 3] of boxes given by centres [N, 3], headings [N, 1] and sizes [N, 3]
/// (the tensor form of [`box_corners`](crate::boxes::box_corners)).
pub fn box_corners_tensor(center: Tensor<2>, heading: Tensor<2>, size: Tensor<2>) -> Tensor<3> {
    let device = center.device();
    let n = center.dims()[0];
    let signs = |axis: usize| {
        Tensor::<2>::from_data(
            TensorData::new(CORNER_SIGNS[axis].to_vec(), [1, 8]),
            &device,
        )
    };
    let half = size.mul_scalar(0.5);
    let lx = half.clone().narrow(1, 0, 1) * signs(0); // [N, 8]
    let wz = half.clone().narrow(1, 1, 1) * signs(2);
    let hy = half.narrow(1, 2, 1) * signs(1);
    let (c, s) = (heading.clone().cos(), heading.sin());
    let x = c.clone() * lx.clone() + s.clone() * wz.clone() + center.clone().narrow(1, 0, 1);
    let y = hy + center.clone().narrow(1, 1, 1);
    let z = s.neg() * lx + c * wz + center.narrow(1, 2, 1);
    let out = Tensor::stack::<3>(vec![x, y, z], 2);
    debug_assert_eq!(out.dims(), [n, 8, 3]);
    out
}

/// F-ConvNet's loss for one batch. Fails with [`ModelError::NonFiniteLoss`] when any
/// term is NaN or infinite.
pub fn fconvnet_loss(
    output: &FConvNetOutput,
    targets: &LossTargets,
    config: &LossConfig,
) -> Result<LossOutput, ModelError> {
    let [b, p, _] = output.cls_logits.dims();
    if p != targets.positions {
        return Err(ModelError::Batch(format!(
            "the output has {p} positions, the targets {}",
            targets.positions
        )));
    }
    let device = output.cls_logits.device();
    let zero = || Tensor::<1>::zeros([1], &device);
    let normaliser = targets.num_positives.max(1) as f32;

    let cls = if targets.num_kept == 0 {
        zero()
    } else {
        let logits = output
            .cls_logits
            .clone()
            .reshape([b * p, 2])
            .select(0, targets.kept.clone());
        focal_loss(
            logits,
            targets.kept_labels.clone(),
            targets.kept_alpha.clone(),
            config.focal_gamma,
            normaliser,
        )
    };

    let box_terms = if targets.num_positives == 0 {
        None
    } else {
        Some(box_losses(output, targets, config, b * p))
    };
    let [
        center,
        heading_cls,
        heading_res,
        size_cls,
        size_res,
        corner,
        projection,
    ] = box_terms.unwrap_or_else(|| std::array::from_fn(|_| zero()));
    let box_total = center.clone()
        + heading_cls.clone()
        + size_cls.clone()
        + heading_res
            .clone()
            .mul_scalar(config.heading_residual_weight)
        + size_res.clone().mul_scalar(config.size_residual_weight)
        + corner.clone().mul_scalar(config.corner_weight);
    let total = cls.clone()
        + box_total.mul_scalar(config.box_weight)
        + projection.clone().mul_scalar(config.projection_weight);

    let values: Vec<f32> = Tensor::cat(
        vec![
            total.clone(),
            cls,
            center,
            heading_cls,
            heading_res,
            size_cls,
            size_res,
            corner,
            projection,
        ],
        0,
    )
    .detach()
    .try_into_vec_as::<f32>()
    .map_err(|e| ModelError::Batch(format!("reading the loss back: {e:?}")))?;
    let components = LossComponents {
        total: values[0],
        cls: values[1],
        center: values[2],
        heading_cls: values[3],
        heading_res: values[4],
        size_cls: values[5],
        size_res: values[6],
        corner: values[7],
        projection: values[8],
        num_positives: targets.num_positives,
    };
    check_finite(&components)?;
    Ok(LossOutput { total, components })
}

/// [`ModelError::NonFiniteLoss`] naming the first non-finite component.
pub fn check_finite(c: &LossComponents) -> Result<(), ModelError> {
    match c
        .named()
        .into_iter()
        .skip(1)
        .chain([("total", c.total)])
        .find(|(_, v)| !v.is_finite())
    {
        Some((component, value)) => Err(ModelError::NonFiniteLoss {
            component,
            value,
            total: c.total,
        }),
        None => Ok(()),
    }
}

/// Centre, heading class, heading residual, size class, size residual, corner, projection
/// (means over positives; projection zero when off).
fn box_losses(
    output: &FConvNetOutput,
    t: &LossTargets,
    config: &LossConfig,
    rows: usize,
) -> [Tensor<1>; 7] {
    let l = t.layout;
    let r = l.len();
    let reg = output
        .regression
        .clone()
        .reshape([rows, r])
        .select(0, t.positive.clone()); // [Np, R]
    let np = t.num_positives;
    let cols = |range: std::ops::Range<usize>| reg.clone().narrow(1, range.start, range.len());

    let center_pred = t.position_centers.clone() + cols(l.center());
    let center = huber(
        norm_last(t.center.clone() - center_pred.clone()),
        config.center_delta,
    )
    .mean();

    let heading_cls = log_softmax(cols(l.heading_scores()), 1)
        .gather(1, t.heading_bin.clone())
        .mean()
        .neg();
    let heading_res_pred = cols(l.heading_residuals()).gather(1, t.heading_bin.clone()); // [Np, 1]
    let heading_res = huber(
        heading_res_pred.clone() - t.heading_residual.clone(),
        config.residual_delta,
    )
    .mean();

    let size_cls = log_softmax(cols(l.size_scores()), 1)
        .gather(1, t.size_cluster.clone())
        .mean()
        .neg();
    let size_res_pred = cols(l.size_residuals())
        .reshape([np, l.size_clusters, 3])
        .gather(1, t.size_index.clone())
        .reshape([np, 3]);
    let size_res = huber(
        norm_last(t.size_residual.clone() - size_res_pred.clone()),
        config.residual_delta,
    )
    .mean();

    let heading = t.heading_bin_f.clone().mul_scalar(t.bin_width)
        + heading_res_pred.mul_scalar(t.bin_width / 2.0);
    let size = t.mean_size.clone() * size_res_pred.add_scalar(1.0);
    let corners = box_corners_tensor(center_pred, heading, size);
    let dist = |gt: &Tensor<3>| {
        norm_last(corners.clone() - gt.clone())
            .reshape([np, 8])
            .mean_dim(1)
    }; // [Np, 1]
    let corner_dist = dist(&t.corners).min_pair(dist(&t.corners_flipped));
    let corner = huber(corner_dist, config.corner_delta).mean();

    let projection = match &t.projection {
        Some((rows, proj, gt)) => {
            projection_loss(corners.select(0, rows.clone()), proj.clone(), gt.clone())
        }
        None => Tensor::zeros([1], &reg.device()),
    };
    [
        center,
        heading_cls,
        heading_res,
        size_cls,
        size_res,
        corner,
        projection,
    ]
}

/// Nearest depth a corner is projected at: corners behind the camera would flip sign.
const MIN_PROJECTION_DEPTH: f32 = 0.1;

/// The 2D box (centre u, centre v, width, height) of corners projected by a row-major 3 × 4
/// matrix; `None` when a corner lies behind the camera.
pub fn projected_box(corners: &[[f32; 3]; 8], m: &[f32; 12]) -> Option<[f32; 4]> {
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for c in corners {
        let row =
            |r: usize| m[4 * r] * c[0] + m[4 * r + 1] * c[1] + m[4 * r + 2] * c[2] + m[4 * r + 3];
        let z = row(2);
        if z < MIN_PROJECTION_DEPTH {
            return None;
        }
        for (d, v) in [row(0) / z, row(1) / z].into_iter().enumerate() {
            lo[d] = lo[d].min(v);
            hi[d] = hi[d].max(v);
        }
    }
    Some([
        0.5 * (lo[0] + hi[0]),
        0.5 * (lo[1] + hi[1]),
        (hi[0] - lo[0]).max(1e-3),
        (hi[1] - lo[1]).max(1e-3),
    ])
}

/// SAF's PL term: corners [Np, 8, 3] projected by [Np, 3, 4]; smooth-L1 (δ = 1) on
/// (Δu / w_gt, Δv / h_gt, ln(w / w_gt), ln(h / h_gt)), summed per box, mean over boxes.
pub fn projection_loss(corners: Tensor<3>, proj: Tensor<3>, gt: Tensor<2>) -> Tensor<1> {
    let [np, _, _] = corners.dims();
    let device = corners.device();
    let homogeneous = Tensor::cat(vec![corners, Tensor::ones([np, 8, 1], &device)], 2);
    let image = homogeneous.matmul(proj.swap_dims(1, 2)); // [Np, 8, 3]
    let z = image
        .clone()
        .narrow(2, 2, 1)
        .clamp_min(MIN_PROJECTION_DEPTH);
    let u = (image.clone().narrow(2, 0, 1) / z.clone()).reshape([np, 8]);
    let v = (image.narrow(2, 1, 1) / z).reshape([np, 8]);
    let (u0, u1) = (u.clone().min_dim(1), u.max_dim(1));
    let (v0, v1) = (v.clone().min_dim(1), v.max_dim(1));
    let col = |k: usize| gt.clone().narrow(1, k, 1);
    let (w_gt, h_gt) = (col(2), col(3));
    let w = (u1.clone() - u0.clone()).clamp_min(1e-3);
    let h = (v1.clone() - v0.clone()).clamp_min(1e-3);
    let du = ((u0 + u1).mul_scalar(0.5) - col(0)) / w_gt.clone();
    let dv = ((v0 + v1).mul_scalar(0.5) - col(1)) / h_gt.clone();
    let dw = (w / w_gt).log();
    let dh = (h / h_gt).log();
    huber(Tensor::cat(vec![du, dv, dw, dh], 1), 1.0)
        .sum_dim(1)
        .mean()
}
