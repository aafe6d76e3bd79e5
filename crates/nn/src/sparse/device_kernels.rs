//! The kernel-map sparse convolution as CubeCL kernels with their own backward pass, for
//! burn's GPU backends (cargo features `wgpu` and `cuda`; [`super::rulebook::RuleLayout::DeviceKernels`]).
//!
//! Why: from burn's operations a kernel-map layer appends a zero row to its input, gathers
//! [output rows, volume · C_in] (every absent neighbour's zeros included: a submanifold layer
//! over LiDAR voxels fills about a third of its 27 offsets), multiplies, and in the backward
//! pass scatters the gathered gradient back with atomic additions (whose order, and so whose
//! rounding, changes from run to run); on wgpu over lavapipe its input gradient came out
//! wrong at a backbone's size (`pipeline::sparse_gradient_probe`). Here the kernels read the
//! features where they lie:
//!
//! - forward: one thread four output values of a row, `y[o, c] = Σ_k Σ_i x[table[o, k], i] ·
//!   W[k, i, c]` over the offsets whose neighbour is present, each input value read once
//!   for the four;
//! - input gradient: one thread four input gradient values of a row, `dx[n, i] = Σ_k Σ_c
//!   dy[inverse[n, k], c] · W[k, i, c]`, through the inverse map (which output reads input n
//!   at offset k), so no two threads write one value: no atomics — the forward kernel
//!   (`map_product`) with the weight read transposed. The inverse is made from the table
//!   when a backward pass asks for it (two launches: cleared, then one writer an entry), so
//!   inference, which never differentiates, neither builds nor stores it;
//! - weight gradient: one thread a 4 × 4 tile of weights (four inputs by four outputs at one
//!   offset) and a block of output rows, `Σ_o x[table[o, k], i] · dy[o, c]` for the tile's
//!   16 weights from four input and four gradient values a row, the blocks' partial sums
//!   then added by burn's `sum_dim`.
//!
//! Every sum runs in a fixed order, so a layer's outputs and gradients are the same bits in
//! every run on one device. They are not the CPU's bits (another order of the same sums):
//! tests on wgpu over lavapipe compare them with the flex path within rounding.
//!
//! Layout: every input is indexed by the strides it comes with (CUDA's allocator pads the
//! rows of a 2-D tensor; wgpu packs them), and outputs are written to one-dimensional
//! buffers, which no runtime pads, then relabelled. Storage-tiled inputs (a matrix product's
//! output may be) are un-tiled first. The kernels are launched unchecked, as burn launches
//! its own: every index is in bounds by construction (the `SAFETY` notes below).

use crate::cube::{f32_buffer as buffer, float_rows, i32_buffer, int_rows, launch_shape};
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

/// The convolution (see the module's documentation).
#[backend_extension(Cube, Autodiff)]
pub trait SparseConvKernelOps: Backend {
    /// `features` [input rows, C_in] convolved with `weight` [volume, C_in, C_out] through
    /// `table` [output rows · volume] (the input row output o reads at offset k, at
    /// `o · volume + k`; any value outside `0..input rows` for none) → [output rows, C_out].
    fn sparse_conv_kernel_map(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        table: IntTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// [`SparseConvKernelOps::sparse_conv_kernel_map`] on burn tensors of a CubeCL device.
pub fn sparse_conv(features: Tensor<2>, weight: Tensor<3>, table: &Tensor<1, Int>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SparseConvKernelOps>::sparse_conv_kernel_map(
        features.into_dispatch(),
        weight.into_dispatch(),
        table.clone().into_dispatch(),
    ))
}

/// The kernels, in CubeCL's language (its prelude names `Tensor` and friends apart from
/// burn's).
mod kernels {
    use crate::cube::block_range;
    use cubecl::prelude::*;

    /// Whether `row` names one of `rows` rows (a kernel map's "none" is anything else).
    #[cube]
    fn present(row: i32, rows: u32) -> bool {
        row >= 0 && row < i32::cast_from(rows)
    }

