//! From a [`FrustumBatch`] (flat host arrays) to the tensors the network consumes.
//!
//! The host-side work — validating the batch, point-minus-slice-centre coordinates of every
//! (point, sub-frustum) pair, and the gather index that max-pools the pairs per slice — is
//! done here, once per batch, so a data loader can run it off the training thread.

use crate::config::ModelConfig;
use crate::error::ModelError;
use burn::prelude::*;
use fusiondet_frustum::{BatchScale, FrustumBatch};

/// The output length of a kernel-3, padding-1 convolution with the given stride.
pub fn conv3_output_len(len: usize, stride: usize) -> usize {
    (len + 2 - 3) / stride + 1
}

/// One scale's ragged (point, slice) pairs as tensors.
#[derive(Debug, Clone)]
pub struct ScaleInputs {
    /// Slices of the whole batch (batch · slices per frustum).
    pub num_slices: usize,
    pub slices_per_frustum: usize,
    /// Real (point, slice) pairs.
    pub num_pairs: usize,
    /// The batch's cap on pairs per slice at this scale.
    pub cap: usize,
    /// Pair coordinates relative to their slice centre, [num_pairs, 3].
    pub rel_coords: Tensor<2>,
    /// How the ragged form max-pools the pair features into slices.
    pub pool: SlicePool,
    /// Host copies, for building the padded form on demand.
    rel_host: Vec<f32>,
    slice_start: Vec<usize>,
}

/// Max-pooling of ragged pair rows into slices, by gather.
///
/// The pair features get a zero row appended (row `num_pairs`). Slices are grouped into
/// buckets by their pair count rounded up to a power of two; a bucket of width w gathers
/// [slices · w] rows — each slice's window repeats its own pairs (duplicates do not change
/// a max), an empty slice points at the zero row — and takes the max over the window.
/// Buckets keep the gathered volume under twice the pairs plus the slices, where one
/// window as wide as the fullest slice would gather slices × cap rows. `restore` puts the
/// bucket-ordered slices back in slice order.
#[derive(Debug, Clone)]
pub struct SlicePool {
    pub buckets: Vec<PoolBucket>,
    /// [num_slices]: row of each slice in the concatenated bucket outputs; `None` when
    /// that is already slice order.
    pub restore: Option<Tensor<1, Int>>,
}

#[derive(Debug, Clone)]
pub struct PoolBucket {
    pub width: usize,
    pub num_slices: usize,
    /// [num_slices · width] rows into the pair features (with the zero row).
    pub index: Tensor<1, Int>,
}

impl SlicePool {
    /// `counts[s]` pairs per slice, slice s's pairs starting at row `starts[s]`.
    fn new(counts: &[usize], starts: &[usize], num_pairs: usize, device: &Device) -> Self {
        let width = |c: usize| c.max(1).next_power_of_two();
        let mut by_width: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for (s, &c) in counts.iter().enumerate() {
            by_width.entry(width(c)).or_default().push(s);
        }
        let mut restore = vec![0i64; counts.len()];
        let mut next = 0;
        let buckets = by_width
            .into_iter()
            .map(|(w, slices)| {
                let mut index = Vec::with_capacity(slices.len() * w);
                for &s in &slices {
                    restore[s] = next;
                    next += 1;
                    let (start, n) = (starts[s], counts[s]);
                    index.extend(
                        (0..w).map(|j| if n == 0 { num_pairs } else { start + j % n } as i64),
                    );
                }
                PoolBucket {
                    width: w,
                    num_slices: slices.len(),
                    index: Tensor::from_data(TensorData::new(index, [slices.len() * w]), device),
                }
            })
            .collect::<Vec<_>>();
        let in_order = restore.iter().enumerate().all(|(i, &r)| r == i as i64);
        let n = restore.len();
        Self {
            buckets,
            restore: (!in_order).then(|| Tensor::from_data(TensorData::new(restore, [n]), device)),
        }
    }

    /// Rows gathered in total (for diagnostics).
    pub fn gathered_rows(&self) -> usize {
        self.buckets.iter().map(|b| b.width * b.num_slices).sum()
    }

