//! Pooling over ragged groups of rows ("segments"): the points of a sub-frustum, the
//! pairs of a frustum, the points of a voxel. Segments are given by their row counts
//! and start rows in a flat [rows, C] tensor, so no group is padded to the largest.

use crate::gather::RowGather;
use crate::{host_max, ragged};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use std::sync::Arc;

/// Max-pooling of ragged rows into segments.
///
/// On the flex CPU device one pass over the rows: inference on the host
/// ([`host_max::runs_max`]), training through the custom operation with its own backward
/// ([`ragged::runs_max`]: the winning row per (segment, channel) kept, the gradient
/// scattered to it). Elsewhere, by gather ([`SegmentPool::max_pool_generic`]):
/// segments are grouped into buckets by their row count rounded up to a power of two; a
/// bucket of width w gathers [segments · w] rows — each segment's window repeats its own
/// rows (duplicates do not change a max) — and takes the max over the window. Empty
/// segments form a bucket of width 0 whose output is zeros (so the features need no zero
/// row appended: that was a copy of the whole [rows, C] tensor per pooling). Buckets keep
/// the gathered volume under twice the rows, where one window as wide as the fullest
/// segment would gather segments × cap rows. `restore` puts the bucket-ordered segments
/// back in segment order.
#[derive(Debug, Clone)]
pub struct SegmentPool {
    pub buckets: Vec<PoolBucket>,
    /// Each segment's start row and row count, for the host path of inference.
    pub starts: Vec<usize>,
    pub counts: Vec<usize>,
    /// The same runs for the custom training operation on the flex device.
    pub runs: Arc<ragged::Runs>,
    /// [num_segments]: row of each segment in the concatenated bucket outputs; `None`
    /// when that is already segment order.
    pub restore: Option<RowGather>,
    /// Rows the segments cover (the largest end): the buckets' source rows.
    rows: usize,
}

#[derive(Debug, Clone)]
pub struct PoolBucket {
    pub width: usize,
    pub num_segments: usize,
    /// [num_segments · width] rows into the features; a `RowGather`, so that on a GPU the
    /// windows' repeated rows add their gradients by readers (burn's `select` there walks
    /// every gathered row per column, and went wrong on lavapipe at size).
    pub index: RowGather,
}

impl SegmentPool {
    /// `counts[s]` rows in segment s, starting at row `starts[s]` (`starts` may hold more
    /// entries, e.g. a closing one).
    pub fn new(counts: &[usize], starts: &[usize], device: &Device) -> Self {
        let width = |c: usize| if c == 0 { 0 } else { c.next_power_of_two() };
        let mut by_width: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for (s, &c) in counts.iter().enumerate() {
            by_width.entry(width(c)).or_default().push(s);
        }
        let rows = counts
            .iter()
            .zip(starts)
            .map(|(&c, &s)| s + c)
            .max()
            .unwrap_or(0);
        let mut restore = vec![0u32; counts.len()];
        let mut next = 0;
        let buckets = by_width
            .into_iter()
            .map(|(w, segments)| {
                let mut index = Vec::with_capacity(segments.len() * w);
                for &s in &segments {
                    restore[s] = next;
                    next += 1;
                    let (start, n) = (starts[s], counts[s]);
                    index.extend((0..w).map(|j| (start + j % n) as u32));
                }
                PoolBucket {
                    width: w,
                    num_segments: segments.len(),
                    index: RowGather::new(&index, rows, device),
                }
            })
            .collect::<Vec<_>>();
        let in_order = restore.iter().enumerate().all(|(i, &r)| r as usize == i);
        let n = restore.len();
        Self {
            buckets,
            starts: starts[..counts.len()].to_vec(),
            counts: counts.to_vec(),
            runs: Arc::new(ragged::Runs::new(&starts[..counts.len()], counts)),
            restore: (!in_order).then(|| RowGather::new(&restore, n, device)),
            rows,
        }
    }

    /// Rows gathered in total (for diagnostics).
    pub fn gathered_rows(&self) -> usize {
        self.buckets.iter().map(|b| b.width * b.num_segments).sum()
    }

    /// Per-segment max of `features` ([rows, C]) → [num_segments, C]; an empty segment
    /// gives zeros.
    pub fn max_pool(&self, features: Tensor<2>) -> Tensor<2> {
        if host_max::host_path(&features) {
            return host_max::runs_max(features, &self.starts, &self.counts);
        }
        if ragged::custom_path(&features) {
            return ragged::runs_max(features, &self.runs);
        }
        self.max_pool_generic(features)
    }