    /// `tile` values of one row a thread, `out[r · D + d]` for d in d₀..d₀ + tile: the sum
    /// over the offsets k whose entry m = `map[r, k]` is present (within 0..`src_rows`), then
    /// over the source's channels j, of `src[m, j] · W[k, j, d]`, each source value read once
    /// for the tile. W [volume, C_in, C_out] is read as [volume, J, D]: the forward pass
    /// (`x` through the table, J = C_in, D = C_out), or `transposed`, the input gradient
    /// (`dy` through the inverse map, J = C_out, D = C_in). Each value's sum runs over the
    /// offsets and then the channels in order.
    #[cube(launch_unchecked)]
    pub fn map_product(
        src: &Tensor<f32>,
        w: &Tensor<f32>,
        map: &Tensor<i32>,
        out: &mut Tensor<f32>,
        src_rows: u32,
        volume: u32,
        #[comptime] transposed: bool,
        #[comptime] tile: u32,
    ) {
        let (width, (w_j, w_d)) = if transposed {
            (w.shape(1), (w.stride(2), w.stride(1)))
        } else {
            (w.shape(2), (w.stride(1), w.stride(2)))
        };
        let tiles = width.div_ceil(tile as usize);
        let unit = ABSOLUTE_POS;
        let (r, d0) = (unit / tiles, (unit % tiles) * tile as usize);
        if r * width >= out.shape(0) {
            terminate!();
        }
        let mut sums = Array::<f32>::new(comptime!(tile as usize));
        #[unroll]
        for t in 0..tile {
            sums[t as usize] = 0f32;
        }
        for k in 0..volume {
            let m = map[(r * volume as usize + k as usize) * map.stride(0)];
            if present(m, src_rows) {
                let src_row = usize::cast_from(m) * src.stride(0);
                for j in 0..src.shape(1) {
                    let value = src[src_row + j * src.stride(1)];
                    let w_at = k as usize * w.stride(0) + j * w_j;
                    #[unroll]
                    for t in 0..tile {
                        let d = d0 + t as usize;
                        if d < width {
                            sums[t as usize] += value * w[w_at + d * w_d];
                        }
                    }
                }
            }
        }
        #[unroll]
        for t in 0..tile {
            let d = d0 + t as usize;
            if d < width {
                out[r * width + d] = sums[t as usize];
            }
        }
    }

    /// One inverse entry a thread: −1, no output reading input n at offset k, until
    /// `invert_table` writes the entries that have one.
    #[cube(launch_unchecked)]
    pub fn clear_inverse(inverse: &mut Tensor<i32>) {
        let unit = ABSOLUTE_POS;
        if unit >= inverse.shape(0) {
            terminate!();
        }
        inverse[unit] = -1i32;
    }

    /// One table entry a thread: where output o reads input n = `table[o · volume + k]`,
    /// `inverse[n · volume + k]` = o. Within one offset an input is read by one output at
    /// most (n fixes o: o = (n + p − d_k) / s), so each inverse entry has one writer at most:
    /// no atomics, the same map in every run.
    #[cube(launch_unchecked)]
    pub fn invert_table(
        table: &Tensor<i32>,
        inverse: &mut Tensor<i32>,
        input_rows: u32,
        volume: u32,
    ) {
        let unit = ABSOLUTE_POS;
        if unit >= table.shape(0) {
            terminate!();
        }
        let n = table[unit * table.stride(0)];
        if present(n, input_rows) {
            let (o, k) = (unit / volume as usize, unit % volume as usize);
            inverse[usize::cast_from(n) * volume as usize + k] = i32::cast_from(o);
        }
    }

