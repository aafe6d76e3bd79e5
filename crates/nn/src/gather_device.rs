//! [`crate::gather::RowGather`] on burn's GPU backends: burn's `select` forward, and a
//! backward pass of one thread a source value, `dx[n, c] = Σ_j dy[readers[j], c]` over
//! `starts[n] ≤ j < starts[n + 1]` in that order (see the `gather` module for why).
//! Inputs are indexed by their strides and the gradient written one-dimensional, as the
//! sparse convolution's kernels do (`sparse::device_kernels`: CUDA pads 2-D rows).

use crate::cube::{f32_buffer, float_rows, i32_buffer, int_rows, launch_shape, root_blocks};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Autodiff, Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::ops::numeric::zeros_client;
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

    /// An index made on the device turned around there: `index` [M] (entries 0..=N, N =
    /// `source_rows` the zero row) → (starts [N + 2], readers [M], i32), source row n read by
    /// `readers[starts[n]..starts[n + 1]]` in ascending order, the zero row (n = N) by none.
    /// Entries of `readers` past `starts[N]` are not written.
    fn turn_around(
        index: IntTensor<Self>,
        source_rows: usize,
    ) -> (IntTensor<Self>, IntTensor<Self>);
}

/// [`RowGatherOps::turn_around`] on a burn index of a CubeCL device: (starts, readers).
pub fn turn_around(index: &Tensor<1, Int>, source_rows: usize) -> (Tensor<1, Int>, Tensor<1, Int>) {
    let (starts, readers) =
        <Dispatch as RowGatherOps>::turn_around(index.clone().into_dispatch(), source_rows);
    (
        Tensor::from_dispatch(starts),
        Tensor::from_dispatch(readers),
    )
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
    use crate::cube::block_range;
    use cubecl::prelude::*;

    /// One chunk of the index a thread: `counts[key · chunks + k]`, how many of chunk k's
    /// entries name source row `key` (every (key, k) is chunk k's alone: no atomics).
    #[cube(launch_unchecked)]
    pub fn chunk_counts(
        index: &Tensor<i32>,
        counts: &mut Tensor<i32>,
        chunk_len: u32,
        chunks: u32,
        zero_row: u32,
    ) {
        let k = ABSOLUTE_POS;
        if k >= chunks as usize {
            terminate!();
        }
        let (first, end) = block_range(k, chunk_len, index.shape(0));
        for m in first..end {
            let key = row_of(index, m, zero_row) as usize;
            counts[key * chunks as usize + k] += 1;
        }
    }

    /// Entry m's source row, anything outside 0..=N read as the zero row N (an index made on
    /// the device is not checked on the host; this keeps every count and slot in bounds).
    #[cube]
    fn row_of(index: &Tensor<i32>, m: usize, zero_row: u32) -> u32 {
        let key = u32::cast_from(index[m * index.stride(0)]);
        select(key > zero_row, zero_row, key)
    }

    /// One block a thread: `sums[block]`, the sum of the block's values.
    #[cube(launch_unchecked)]
    pub fn block_sums(values: &Tensor<i32>, sums: &mut Tensor<i32>, block_len: u32) {
        let block = ABSOLUTE_POS;
        if block >= sums.shape(0) {
            terminate!();
        }
        let (first, end) = block_range(block, block_len, values.shape(0));
        let mut sum = 0i32;
        for i in first..end {
            sum += values[i];
        }
        sums[block] = sum;
    }

    /// One thread: `sums` replaced by its exclusive prefix sums, in order.
    #[cube(launch_unchecked)]
    pub fn exclusive_scan_in_place(sums: &mut Tensor<i32>) {
        if ABSOLUTE_POS >= 1 {
            terminate!();
        }
        let mut running = 0i32;
        for i in 0..sums.shape(0) {
            let v = sums[i];
            sums[i] = running;
            running += v;
        }
    }

    /// One block a thread: the block's values replaced by their exclusive prefix sums over
    /// the whole array, from the block's offset `offsets[block]`.
    #[cube(launch_unchecked)]
    pub fn block_prefix(values: &mut Tensor<i32>, offsets: &Tensor<i32>, block_len: u32) {
        let block = ABSOLUTE_POS;
        if block >= offsets.shape(0) {
            terminate!();
        }
        let (first, end) = block_range(block, block_len, values.shape(0));
        let mut running = offsets[block];
        for i in first..end {
            let v = values[i];
            values[i] = running;
            running += v;
        }
    }

    /// One source row a thread (and one more): `starts[n]` = where row n's readers begin,
    /// the prefix at (n, chunk 0); the zero row's range (n = N) left empty.
    #[cube(launch_unchecked)]
    pub fn readers_starts(offsets: &Tensor<i32>, starts: &mut Tensor<i32>, chunks: u32) {
        let n = ABSOLUTE_POS;
        let rows = starts.shape(0);
        if n >= rows {
            terminate!();
        }
        let mut key = n;
        if n == rows - 1 {
            key = n - 1;
        }
        starts[n] = offsets[key * chunks as usize];
    }

    /// One chunk a thread: each entry m of the chunk, in order, written at its (key, chunk)
    /// slot, which then moves on (the zero row's entries are counted, not written).
    #[cube(launch_unchecked)]
    pub fn chunk_scatter(
        index: &Tensor<i32>,
        offsets: &mut Tensor<i32>,
        readers: &mut Tensor<i32>,
        chunk_len: u32,
        chunks: u32,
        zero_row: u32,
    ) {
        let k = ABSOLUTE_POS;
        if k >= chunks as usize {
            terminate!();
        }
        let (first, end) = block_range(k, chunk_len, index.shape(0));
        for m in first..end {
            let key = row_of(index, m, zero_row);
            let at = key as usize * chunks as usize + k;
            let slot = offsets[at];
            offsets[at] = slot + 1;
            if key < zero_row {
                readers[usize::cast_from(slot)] = i32::cast_from(m);
            }
        }
    }

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

/// At most this many (row, chunk) counts for a turn-around: the index is cut into as many
/// chunks as fit (each a thread's serial walk), at least one, at most one per 256 entries.
const TURN_AROUND_COUNTS: usize = 1 << 23;

/// The turn-around on the device (see [`RowGatherOps::turn_around`]). A stable counting
/// sort by source row, deterministic without atomics: the index cut into C chunks, each
/// chunk's thread counts its entries per row into its own column of an [(N + 1) × C]
/// table, the table's exclusive prefix sums in row-major order give each (row, chunk) its
/// first slot (so a row's readers come chunk by chunk, each chunk's in order: ascending),
/// and each chunk's thread writes its entries there.
fn turn_around_on_device(index: CubeTensor, source_rows: usize) -> (CubeTensor, CubeTensor) {
    let index = int_rows(index);
    let m = index.meta.shape().num_elements();
    assert!(
        m < i32::MAX as usize && source_rows < i32::MAX as usize,
        "an index of {m} entries into {source_rows} rows: turned around in 32 bits"
    );
    let keys = source_rows + 1;
    let chunks = (TURN_AROUND_COUNTS / keys).clamp(1, m.div_ceil(256).max(1));
    let chunk_len = m.div_ceil(chunks).max(1);
    let client = index.client.clone();
    let device = index.device.clone();
    let counts = zeros_client(
        client.clone(),
        device.clone(),
        [keys * chunks].into(),
        DType::I32,
    );
    let readers = i32_buffer(&index, m.max(1));
    let starts = i32_buffer(&index, keys + 1);
    if m > 0 {
        let (count, dim) = launch_shape(&client, chunks);
        // SAFETY: threads past the last chunk return first; a chunk's entries are clipped to
        // M; every key is clamped to 0..=N, so key · C + k < (N + 1) · C.
        unsafe {
            kernels::chunk_counts::launch_unchecked(
                &client,
                count,
                dim,
                index.clone().into_tensor_arg(),
                counts.clone().into_tensor_arg(),
                chunk_len as u32,
                chunks as u32,
                source_rows as u32,
            );
        }
    }
    exclusive_scan(&counts);
    let (count, dim) = launch_shape(&client, keys + 1);
    // SAFETY: threads past the last start return first; n ≤ N reads the table at n · C,
    // within its (N + 1) · C values.
    unsafe {
        kernels::readers_starts::launch_unchecked(
            &client,
            count,
            dim,
            counts.clone().into_tensor_arg(),
            starts.clone().into_tensor_arg(),
            chunks as u32,
        );
    }
    if m > 0 {
        let (count, dim) = launch_shape(&client, chunks);
        // SAFETY: as for the counts; each (row, chunk) slot runs from its prefix over as many
        // values as the chunk counted there, all below M, and only entries below the zero
        // row are written.
        unsafe {
            kernels::chunk_scatter::launch_unchecked(
                &client,
                count,
                dim,
                index.into_tensor_arg(),
                counts.into_tensor_arg(),
                readers.clone().into_tensor_arg(),
                chunk_len as u32,
                chunks as u32,
                source_rows as u32,
            );
        }
    }
    (starts, readers)
}

/// `values` (i32, one-dimensional) replaced by their exclusive prefix sums: blocks of about
/// √L values summed, the block sums scanned by one thread, then each block's values.
fn exclusive_scan(values: &CubeTensor) {
    let len = values.meta.shape().num_elements();
    if len == 0 {
        return;
    }
    let (blocks, block_len) = root_blocks(len);
    let client = values.client.clone();
    let sums = i32_buffer(values, blocks);
    let (count, dim) = launch_shape(&client, blocks);
    // SAFETY: threads past the last block return first; each block's values are clipped to
    // L, its sum written at its index below the block count.
    unsafe {
        kernels::block_sums::launch_unchecked(
            &client,
            count.clone(),
            dim,
            values.clone().into_tensor_arg(),
            sums.clone().into_tensor_arg(),
            block_len as u32,
        );
    }
    let (one, single) = launch_shape(&client, 1);
    // SAFETY: one thread walks the block sums within their length.
    unsafe {
        kernels::exclusive_scan_in_place::launch_unchecked(
            &client,
            one,
            single,
            sums.clone().into_tensor_arg(),
        );
    }
    // SAFETY: as for the block sums.
    unsafe {
        kernels::block_prefix::launch_unchecked(
            &client,
            count,
            dim,
            values.clone().into_tensor_arg(),
            sums.into_tensor_arg(),
            block_len as u32,
        );
    }
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

    fn turn_around(index: CubeTensor, source_rows: usize) -> (CubeTensor, CubeTensor) {
        turn_around_on_device(index, source_rows)
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

    fn turn_around(
        index: IntTensor<Self>,
        source_rows: usize,
    ) -> (IntTensor<Self>, IntTensor<Self>) {
        turn_around_on_device(index, source_rows)
    }
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use crate::cube::{assert_close, upstream, working_wgpu_device};
    use crate::gather::RowGather;
    use burn::prelude::*;

    fn ints(t: Tensor<1, Int>) -> Vec<i64> {
        t.into_data().convert::<i64>().try_to_vec::<i64>().unwrap()
    }

    /// The device's turn-around lists the host's readers in the host's order, for indices
    /// with and without the zero row, one chunk or many (rows × chunks over the table's
    /// budget), chunk lengths that do and do not divide the index, and an empty index.
    #[test]
    fn the_device_turns_an_index_around_as_the_host_does() {
        let Some(gpu) = working_wgpu_device("the device's turn-around of an index") else {
            return;
        };
        for (n, m, stride) in [
            (5, 0, 1),
            (1, 7, 1),
            (13, 1000, 7),
            (997, 20_000, 389),
            (40_000, 300_000, 7919),
            (9_000_000, 3_000, 104_729),
        ] {
            // Every seventh entry the zero row (n), the rest scattered over the rows.
            let index: Vec<u32> = (0..m)
                .map(|j| {
                    if j % 7 == 3 {
                        n as u32
                    } else {
                        ((j * stride) % n) as u32
                    }
                })
                .collect();
            let (want_starts, want_readers) = crate::gather::readers_of(&index, n);
            let on_gpu = Tensor::<1, Int>::from_data(
                TensorData::new(index.iter().map(|&v| v as i64).collect(), [m]),
                &gpu,
            );
            let (starts, readers) = super::turn_around(&on_gpu, n);
            let (starts, readers) = (ints(starts), ints(readers));
            assert_eq!(starts.len(), n + 2, "{n} rows");
            assert_eq!(
                &starts[..=n],
                &want_starts[..],
                "{n} rows, {m} entries: starts"
            );
            assert_eq!(starts[n + 1], starts[n], "the zero row has no readers");
            let listed = want_readers.len();
            assert_eq!(
                &readers[..listed],
                &want_readers[..],
                "{n} rows, {m} entries: readers"
            );
        }
        // Entries outside 0..=N (no query writes them) are read as the zero row, in bounds.
        let wild = Tensor::<1, Int>::from_data(TensorData::new(vec![2i64, -1, 0, 9, 2], [5]), &gpu);
        let (starts, readers) = super::turn_around(&wild, 3);
        assert_eq!(ints(starts), vec![0, 1, 1, 3, 3]);
        assert_eq!(&ints(readers)[..3], &[2, 0, 4]);
    }

    /// A gather by a device index: the same values and gradients, to the bit, as by the
    /// same index made on the host.
    #[test]
    fn a_device_index_gathers_and_differentiates_as_a_host_index() {
        let Some(gpu) = working_wgpu_device("a gather by a device index") else {
            return;
        };
        let gpu = gpu.autodiff();
        let (n, m, c) = (900, 12_000, 5);
        let index: Vec<u32> = (0..m)
            .map(|j| {
                if j % 5 == 0 {
                    n as u32
                } else {
                    ((j * 613) % n) as u32
                }
            })
            .collect();
        let values = inputs(n * c);
        let through = |gather: &RowGather| {
            let x = Tensor::<2>::from_data(TensorData::new(values.clone(), [n, c]), &gpu)
                .require_grad();
            let y = gather.gather(x.clone());
            let grads = (y.clone() * upstream([m, c], &gpu)).sum().backward();
            (
                y.into_data().try_to_vec::<f32>().unwrap(),
                x.grad(&grads)
                    .unwrap()
                    .into_data()
                    .try_to_vec::<f32>()
                    .unwrap(),
            )
        };
        let host = RowGather::new(&index, n, &gpu);
        // Made where a kernel makes its index: on the device without autodiff.
        let device_index = Tensor::<1, Int>::from_data(
            TensorData::new(index.iter().map(|&v| v as i64).collect(), [m]),
            &gpu.clone().without_autodiff(),
        );
        let device = RowGather::from_device_index(device_index, n, &gpu);
        assert!(device.sums_readers_on_device() && host.sums_readers_on_device());
        assert_eq!(through(&device), through(&host));
    }

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