    /// Per-slice max of `features` ([num_pairs + 1, C], the last row zero) → [num_slices, C].
    pub fn max_pool(&self, features: Tensor<2>) -> Tensor<2> {
        let c = features.dims()[1];
        let parts: Vec<Tensor<2>> = self
            .buckets
            .iter()
            .map(|b| {
                let rows = features.clone().select(0, b.index.clone());
                if b.width == 1 {
                    rows
                } else {
                    rows.reshape([b.num_slices, b.width, c])
                        .max_dim(1)
                        .reshape([b.num_slices, c])
                }
            })
            .collect();
        let pooled = if parts.len() == 1 {
            parts.into_iter().next().unwrap()
        } else {
            Tensor::cat(parts, 0)
        };
        match &self.restore {
            Some(r) => pooled.select(0, r.clone()),
            None => pooled,
        }
    }
}

/// The padded form of one scale: every slice padded to the cap, with masks.
#[derive(Debug, Clone)]
pub struct PaddedScaleInputs {
    pub num_slices: usize,
    pub cap: usize,
    /// [num_slices · cap, 3]; padding rows are zero.
    pub coords: Tensor<2>,
    /// [num_slices · cap, 1]: 1 for real pairs, 0 for padding.
    pub valid: Tensor<2>,
    /// [num_slices · cap, 1]: true for padding rows.
    pub padding: Tensor<2, Bool>,
    /// [num_slices, 1]: true for slices without any pair.
    pub empty: Tensor<2, Bool>,
    pub num_pairs: usize,
}

/// Everything the network's forward pass needs for one batch.
#[derive(Debug, Clone)]
pub struct BatchInputs {
    pub batch_size: usize,
    /// The four scales, finest first.
    pub scales: Vec<ScaleInputs>,
    /// [batch, num_classes].
    pub class_one_hot: Tensor<2>,
    /// Output positions per frustum (the slices of the output scale).
    pub positions: usize,
    /// Output position centres, [batch · positions · 3] (host copy, frustum-major).
    pub position_centers: Vec<f32>,
    device: Device,
}

impl BatchInputs {
    /// Validates `batch` against the network and builds its tensors on `device`.
    pub fn new(
        batch: &FrustumBatch,
        config: &ModelConfig,
        device: &Device,
    ) -> Result<Self, ModelError> {
        let err = |msg: String| Err(ModelError::Batch(msg));
        let b = batch.batch_size;
        if b == 0 {
            return err("empty batch".into());
        }
        let num_points = b * batch.points_per_frustum;
        if batch.points.len() != num_points * 3 {
            return err(format!(
                "points has {} values, expected batch {b} × {} points × 3",
                batch.points.len(),
                batch.points_per_frustum
            ));
        }
        if batch.class_one_hot.len() != b * config.num_classes {
            return err(format!(
                "class_one_hot has {} values, expected {b} × {}",
                batch.class_one_hot.len(),
                config.num_classes
            ));
        }
        if batch.scales.len() != config.pointnet_widths.len() {
            return err(format!(
                "{} scales, the network has {}",
                batch.scales.len(),
                config.pointnet_widths.len()
            ));
        }
        if batch.output_scale != 1 {
            return err(format!(
                "output_scale is {}; F-ConvNet predicts at scale 1 (the block-2 resolution)",
                batch.output_scale
            ));
        }
        for k in 1..batch.scales.len() {
            let prev = batch.scales[k - 1].slices_per_frustum;
            let want = conv3_output_len(prev, 2);
            if batch.scales[k].slices_per_frustum != want {
                return err(format!(
                    "scale {k} has {} slices per frustum; a stride-2 convolution over the {prev} \
                     slices of scale {} gives {want}",
                    batch.scales[k].slices_per_frustum,
                    k - 1
                ));
            }
        }
        let scales = batch
            .scales
            .iter()
            .enumerate()
            .map(|(k, s)| ScaleInputs::new(k, s, b, &batch.points, num_points, device))
            .collect::<Result<Vec<_>, _>>()?;
        let out = &batch.scales[batch.output_scale];
        let class_one_hot = Tensor::from_data(
            TensorData::new(batch.class_one_hot.clone(), [b, config.num_classes]),
            device,
        );
        Ok(Self {
            batch_size: b,
            positions: out.slices_per_frustum,
            position_centers: out.slice_centers.clone(),
            scales,
            class_one_hot,
            device: device.clone(),
        })
    }