    /// [`SegmentPool::max_pool`] by burn's generic operations (gather into the buckets,
    /// max over each window), on any backend: what other devices run, and the reference
    /// the custom operation is tested against.
    pub fn max_pool_generic(&self, features: Tensor<2>) -> Tensor<2> {
        let [rows, c] = features.dims();
        // Rows past every segment are read by none (the buckets' gathers take exactly
        // their source rows).
        let features = if rows > self.rows {
            features.slice([0..self.rows, 0..c])
        } else {
            features
        };
        let parts: Vec<Tensor<2>> = self
            .buckets
            .iter()
            .map(|b| {
                if b.width == 0 {
                    return Tensor::zeros([b.num_segments, c], &features.device());
                }
                let rows = b.index.gather(features.clone());
                if b.width == 1 {
                    rows
                } else {
                    rows.reshape([b.num_segments, b.width, c])
                        .max_dim(1)
                        .reshape([b.num_segments, c])
                }
            })
            .collect();
        let pooled = if parts.len() == 1 {
            parts.into_iter().next().unwrap()
        } else {
            Tensor::cat(parts, 0)
        };
        match &self.restore {
            Some(r) => r.gather(pooled),
            None => pooled,
        }
    }
}

/// Per-segment mean of `features` ([rows, C]) where row r belongs to segment
/// `segment_of_row[r]`: a differentiable scatter-add, then a division by each segment's
/// row count (an empty segment gives zeros). The mean voxel feature of a voxel encoder.
pub fn segment_mean(
    features: Tensor<2>,
    segment_of_row: &[usize],
    num_segments: usize,
) -> Tensor<2> {
    let [rows, c] = features.dims();
    assert_eq!(rows, segment_of_row.len(), "one segment per row");
    let device = features.device();
    let mut counts = vec![0f32; num_segments];
    for &s in segment_of_row {
        counts[s] += 1.0;
    }
    let inverse: Vec<f32> = counts
        .iter()
        .map(|&n| if n > 0.0 { 1.0 / n } else { 0.0 })
        .collect();
    let index: Vec<i64> = segment_of_row.iter().map(|&s| s as i64).collect();
    let sums = Tensor::<2>::zeros([num_segments, c], &device).select_assign(
        0,
        Tensor::from_data(TensorData::new(index, [rows]), &device),
        features,
        IndexingUpdateOp::Add,
    );
    sums * Tensor::<2>::from_data(TensorData::new(inverse, [num_segments, 1]), &device)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(values: &[[f32; 2]], device: &Device) -> Tensor<2> {
        let flat: Vec<f32> = values.iter().flatten().copied().collect();
        Tensor::from_data(TensorData::new(flat, [values.len(), 2]), device)
    }

    #[test]
    fn max_pool_matches_a_loop_with_empty_and_uneven_segments() {
        let device = Device::flex();
        let data = [
            [1.0, -2.0],
            [3.0, 0.5],
            [-1.0, 4.0],
            [2.0, 2.0],
            [0.0, -5.0],
        ];
        // Segments: rows 0..2, empty, rows 2..5.
        let (counts, starts) = ([2, 0, 3], [0, 2, 2]);
        let pool = SegmentPool::new(&counts, &starts, &device);
        let out: Vec<f32> = pool
            .max_pool(rows(&data, &device))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(out, vec![3.0, 0.5, 0.0, 0.0, 2.0, 4.0]);
        // The empty segment gathers nothing.
        assert_eq!(pool.gathered_rows(), 2 + 4);
    }

    #[test]
    fn mean_matches_a_loop_and_has_gradients() {
        let device = Device::flex().autodiff();
        let data = [[1.0, -2.0], [3.0, 0.5], [-1.0, 4.0], [2.0, 2.0]];
        let x = rows(&data, &device).require_grad();
        let mean = segment_mean(x.clone(), &[0, 2, 0, 2], 3);
        let out: Vec<f32> = mean.clone().into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(out, vec![0.0, 1.0, 0.0, 0.0, 2.5, 1.25]);
        let grads = mean.sum().backward();
        let g: Vec<f32> = x
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(g, vec![0.5; 8]);
    }
}
