//! Rows gathered by an index made on the host, differentiated on GPUs by each source row's
//! list of readers.
//!
//! Why: burn differentiates `select` through `select_assign` with `Add`, and its CubeCL
//! kernel for that gives each column one thread that walks every gathered row in turn:
//! gradients of [M, C] gathered rows go back with C threads of M serial steps each (a RoI
//! grid pooling level of 128 RoIs · 216 grid points · 16 samples: 442,368 steps on each of
//! 32 threads), and on wgpu over lavapipe its sums came out wrong at that size
//! (`pipeline::sparse_gradient_probe`). With the index on the host its transpose is cheap to
//! build there: for every source row, the gathered rows that read it, in ascending order.
//! On a CubeCL device (`gather_device`, features `wgpu` / `cuda`) the backward pass is one
//! thread a source value adding its readers' gradients in that order: every value written
//! by one thread, no atomics, the same bits run after run. On the CPU (and any other
//! backend) the gather stays burn's `select`, whose results every pinned file was made with.

use crate::row_pairs::RowPairs;
use burn::prelude::*;

/// A gather's index on its device, and on CubeCL devices its readers, for the backward pass.
/// An index equal to the source's row count reads a row of zeros (an empty voxel, cell or
/// neighbour slot), which gets no gradient: its readers, often most gathered rows, are not
/// listed, so no thread walks them.
#[derive(Debug, Clone)]
pub struct RowGather {
    /// [M] source rows, one a gathered row (`source_rows`: the zero row).
    index: Tensor<1, Int>,
    source_rows: usize,
    /// Whether any gathered row reads the zero row.
    reads_zeros: bool,
    /// On differentiating CubeCL devices: (starts [N + 1], or [N + 2] with the zero row,
    /// readers); source row n is read by gathered rows `readers[starts[n]..starts[n + 1]]`,
    /// ascending.
    #[cfg_attr(not(any(feature = "wgpu", feature = "cuda")), allow(dead_code))]
    readers: Option<(Tensor<1, Int>, Tensor<1, Int>)>,
}

impl RowGather {
    /// Gathered row m reads source row `index[m]` of `source_rows`, or zeros where it is
    /// `source_rows` (past that it panics: an index is built by the caller, never read from a
    /// user's file).
    pub fn new(index: &[u32], source_rows: usize, device: &Device) -> Self {
        Self::build(index, source_rows, false, device)
    }

    /// [`RowGather::new`] for an index that also sums rows into their sources
    /// ([`RowGather::sum_by_source`]): its readers are listed on every CubeCL device, not
    /// only where a backward pass reads them. No row may read the zero row.
    pub fn with_sums(index: &[u32], source_rows: usize, device: &Device) -> Self {
        let gather = Self::build(index, source_rows, true, device);
        assert!(
            !gather.reads_zeros,
            "a summed index names a source row everywhere"
        );
        gather
    }

    /// A gather by an index made on the device: `index` [M] names rows 0..=`source_rows`, the
    /// last the zero row, for values on `values_device`. Where that is a CubeCL device that
    /// differentiates, the index is turned around there (`gather_device::turn_around`: the
    /// same readers in the same order as [`RowGather::new`] lists for the same index, so the
    /// same gradients to the bit); the zero row is appended whether or not a row reads it.
    /// The values' device decides, not the index's: a kernel makes its index on the device
    /// without autodiff (the RoI grid query's), and judged by it a training step's gather
    /// fell back to burn's `select`, whose backward walks every row per column.
    pub fn from_device_index(
        index: Tensor<1, Int>,
        source_rows: usize,
        values_device: &Device,
    ) -> Self {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        let readers = (on_cube_device(values_device) && values_device.is_autodiff())
            .then(|| crate::gather_device::turn_around(&index, source_rows));
        #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
        let readers = {
            let _ = values_device;
            None
        };
        Self {
            index,
            source_rows,
            reads_zeros: true,
            readers,
        }
    }

    fn build(index: &[u32], source_rows: usize, sums: bool, device: &Device) -> Self {
        for &n in index {
            assert!((n as usize) <= source_rows, "row {n} of {source_rows}");
        }
        let reads_zeros = index.iter().any(|&n| n as usize == source_rows);
        let m = index.len();
        let as_i64: Vec<i64> = index.iter().map(|&n| n as i64).collect();
        let index_tensor = Tensor::<1, Int>::from_data(TensorData::new(as_i64, [m]), device);
        // Only a differentiating device runs the backward pass that reads them, and the
        // sums' forward pass.
        let readers = (on_cube_device(device) && (sums || device.is_autodiff())).then(|| {
            let (mut starts, readers) = readers_of(index, source_rows);
            if reads_zeros {
                // The appended zero row, with no reader listed: its gradient is zeros.
                starts.push(starts[source_rows]);
            }
            let (rows, listed) = (starts.len(), readers.len());
            (
                Tensor::<1, Int>::from_data(TensorData::new(starts, [rows]), device),
                Tensor::<1, Int>::from_data(TensorData::new(readers, [listed]), device),
            )
        });
        Self {
            index: index_tensor,
            source_rows,
            reads_zeros,
            readers,
        }
    }

    /// The [M] index on its device.
    pub fn index(&self) -> &Tensor<1, Int> {
        &self.index
    }