    pub fn device(&self) -> &Device {
        &self.device
    }
}

impl ScaleInputs {
    fn new(
        k: usize,
        s: &BatchScale,
        batch_size: usize,
        points: &[f32],
        num_points: usize,
        device: &Device,
    ) -> Result<Self, ModelError> {
        let err = |msg: String| Err(ModelError::Batch(format!("scale {k}: {msg}")));
        let num_slices = batch_size * s.slices_per_frustum;
        if s.slices_per_frustum == 0 {
            return err("no slices".into());
        }
        if s.slice_centers.len() != num_slices * 3 {
            return err(format!(
                "slice_centers has {} values, expected {num_slices} × 3",
                s.slice_centers.len()
            ));
        }
        if s.pair_point.len() != s.pair_slice.len() {
            return err("pair_point and pair_slice differ in length".into());
        }
        let num_pairs = s.pair_point.len();
        let mut rel = Vec::with_capacity(num_pairs * 3);
        let mut counts = vec![0usize; num_slices];
        let mut last = 0i64;
        for (&p, &sl) in s.pair_point.iter().zip(&s.pair_slice) {
            if p < 0 || p as usize >= num_points {
                return err(format!("pair point {p} outside 0..{num_points}"));
            }
            if sl < last || sl as usize >= num_slices {
                return err(format!(
                    "pair slice {sl} out of order or outside 0..{num_slices} (must be non-decreasing)"
                ));
            }
            last = sl;
            let (p, sl) = (p as usize, sl as usize);
            if p / (num_points / batch_size) != sl / s.slices_per_frustum {
                return err(format!(
                    "pair joins point {p} and slice {sl} of different frustums"
                ));
            }
            counts[sl] += 1;
            for d in 0..3 {
                rel.push(points[p * 3 + d] - s.slice_centers[sl * 3 + d]);
            }
        }
        let fullest = counts.iter().copied().max().unwrap_or(0);
        if fullest > s.max_points_per_slice {
            return err(format!(
                "a slice holds {fullest} pairs, more than the cap {}",
                s.max_points_per_slice
            ));
        }
        let mut slice_start = Vec::with_capacity(num_slices + 1);
        slice_start.push(0);
        for c in &counts {
            slice_start.push(slice_start.last().unwrap() + c);
        }
        let pool = SlicePool::new(&counts, &slice_start, num_pairs, device);
        Ok(Self {
            num_slices,
            slices_per_frustum: s.slices_per_frustum,
            num_pairs,
            cap: s.max_points_per_slice.max(1),
            rel_coords: Tensor::from_data(TensorData::new(rel.clone(), [num_pairs, 3]), device),
            pool,
            rel_host: rel,
            slice_start,
        })
    }

    /// The padded form: every slice's pairs followed by zero rows up to the cap.
    pub fn padded(&self, device: &Device) -> PaddedScaleInputs {
        let (s, cap) = (self.num_slices, self.cap);
        let mut coords = vec![0f32; s * cap * 3];
        let mut valid = vec![0f32; s * cap];
        let empty: Vec<bool> = self.slice_start.windows(2).map(|w| w[0] == w[1]).collect();
        for sl in 0..s {
            let (start, end) = (self.slice_start[sl], self.slice_start[sl + 1]);
            for (j, pair) in (start..end).enumerate() {
                let row = sl * cap + j;
                coords[row * 3..row * 3 + 3]
                    .copy_from_slice(&self.rel_host[pair * 3..pair * 3 + 3]);
                valid[row] = 1.0;
            }
        }
        let padding: Vec<bool> = valid.iter().map(|v| *v == 0.0).collect();
        PaddedScaleInputs {
            num_slices: s,
            cap,
            coords: Tensor::from_data(TensorData::new(coords, [s * cap, 3]), device),
            valid: Tensor::from_data(TensorData::new(valid, [s * cap, 1]), device),
            padding: Tensor::from_data(TensorData::new(padding, [s * cap, 1]), device),
            empty: Tensor::from_data(TensorData::new(empty, [s, 1]), device),
            num_pairs: self.num_pairs,
        }
    }
}