    /// A tile of `tile` × `tile` weights (inputs i₀.., outputs c₀.. at one offset k) and one
    /// block of output rows a thread: `partial[b · weights + (k · C_in + i) · C_out + c]`,
    /// the block's share of each of those weights' gradients. Each present row's table
    /// entry, `tile` input values and `tile` gradient values are read once for `tile`²
    /// products (one weight a thread read all three for one). Each weight's sum still runs
    /// over the block's rows in order.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn weight_gradient(
        x: &Tensor<f32>,
        dy: &Tensor<f32>,
        table: &Tensor<i32>,
        partial: &mut Tensor<f32>,
        input_rows: u32,
        output_rows: u32,
        volume: u32,
        c_in: u32,
        c_out: u32,
        block_rows: u32,
        #[comptime] tile: u32,
    ) {
        let unit = ABSOLUTE_POS;
        let (tiles_in, tiles_out) = (c_in.div_ceil(tile) as usize, c_out.div_ceil(tile) as usize);
        let tiles = volume as usize * tiles_in * tiles_out;
        let weights = volume as usize * c_in as usize * c_out as usize;
        let block = unit / tiles;
        if block * weights >= partial.shape(0) {
            terminate!();
        }
        let t = unit % tiles;
        let (k, rest) = (t / (tiles_in * tiles_out), t % (tiles_in * tiles_out));
        let (i0, c0) = (
            (rest / tiles_out) * tile as usize,
            (rest % tiles_out) * tile as usize,
        );
        let mut sums = Array::<f32>::new(comptime!((tile * tile) as usize));
        let mut inputs = Array::<f32>::new(comptime!(tile as usize));
        let mut gradients = Array::<f32>::new(comptime!(tile as usize));
        #[unroll]
        for a in 0..tile * tile {
            sums[a as usize] = 0f32;
        }
        let (first, end) = block_range(block, block_rows, output_rows as usize);
        for o in first..end {
            let n = table[(o * volume as usize + k) * table.stride(0)];
            if present(n, input_rows) {
                let x_row = usize::cast_from(n) * x.stride(0);
                #[unroll]
                for a in 0..tile {
                    // Past the edge of a layer's channels a tile reads zeros.
                    let (i, c) = (i0 + a as usize, c0 + a as usize);
                    let mut input = 0f32;
                    if i < c_in as usize {
                        input = x[x_row + i * x.stride(1)];
                    }
                    inputs[a as usize] = input;
                    let mut gradient = 0f32;
                    if c < c_out as usize {
                        gradient = dy[o * dy.stride(0) + c * dy.stride(1)];
                    }
                    gradients[a as usize] = gradient;
                }
                #[unroll]
                for a in 0..tile {
                    #[unroll]
                    for b in 0..tile {
                        sums[(a * tile + b) as usize] += inputs[a as usize] * gradients[b as usize];
                    }
                }
            }
        }
        #[unroll]
        for a in 0..tile {
            #[unroll]
            for b in 0..tile {
                let (i, c) = (i0 + a as usize, c0 + b as usize);
                if i < c_in as usize && c < c_out as usize {
                    partial[block * weights + (k * c_in as usize + i) * c_out as usize + c] =
                        sums[(a * tile + b) as usize];
                }
            }
        }
    }
}

/// Output values (forward) or input gradient values (backward) of one row a thread makes.
const ROW_TILE: u32 = 4;

/// Weights (and gradient values) a thread of the weight gradient takes on each side: a
/// thread's tile is `WEIGHT_TILE`² weights.
const WEIGHT_TILE: u32 = 4;

/// Threads the weight gradient aims for: blocks of output rows are sized so that a layer's
/// weight tiles times its blocks come to about this many (an H100's or H200's resident
/// threads, about 2¹⁸; the partial sums, `WEIGHT_TILE`² a thread, stay within 16 MB).
const WEIGHT_GRADIENT_THREADS: usize = 1 << 18;

/// The fewest output rows a weight-gradient block takes: below it the partial sums' addition
/// (one pass over the blocks per weight) would walk more than the blocks saved.
const WEIGHT_GRADIENT_BLOCK_ROWS: usize = 32;

fn dims<const D: usize>(t: &CubeTensor) -> [usize; D] {
    let shape = t.meta.shape();
    assert_eq!(shape.num_dims(), D, "a {D}-dimensional tensor");
    std::array::from_fn(|d| shape[d])
}

