//! From a [`FrustumBatch`] (flat host arrays) to the tensors the network consumes.
//!
//! The host-side work — validating the batch, point-minus-slice-centre coordinates of every
//! (point, sub-frustum) pair, and the gather index that max-pools the pairs per slice — is
//! done here, once per batch, so a data loader can run it off the training thread.

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::lfa::LfaInputs;
use burn::prelude::*;
use fusiondet_frustum::{BatchScale, FrustumBatch};
use fusiondet_nn::SegmentPool;
use fusiondet_nn::gather::RowGather;

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
    pub pool: SegmentPool,
    /// Indices for FCAM's attention; built only when the encoder needs them.
    pub attention: Option<AttentionIndex>,
    /// [num_pairs]: each pair's row in the LFA feature tensor (SAF only).
    pub pair_feature_row: Option<RowGather>,
    /// Host copies, for building the padded form on demand.
    rel_host: Vec<f32>,
    slice_start: Vec<usize>,
}

/// How CBAM reaches one scale's pairs per frustum (channel attention) and on the
/// (sub-frustum × point) grid (spatial attention); see [`crate::attention`].
#[derive(Debug, Clone)]
pub struct AttentionIndex {
    pub frustums: usize,
    pub slices_per_frustum: usize,
    /// Grid columns: the scale's cap on points per sub-frustum.
    pub cap: usize,
    /// [pairs]: the frustum of each pair (`index()` on the device), its gather of frustum
    /// rows to pairs and its sums of pair rows into frustums. The three gathers are
    /// `RowGather`s: burn's `select` (and `select_assign` for the sums) on the CPU; on a GPU
    /// additions by each row's readers, where burn's walk every row per column.
    pub pair_frustum: RowGather,
    /// [frustums, 1]: pairs per frustum, at least 1 (the mean's divisor).
    pub frustum_counts: Tensor<2>,
    /// Max-pools pair rows into frustums.
    pub frustum_pool: SegmentPool,
    /// [frustums · slices · cap]: the pair in each grid cell, `pairs` (the gather's zero
    /// row) if empty.
    pub grid_cell_pair: RowGather,
    /// [pairs]: the grid cell of each pair.
    pub pair_grid_cell: RowGather,
    /// The same cells on the host, for CBAM's host path in inference.
    pub pair_grid_cell_host: Vec<u32>,
}

impl AttentionIndex {
    /// `slice_start` has one entry per slice plus the end; pairs are in slice order and
    /// slices frustum-major, so each frustum's pairs are contiguous.
    fn new(
        slice_start: &[usize],
        frustums: usize,
        slices_per_frustum: usize,
        cap: usize,
        device: &Device,
    ) -> Self {
        let num_pairs = *slice_start.last().unwrap_or(&0);
        let mut pair_frustum = Vec::with_capacity(num_pairs);
        let mut pair_cell = Vec::with_capacity(num_pairs);
        let cells = frustums * slices_per_frustum * cap;
        let mut cell_pair = vec![num_pairs as u32; cells];
        for (sl, w) in slice_start.windows(2).enumerate() {
            for (j, pair) in (w[0]..w[1]).enumerate() {
                let cell = sl * cap + j;
                pair_frustum.push((sl / slices_per_frustum) as u32);
                pair_cell.push(cell as u32);
                cell_pair[cell] = pair as u32;
            }
        }
        let starts: Vec<usize> = (0..=frustums)
            .map(|f| slice_start[f * slices_per_frustum])
            .collect();
        let counts: Vec<usize> = starts.windows(2).map(|w| w[1] - w[0]).collect();
        let counts_f: Vec<f32> = counts.iter().map(|&c| c.max(1) as f32).collect();
        Self {
            frustums,
            slices_per_frustum,
            cap,
            pair_frustum: RowGather::with_sums(&pair_frustum, frustums, device),
            frustum_counts: Tensor::from_data(TensorData::new(counts_f, [frustums, 1]), device),
            frustum_pool: SegmentPool::new(&counts, &starts, device),
            grid_cell_pair: RowGather::new(&cell_pair, num_pairs, device),
            pair_grid_cell: RowGather::new(&pair_cell, cells, device),
            pair_grid_cell_host: pair_cell,
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
    /// SAF's neighbour indices, when the network has LFA.
    pub lfa: Option<LfaInputs>,
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
        let lfa = config
            .lfa
            .as_ref()
            .map(|l| LfaInputs::new(&batch.points, b, batch.points_per_frustum, l, device))
            .transpose()?;
        // Points that survive LFA's halvings, per frustum (all of them without LFA).
        let surviving = config.lfa.as_ref().map_or(batch.points_per_frustum, |l| {
            batch.points_per_frustum >> l.stages.len()
        });
        let scales = batch
            .scales
            .iter()
            .enumerate()
            .map(|(k, s)| {
                let mut scale = ScaleInputs::new(
                    k,
                    s,
                    b,
                    &batch.points,
                    num_points,
                    config.slice_encoder.uses_attention(),
                    device,
                )?;
                if lfa.is_some() {
                    scale.pair_feature_row = Some(pair_feature_rows(
                        k,
                        &s.pair_point,
                        batch.points_per_frustum,
                        surviving,
                        b,
                        device,
                    )?);
                }
                Ok(scale)
            })
            .collect::<Result<Vec<_>, ModelError>>()?;
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
            lfa,
            device: device.clone(),
        })
    }

    pub fn device(&self) -> &Device {
        &self.device
    }
}