    /// Whether the readers are listed on a CubeCL device: a backward pass (and
    /// [`RowGather::sum_by_source`]) then adds each source row's readers there, not through
    /// burn's `select_assign`.
    pub fn sums_readers_on_device(&self) -> bool {
        self.readers.is_some()
    }

    /// How many rows the gather reads from (besides the zero row).
    pub fn source_rows(&self) -> usize {
        self.source_rows
    }

    /// `values` [N, C] → [M, C], row m being `values[index[m]]` (zeros for index N).
    pub fn gather(&self, values: Tensor<2>) -> Tensor<2> {
        let [rows, c] = values.dims();
        assert_eq!(rows, self.source_rows, "values of the gather's source rows");
        // The zero row appended, as the callers did before: the same operations on the
        // CPU, so the same bits.
        let values = if self.reads_zeros {
            let device = values.device();
            Tensor::cat(vec![values, Tensor::zeros([1, c], &device)], 0)
        } else {
            values
        };
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if let Some((starts, readers)) = &self.readers
            && on_cube_device(&values.device())
        {
            return crate::gather_device::gather_rows(values, &self.index, starts, readers);
        }
        values.select(0, self.index.clone())
    }

    /// The gather turned around: `values` [M, C] → [N, C], source row n the sum of the rows
    /// that read it (zeros where none does): a segment sum by a host index, as CBAM's
    /// per-frustum means take it. On the CPU burn's `select_assign` with `Add` (the bits
    /// every pinned result was made with); on a CubeCL device, for an index made by
    /// [`RowGather::with_sums`], one thread a source value adding its readers in ascending
    /// order (`select_assign` there walks every row per column, and on lavapipe went wrong
    /// at size), differentiated by a gather.
    pub fn sum_by_source(&self, values: Tensor<2>) -> Tensor<2> {
        let [rows, c] = values.dims();
        assert_eq!(rows, self.index.dims()[0], "values of the gathered rows");
        assert!(
            !self.reads_zeros,
            "a summed index names a source row everywhere"
        );
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if let Some((starts, readers)) = &self.readers
            && on_cube_device(&values.device())
        {
            return crate::gather_device::sum_rows(values, &self.index, starts, readers);
        }
        let device = values.device();
        Tensor::<2>::zeros([self.source_rows, c], &device).select_assign(
            0,
            self.index.clone(),
            values,
            burn::tensor::IndexingUpdateOp::Add,
        )
    }
}

/// Whether `device` runs CubeCL kernels (only in a GPU build).
fn on_cube_device(device: &Device) -> bool {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    {
        crate::cube::cube_runtime(device).is_some()
    }
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    {
        let _ = device;
        false
    }
}

/// The index turned around: (starts [N + 1], readers) with source row n read by gathered
/// rows `readers[starts[n]..starts[n + 1]]`, in ascending order; the zero row's readers are
/// left out. The index as one list turned around by [`RowPairs`], the zero row counted as
/// row N: its readers come last, and are cut off.
pub(crate) fn readers_of(index: &[u32], source_rows: usize) -> (Vec<i64>, Vec<i64>) {
    let by_row = RowPairs::new(source_rows + 1, std::iter::once(index));
    let starts: Vec<i64> = by_row.starts()[..=source_rows]
        .iter()
        .map(|&s| s as i64)
        .collect();
    let listed = by_row.starts()[source_rows];
    let readers = by_row.entries()[..listed]
        .iter()
        .map(|&(_, m)| m as i64)
        .collect();
    (starts, readers)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readers_list_every_gathered_row_under_its_source_in_order() {
        let (starts, readers) = readers_of(&[2, 0, 2, 3, 2], 5);
        assert_eq!(starts, vec![0, 1, 1, 4, 5, 5]);
        assert_eq!(readers, vec![1, 0, 2, 4, 3]);
        // Row 4 of 4 is the zero row: read, never listed.
        let (starts, readers) = readers_of(&[4, 1, 4, 0], 4);
        assert_eq!(starts, vec![0, 1, 2, 2, 2]);
        assert_eq!(readers, vec![3, 1]);
    }

    /// On the CPU the gather is burn's `select` after the zero row: the same values and
    /// gradients, to the bit.
    #[test]
    fn on_the_cpu_it_is_select() {
        let device = Device::flex().autodiff();
        let values: Vec<f32> = (0..12).map(|v| v as f32 * 0.37 - 1.0).collect();
        let index = [2u32, 0, 2, 3, 2, 4];
        let gather = RowGather::new(&index, 4, &device);
        let run = |ours: bool| {
            let x = Tensor::<2>::from_data(TensorData::new(values.clone(), [4, 3]), &device)
                .require_grad();
            let y = if ours {
                gather.gather(x.clone())
            } else {
                Tensor::cat(vec![x.clone(), Tensor::zeros([1, 3], &device)], 0)
                    .select(0, gather.index().clone())
            };
            let weights: Vec<f32> = (0..18).map(|v| v as f32 - 4.0).collect();
            let loss =
                (y.clone() * Tensor::from_data(TensorData::new(weights, [6, 3]), &device)).sum();
            let grads = loss.backward();
            (
                y.try_into_vec_as::<f32>().unwrap(),
                x.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap(),
            )
        };
        assert_eq!(run(true), run(false));
    }
}