fn forward(features: CubeTensor, weight: CubeTensor, table: CubeTensor) -> CubeTensor {
    let [input_rows, c_in] = dims(&features);
    let [volume, w_in, c_out] = dims(&weight);
    assert_eq!(c_in, w_in, "features of the weight's input width");
    let [entries] = dims(&table);
    assert_eq!(entries % volume.max(1), 0, "a table of whole output rows");
    let output_rows = entries / volume.max(1);
    let out = buffer(&features, output_rows * c_out);
    let units = output_rows * c_out.div_ceil(ROW_TILE as usize);
    if units > 0 {
        let client = features.client.clone();
        let (count, dim) = launch_shape(&client, units);
        // SAFETY: threads past the last output row return first; output o's table entries
        // are o · volume + k < entries; a table value is used only within 0..input_rows, the
        // features' rows; k < volume, i < C_in and c < C_out (a tile stops at C_out) index
        // the weight within its shape.
        unsafe {
            kernels::map_product::launch_unchecked(
                &client,
                count,
                dim,
                features.into_tensor_arg(),
                weight.into_tensor_arg(),
                table.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                input_rows as u32,
                volume as u32,
                false,
                ROW_TILE,
            );
        }
    }
    CubeBackend::float_reshape(out, [output_rows, c_out].into())
}

/// The inverse of `table` [output rows · volume]: [input rows · volume], the output row that
/// reads input n at offset k at `n · volume + k`, or −1 (two launches).
fn invert(table: &CubeTensor, input_rows: usize, volume: usize) -> CubeTensor {
    let [entries] = dims(table);
    let len = input_rows * volume;
    let inverse = i32_buffer(table, len);
    let client = table.client.clone();
    if len > 0 {
        let (count, dim) = launch_shape(&client, len);
        // SAFETY: threads past the last entry return first.
        unsafe {
            kernels::clear_inverse::launch_unchecked(
                &client,
                count,
                dim,
                inverse.clone().into_tensor_arg(),
            );
        }
    }
    if entries > 0 && len > 0 {
        let (count, dim) = launch_shape(&client, entries);
        // SAFETY: threads past the last table entry return first; an entry is used only
        // within 0..input_rows, so n · volume + k < input_rows · volume, the inverse's length.
        unsafe {
            kernels::invert_table::launch_unchecked(
                &client,
                count,
                dim,
                table.clone().into_tensor_arg(),
                inverse.clone().into_tensor_arg(),
                input_rows as u32,
                volume as u32,
            );
        }
    }
    inverse
}

/// (input gradient, weight gradient), each where asked for.
fn backward(
    [features, weight, table]: [CubeTensor; 3],
    grad: CubeTensor,
    [want_x, want_w]: [bool; 2],
) -> (Option<CubeTensor>, Option<CubeTensor>) {
    let [input_rows, c_in] = dims(&features);
    let [volume, _, c_out] = dims(&weight);
    let [output_rows, _] = dims(&grad);
    let client = features.client.clone();
    let dx = want_x.then(|| {
        let inverse = invert(&table, input_rows, volume);
        let dx = buffer(&features, input_rows * c_in);
        let units = input_rows * c_in.div_ceil(ROW_TILE as usize);
        if units > 0 {
            let (count, dim) = launch_shape(&client, units);
            // SAFETY: threads past the last input row return first; input n's inverse
            // entries are n · volume + k < input_rows · volume; an inverse value is used only
            // within 0..output_rows, the gradient's rows; k, i, c index the weight within its
            // shape (a tile stops at C_in).
            unsafe {
                kernels::map_product::launch_unchecked(
                    &client,
                    count,
                    dim,
                    grad.clone().into_tensor_arg(),
                    weight.clone().into_tensor_arg(),
                    inverse.into_tensor_arg(),
                    dx.clone().into_tensor_arg(),
                    output_rows as u32,
                    volume as u32,
                    true,
                    ROW_TILE,
                );
            }
        }
        CubeBackend::float_reshape(dx, [input_rows, c_in].into())
    });
    let dw = want_w.then(|| {
        let weights = volume * c_in * c_out;
        let tile = WEIGHT_TILE as usize;
        let tiles = volume * c_in.div_ceil(tile) * c_out.div_ceil(tile);
        let blocks = (WEIGHT_GRADIENT_THREADS / tiles.max(1))
            .min(output_rows.div_ceil(WEIGHT_GRADIENT_BLOCK_ROWS))
            .max(1);
        let block_rows = output_rows.div_ceil(blocks).max(1);
        let blocks = output_rows.div_ceil(block_rows).max(1);
        let partial = buffer(&features, blocks * weights);
        if weights > 0 {
            let (count, dim) = launch_shape(&client, blocks * tiles);
            // SAFETY: threads past the last partial sum return first; a block's rows are
            // clipped to output_rows, whose table entries o · volume + k lie within the
            // table; a table value is used only within 0..input_rows, the features' rows;
            // a tile reads and writes only i < C_in and c < C_out.
            unsafe {
                kernels::weight_gradient::launch_unchecked(
                    &client,
                    count,
                    dim,
                    features.into_tensor_arg(),
                    grad.into_tensor_arg(),
                    table.into_tensor_arg(),
                    partial.clone().into_tensor_arg(),
                    input_rows as u32,
                    output_rows as u32,
                    volume as u32,
                    c_in as u32,
                    c_out as u32,
                    block_rows as u32,
                    WEIGHT_TILE,
                );
            }
        }
        let partial = CubeBackend::float_reshape(partial, [blocks, weights].into());
        let summed = CubeBackend::float_sum_dim(partial, 0);
        CubeBackend::float_reshape(summed, [volume, c_in, c_out].into())
    });
    (dx, dw)
}