/// Rows of the pairs' points among LFA's survivors: point i < `surviving` of frustum f
/// (row f · n0 + i of the batch) is row f · surviving + i of the LFA features.
fn pair_feature_rows(
    k: usize,
    pair_point: &[i64],
    n0: usize,
    surviving: usize,
    frustums: usize,
    device: &Device,
) -> Result<RowGather, ModelError> {
    let mut rows = Vec::with_capacity(pair_point.len());
    for &p in pair_point {
        let (f, i) = (p as usize / n0, p as usize % n0);
        if i >= surviving {
            return Err(ModelError::Batch(format!(
                "scale {k}: a sub-frustum uses point {i} of its frustum, but only the first \
                 {surviving} survive LFA's halvings; set frustum.sliced_points = {surviving}"
            )));
        }
        rows.push((f * surviving + i) as u32);
    }
    Ok(RowGather::new(&rows, frustums * surviving, device))
}

impl ScaleInputs {
    fn new(
        k: usize,
        s: &BatchScale,
        batch_size: usize,
        points: &[f32],
        num_points: usize,
        with_attention: bool,
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
        if !s.relative_depth_gains.is_empty() && s.relative_depth_gains.len() != num_slices {
            return err(format!(
                "relative_depth_gains has {} values, expected {num_slices}",
                s.relative_depth_gains.len()
            ));
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
            if let Some(&gain) = s.relative_depth_gains.get(sl) {
                // z is the depth along the frustum (see `fusiondet_frustum::batch`).
                *rel.last_mut().expect("three pushed") *= gain;
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
        let pool = SegmentPool::new(&counts, &slice_start, device);
        let cap = s.max_points_per_slice.max(1);
        let attention = with_attention.then(|| {
            AttentionIndex::new(&slice_start, batch_size, s.slices_per_frustum, cap, device)
        });
        Ok(Self {
            num_slices,
            slices_per_frustum: s.slices_per_frustum,
            num_pairs,
            cap,
            attention,
            pair_feature_row: None,
            rel_coords: Tensor::from_data(TensorData::new(rel.clone(), [num_pairs, 3]), device),
            pool,
            rel_host: rel,
            slice_start,
        })
    }

    /// Row offsets of each slice's pairs, plus the end.
    pub fn slice_start(&self) -> &[usize] {
        &self.slice_start
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{SyntheticSpec, synthetic_batch};

    /// A sub-frustum's depth gain multiplies the depth (z) of its pairs' relative
    /// coordinates and nothing else; a gain list of the wrong length is refused.
    #[test]
    fn relative_depth_gains_scale_only_the_depth_of_their_sub_frustum() {
        let device = Device::flex();
        let config = ModelConfig::tiny();
        let plain = synthetic_batch(&SyntheticSpec::tiny(2), 3);
        let mut gained = plain.clone();
        let scale = &mut gained.scales[0];
        let per = scale.slices_per_frustum;
        scale.relative_depth_gains = (0..2 * per)
            .map(|sl: usize| if sl.is_multiple_of(per) { 0.25 } else { 1.0 })
            .collect();
        let a = BatchInputs::new(&plain, &config, &device).unwrap();
        let b = BatchInputs::new(&gained, &config, &device).unwrap();
        let pair_slice = &plain.scales[0].pair_slice;
        let (ra, rb) = (&a.scales[0].rel_host, &b.scales[0].rel_host);
        let mut in_first = 0;
        for (pair, &sl) in pair_slice.iter().enumerate() {
            let gain = if (sl as usize).is_multiple_of(per) {
                0.25
            } else {
                1.0
            };
            in_first += usize::from(gain != 1.0);
            assert_eq!(rb[pair * 3], ra[pair * 3]);
            assert_eq!(rb[pair * 3 + 1], ra[pair * 3 + 1]);
            assert_eq!(rb[pair * 3 + 2], ra[pair * 3 + 2] * gain);
        }
        assert!(
            in_first > 0,
            "the synthetic batch has pairs in a first sub-frustum"
        );
        for k in 1..a.scales.len() {
            assert_eq!(a.scales[k].rel_host, b.scales[k].rel_host);
        }
        gained.scales[0].relative_depth_gains.pop();
        let e = BatchInputs::new(&gained, &config, &device).unwrap_err();
        assert!(e.to_string().contains("relative_depth_gains"), "{e}");
    }
}
