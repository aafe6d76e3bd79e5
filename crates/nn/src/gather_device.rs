//! [`crate::gather::RowGather`] on burn's GPU backends: burn's `select` forward, and a
//! backward pass of one thread a source value, `dx[n, c] = Σ_j dy[readers[j], c]` over
//! `starts[n] ≤ j < starts[n + 1]` in that order (see the `gather` module for why).
//! Inputs are indexed by their strides and the gradient written one-dimensional, as the
//! sparse convolution's kernels do (`sparse::device_kernels`: CUDA pads 2-D rows).

use crate::cube::{f32_buffer, float_rows, int_rows, launch_shape};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Autodiff, Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The gather (see the module's documentation).
#[backend_extension(Cube, Autodiff)]
pub trait RowGatherOps: Backend {
    /// `values` [N, C] at `index` [M] → [M, C]; `starts` [N + 1] and `readers` (at most M)
    /// list the gathered rows that read each source row, ascending (the backward pass's
    /// order); a row with an empty range gets a zero gradient.
    fn gather_rows(
        values: FloatTensor<Self>,
        index: IntTensor<Self>,
        starts: IntTensor<Self>,
        readers: IntTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The gather turned around: `values` [M, C] → [N, C] (N + 1 = `starts`' length), row n
    /// the sum of `values[readers[j]]` over `starts[n] ≤ j < starts[n + 1]` in that order;
    /// `index` [M] (every entry below N) is the gradient's gather.
    fn sum_rows(
        values: FloatTensor<Self>,
        index: IntTensor<Self>,
        starts: IntTensor<Self>,
        readers: IntTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// [`RowGatherOps::gather_rows`] on burn tensors of a CubeCL device.
pub fn gather_rows(
    values: Tensor<2>,
    index: &Tensor<1, Int>,
    starts: &Tensor<1, Int>,
    readers: &Tensor<1, Int>,
) -> Tensor<2> {
    dispatch(Dispatch::gather_rows, values, [index, starts, readers])
}

/// [`RowGatherOps::sum_rows`] on burn tensors of a CubeCL device.
pub fn sum_rows(
    values: Tensor<2>,
    index: &Tensor<1, Int>,
    starts: &Tensor<1, Int>,
    readers: &Tensor<1, Int>,
) -> Tensor<2> {
    dispatch(Dispatch::sum_rows, values, [index, starts, readers])
}

/// An operation of [`RowGatherOps`] on burn's dispatch backend: (values, index, starts,
/// readers) → rows.
type RowsOp = fn(
    FloatTensor<Dispatch>,
    IntTensor<Dispatch>,
    IntTensor<Dispatch>,
    IntTensor<Dispatch>,
) -> FloatTensor<Dispatch>;

/// One of the operations on burn tensors.
fn dispatch(
    op: RowsOp,
    values: Tensor<2>,
    [index, starts, readers]: [&Tensor<1, Int>; 3],
) -> Tensor<2> {
    Tensor::from_dispatch(op(
        values.into_dispatch(),
        index.clone().into_dispatch(),
        starts.clone().into_dispatch(),
        readers.clone().into_dispatch(),
    ))
}

mod kernels {
    use cubecl::prelude::*;

    /// One source value a thread: `dx[n · C + c]`.
    #[cube(launch_unchecked)]
    pub fn readers_sum(
        dy: &Tensor<f32>,
        starts: &Tensor<i32>,
        readers: &Tensor<i32>,
        dx: &mut Tensor<f32>,
        channels: u32,
    ) {
        let unit = ABSOLUTE_POS;
        if unit >= dx.shape(0) {
            terminate!();
        }
        let (n, c) = (unit / channels as usize, unit % channels as usize);
        let first = usize::cast_from(starts[n * starts.stride(0)]);
        let end = usize::cast_from(starts[(n + 1) * starts.stride(0)]);
        let mut sum = 0f32;
        for j in first..end {
            let m = usize::cast_from(readers[j * readers.stride(0)]);
            sum += dy[m * dy.stride(0) + c * dy.stride(1)];
        }
        dx[unit] = sum;
    }
}

fn dims2(t: &CubeTensor) -> [usize; 2] {
    let shape = t.meta.shape();
    assert_eq!(shape.num_dims(), 2, "a matrix");
    [shape[0], shape[1]]
}

/// The gradient of the source rows, [N, C], from the gathered rows' `grad` [M, C]; the
/// forward pass of the sums (the same additions).
fn backward(grad: CubeTensor, starts: CubeTensor, readers: CubeTensor) -> CubeTensor {
    let grad = float_rows(grad);
    let [_, channels] = dims2(&grad);
    let source_rows = starts.meta.shape()[0] - 1;
    let units = source_rows * channels;
    let dx = f32_buffer(&grad, units);
    if units > 0 {
        let client = grad.client.clone();
        let (count, dim) = launch_shape(&client, units);
        // SAFETY: threads past the last source value return first; n + 1 ≤ N indexes
        // `starts` [N + 1]; starts ascend from 0 to the readers' length, so j indexes
        // `readers`; a reader is a gathered row, below the gradient's M rows; c < C its
        // columns.
        unsafe {
            kernels::readers_sum::launch_unchecked(
                &client,
                count,
                dim,
                grad.into_tensor_arg(),
                starts.into_tensor_arg(),
                readers.into_tensor_arg(),
                dx.clone().into_tensor_arg(),
                channels as u32,
            );
        }
    }
    CubeBackend::float_reshape(dx, [source_rows, channels].into())
}

impl RowGatherOps for CubeBackend {
    fn gather_rows(
        values: CubeTensor,
        index: CubeTensor,
        _starts: CubeTensor,
        _readers: CubeTensor,
    ) -> CubeTensor {
        CubeBackend::float_select(values, 0, index)
    }

    fn sum_rows(
        values: CubeTensor,
        _index: CubeTensor,
        starts: CubeTensor,
        readers: CubeTensor,
    ) -> CubeTensor {
        backward(values, int_rows(starts), int_rows(readers))
    }
}

/// The backward step of [`RowGatherOps::sum_rows`]: each summed row's gradient gathered
/// back to the rows that went into it.
#[derive(Debug)]
struct SumRowsBackward;

impl Backward<CubeBackend, 1> for SumRowsBackward {
    /// The index [M].
    type State = CubeTensor;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<CubeBackend>(&ops.node);
        if let [Some(node)] = ops.parents {
            grads.register::<CubeBackend>(node.id, CubeBackend::float_select(grad, 0, ops.state));
        }
    }
}

/// The backward step of [`RowGatherOps::gather_rows`].
#[derive(Debug)]
struct RowGatherBackward;

impl Backward<CubeBackend, 1> for RowGatherBackward {
    /// The readers' starts and rows (i32).
    type State = [CubeTensor; 2];

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<CubeBackend>(&ops.node);
        let [starts, readers] = ops.state;
        if let [Some(node)] = ops.parents {
            grads.register::<CubeBackend>(node.id, backward(grad, starts, readers));
        }
    }
}

impl<C: CheckpointStrategy> RowGatherOps for Autodiff<CubeBackend, C> {
    fn gather_rows(
        values: FloatTensor<Self>,
        index: IntTensor<Self>,
        starts: IntTensor<Self>,
        readers: IntTensor<Self>,
    ) -> FloatTensor<Self> {
        let (values, parent) = values.into_parts();
        let out = CubeBackend::float_select(values, 0, index);
        match RowGatherBackward
            .prepare::<C>([parent])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish([int_rows(starts), int_rows(readers)], out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }

    fn sum_rows(
        values: FloatTensor<Self>,
        index: IntTensor<Self>,
        starts: IntTensor<Self>,
        readers: IntTensor<Self>,
    ) -> FloatTensor<Self> {
        let (values, parent) = values.into_parts();
        let out = backward(values, int_rows(starts), int_rows(readers));
        match SumRowsBackward
            .prepare::<C>([parent])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(index, out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use crate::cube::{assert_close, upstream, working_wgpu_device};
    use crate::gather::RowGather;
    use burn::prelude::*;

    /// `len` input values in [−1, 1) from a fixed sequence.
    fn inputs(len: usize) -> Vec<f32> {
        (0..len)
            .map(|v| ((v * 37) % 101) as f32 / 50.0 - 1.0)
            .collect()
    }

    /// Values and gradients of a gather of `m` rows from `n` on `device` (one in seven of
    /// them the zero row), through the [`RowGather`] or burn's `select`.
    fn run(n: usize, m: usize, c: usize, device: &Device, ours: bool) -> [Vec<f32>; 2] {
        // A stride coprime to n reads every row about m / n times, scattered.
        let index: Vec<u32> = (0..m)
            .map(|i| if i % 7 == 3 { n } else { (i * 7919) % n } as u32)
            .collect();
        let values = inputs(n * c);
        let gather = RowGather::new(&index, n, device);
        let x = Tensor::<2>::from_data(TensorData::new(values, [n, c]), device).require_grad();
        let y = if ours {
            gather.gather(x.clone())
        } else {
            Tensor::cat(vec![x.clone(), Tensor::zeros([1, c], device)], 0)
                .select(0, gather.index().clone())
        };
        let grads = (y.clone() * upstream([m, c], device)).sum().backward();
        [
            y.try_into_vec_as::<f32>().unwrap(),
            x.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap(),
        ]
    }

    /// The gather on wgpu against the CPU's `select`: the same rows, and gradients within
    /// rounding at a RoI pooling level's size (27 readers a row), the same bits twice. (At
    /// the largest size burn's own `select` on lavapipe gave a gradient off by 1.4 of its
    /// largest value, 2026-11-29.)
    #[test]
    fn gather_rows_match_the_cpu() {
        let Some(gpu) = working_wgpu_device("the row gather's kernels") else {
            return;
        };
        let gpu = gpu.autodiff();
        let cpu = Device::flex().autodiff();
        for (n, m, c) in [(5, 12, 3), (300, 301, 8), (20_001, 540_027, 16)] {
            let want = run(n, m, c, &cpu, false);
            let got = run(n, m, c, &gpu, true);
            assert_eq!(got[0], want[0], "{n} → {m}: gathered rows");
            assert_close(&got[1], &want[1], 1e-5, &format!("{n} → {m}: gradient"));
            assert_eq!(run(n, m, c, &gpu, true), got, "{n} → {m}: a second run");
        }
    }

    /// The sums into the sources on wgpu against the CPU's `select_assign`: values within
    /// rounding (another order of the same additions), the same bits twice, and the
    /// gradient (a gather) the CPU's exactly; at the size where burn's own kernel went
    /// wrong on lavapipe.
    #[test]
    fn sums_by_source_match_the_cpu() {
        let Some(gpu) = working_wgpu_device("the row sums' kernel") else {
            return;
        };
        let run = |n: usize, m: usize, c: usize, device: &Device| {
            let index: Vec<u32> = (0..m).map(|i| ((i * 7919) % n) as u32).collect();
            let values = inputs(m * c);
            let sums = RowGather::with_sums(&index, n, device);
            let x = Tensor::<2>::from_data(TensorData::new(values, [m, c]), device).require_grad();
            let y = sums.sum_by_source(x.clone());
            let grads = (y.clone() * upstream([n, c], device)).sum().backward();
            [
                y.try_into_vec_as::<f32>().unwrap(),
                x.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap(),
            ]
        };
        let (gpu, cpu) = (gpu.autodiff(), Device::flex().autodiff());
        for (n, m, c) in [(5, 12, 3), (300, 301, 8), (20_001, 540_027, 16)] {
            let want = run(n, m, c, &cpu);
            let got = run(n, m, c, &gpu);
            assert_close(&got[0], &want[0], 1e-5, &format!("{m} → {n}: sums"));
            assert_eq!(got[1], want[1], "{m} → {n}: gradient");
            assert_eq!(run(n, m, c, &gpu), got, "{m} → {n}: a second run");
        }
        // Inference (no autodiff) builds the readers and takes the kernel too.
        let plain = gpu.without_autodiff();
        let index: Vec<u32> = (0..40).map(|i| (i % 7) as u32).collect();
        let values: Vec<f32> = (0..40 * 2).map(|v| v as f32).collect();
        let sums = RowGather::with_sums(&index, 7, &plain);
        let x = Tensor::<2>::from_data(TensorData::new(values, [40, 2]), &plain);
        let got = sums.sum_by_source(x).try_into_vec_as::<f32>().unwrap();
        let want: Vec<f32> = (0..7 * 2)
            .map(|v| {
                (0..40)
                    .filter(|i| i % 7 == v / 2)
                    .map(|i| (i * 2 + v % 2) as f32)
                    .sum()
            })
            .collect();
        assert_eq!(got, want, "sums without autodiff");
    }
}