impl SparseConvKernelOps for CubeBackend {
    fn sparse_conv_kernel_map(
        features: CubeTensor,
        weight: CubeTensor,
        table: CubeTensor,
    ) -> CubeTensor {
        forward(float_rows(features), float_rows(weight), int_rows(table))
    }
}

/// The backward step of [`SparseConvKernelOps::sparse_conv_kernel_map`].
#[derive(Debug)]
struct SparseConvKernelBackward;

impl Backward<CubeBackend, 2> for SparseConvKernelBackward {
    /// The features, the weight and the table (as the kernels read them).
    type State = [CubeTensor; 3];

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = float_rows(grads.consume::<CubeBackend>(&ops.node));
        let [node_x, node_w] = ops.parents;
        let want = [node_x.is_some(), node_w.is_some()];
        let (dx, dw) = backward(ops.state, grad, want);
        for (node, g) in [(node_x, dx), (node_w, dw)] {
            if let (Some(node), Some(g)) = (node, g) {
                grads.register::<CubeBackend>(node.id, g);
            }
        }
    }
}

impl<C: CheckpointStrategy> SparseConvKernelOps for Autodiff<CubeBackend, C> {
    fn sparse_conv_kernel_map(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        table: IntTensor<Self>,
    ) -> FloatTensor<Self> {
        let (features, a) = features.into_parts();
        let (weight, b) = weight.into_parts();
        let (features, weight) = (float_rows(features), float_rows(weight));
        let table = int_rows(table);
        let out = forward(features.clone(), weight.clone(), table.clone());
        match SparseConvKernelBackward
            .prepare::<C>([a, b])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish([features, weight, table], out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::super::conv::SparseConv3d;
    use super::super::rulebook::{ConvGeometry, RuleGather, RuleLayout, Rulebook};
    use super::super::sites::SparseSites;
    use super::super::test_data::{sites, values};
    use crate::cube::{assert_close, working_wgpu_device};
    use burn::prelude::*;
    use std::sync::Arc;

    fn flat<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    /// One layer's (output, input gradient, weight gradient) on `device` in `layout`;
    /// `transposed` hands the kernels the features as a transposed view (strides [1, rows]),
    /// as padded or permuted tensors arrive.
    fn run(
        conv: &SparseConv3d,
        sites: &Arc<SparseSites>,
        layout: RuleLayout,
        device: &Device,
        transposed: bool,
    ) -> [Vec<f32>; 3] {
        let conv = conv.clone().fork(device);
        let [c_in, c_out] = conv.channels();
        let book = if conv.submanifold {
            Rulebook::submanifold_in(sites, conv.geometry.kernel, layout, device)
        } else {
            Rulebook::strided_in(sites, conv.geometry, layout, device)
        };
        if layout == RuleLayout::DeviceKernels {
            assert!(
                matches!(&book.gather, RuleGather::KernelMap { kernels: true, .. }),
                "the kernels' layout on a CubeCL device"
            );
        }
        let rows = sites.len();
        let data = values(rows * c_in, 1);
        let x = if transposed {
            let by_channel: Vec<f32> = (0..c_in * rows)
                .map(|j| data[(j % rows) * c_in + j / rows])
                .collect();
            Tensor::<2>::from_data(TensorData::new(by_channel, [c_in, rows]), device).transpose()
        } else {
            Tensor::<2>::from_data(TensorData::new(data, [rows, c_in]), device)
        }
        .require_grad();
        let upstream = Tensor::<2>::from_data(
            TensorData::new(
                values(book.output_rows() * c_out, 3),
                [book.output_rows(), c_out],
            ),
            device,
        );
        let out = conv.forward(x.clone(), &book);
        let grads = (out.clone() * upstream).sum().backward();
        [
            flat(out),
            flat(x.grad(&grads).unwrap()),
            flat(conv.weight.grad(&grads).unwrap()),
        ]
    }

    /// The kernels against the flex CPU path (per offset, the order every pinned result was
    /// made with): outputs and both gradients within rounding, for submanifold and strided
    /// layers, narrow and wide channels, sites so sparse most offsets are empty; the same bits
    /// when the features arrive as a transposed view, and in a second run.
    #[test]
    fn device_kernels_match_the_cpu() {
        let Some(gpu) = working_wgpu_device("the sparse convolution's kernels") else {
            return;
        };
        let gpu = gpu.autodiff();
        let cpu = Device::flex().autodiff();
        let cases = [
            ([6, 7, 8], 60, ConvGeometry::same([3; 3]), true, [3, 5]),
            (
                [6, 7, 8],
                60,
                ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
                false,
                [4, 6],
            ),
            ([30, 30, 30], 40, ConvGeometry::same([3; 3]), true, [2, 3]),
            (
                [10, 14, 14],
                400,
                ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
                false,
                [16, 32],
            ),
            (
                [9, 10, 11],
                300,
                ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3]),
                false,
                [8, 8],
            ),
            ([8, 8, 8], 150, ConvGeometry::same([3; 3]), true, [16, 16]),
        ];
        for (case, (shape, count, geometry, submanifold, channels)) in cases.into_iter().enumerate()
        {
            let sites = sites(shape, count, case as u64 + 1);
            let conv = if submanifold {
                SparseConv3d::submanifold(channels, geometry.kernel, &cpu)
            } else {
                SparseConv3d::regular(channels, geometry, &cpu)
            };
            let want = run(&conv, &sites, RuleLayout::PerOffset, &cpu, false);
            let got = run(&conv, &sites, RuleLayout::DeviceKernels, &gpu, false);
            for (what, (got, want)) in ["output", "input gradient", "weight gradient"]
                .iter()
                .zip(got.iter().zip(&want))
            {
                assert_close(got, want, 1e-5, &format!("case {case}: {what}"));
            }
            let transposed = run(&conv, &sites, RuleLayout::DeviceKernels, &gpu, true);
            assert_eq!(
                transposed, got,
                "case {case}: a transposed view of the features"
            );
            let again = run(&conv, &sites, RuleLayout::DeviceKernels, &gpu, false);
            assert_eq!(again, got, "case {case}: a second run");
        }
    }

    /// A layer over no sites gives an empty output on the kernels' path too.
    #[test]
    fn empty_sites() {
        let Some(gpu) = working_wgpu_device("the sparse convolution's kernels") else {
            return;
        };
        let empty = Arc::new(SparseSites::new(Vec::new(), [4, 4, 4], 1).unwrap());
        let conv = SparseConv3d::submanifold([2, 3], [3; 3], &gpu);
        let book = Rulebook::submanifold_in(&empty, [3; 3], RuleLayout::DeviceKernels, &gpu);
        let out = conv.forward(Tensor::zeros([0, 2], &gpu), &book);
        assert_eq!(out.dims(), [0, 3]);
    }
}
