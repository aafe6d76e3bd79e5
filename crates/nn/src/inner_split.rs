//! Matrix products with a long inner dimension and a small output on a GPU: the inner
//! dimension cut into chunks whose products run side by side, then summed.
//!
//! Why: cubek's matrix products (burn 0.22's on CUDA and wgpu) spread their cubes over the
//! output's tiles and the batch, never over the inner dimension (as [`crate::linear_chunked`]
//! says of weight gradients). DASANet's TDIS products F^D·W (Eq. 2, 4 and 6: [R, N·C] ·
//! [N·C, N | C | 1], N·C = 216 · 656 = 141,696 at the published widths) and its RoI head's
//! first layer ([R, 141,696] · [141,696, 256]) have R = 100 rows a frame in detection and a
//! few hundred in training. That is a handful of output tiles, so a handful of cubes, each
//! walking 141,696 products a value while the rest of the GPU idles; a lavapipe profile of a
//! DASANet training step found them among its launches of at most 16 cubes.
//!
//! Here x [M, K] · W [K, N] is the batched product [S, M, K/S] · [S, K/S, N] summed over the
//! S chunks: S times the cubes, each walking K/S. W's chunks are a reshape; x's are a
//! strided view that cubek copies into a packed batch before the product (one pass over x,
//! against the K/S·N products each of its values then takes part in, and the copy is not
//! kept for the backward pass). Only where K has a divisor near [`CHUNK_INNER`] (padding
//! would copy x once more, and W with it) and
//! the output is a few tiles ([`FEW_TILES`]); elsewhere, and off CubeCL devices, the plain
//! product. Gradients go through burn's autodiff of the same operations. The sums run in
//! another order than one product's, so values agree with it to float rounding, not to the
//! bit (tests); the CPU never takes this path, whose results stay flex's own.
//! `FUSIONDET_INNER_SPLIT=off` keeps the plain product on a GPU too, for side-by-side timing.

use crate::linear_chunked::RowChunks;
use burn::nn::Linear;
use burn::prelude::*;

/// The inner length a chunk is aimed at: long enough for a cube's loop to stream, short
/// enough that TDIS's 141,696 make 36 chunks.
pub const CHUNK_INNER: usize = 4096;

/// Outputs of fewer 64 × 64 tiles than this are split: fewer cubes than an H100-class GPU
/// has multiprocessors (132).
pub const FEW_TILES: usize = 128;

/// How many chunks x [M, K] · W [K, N] is cut into along K on a GPU, or `None` for the plain
/// product: an output of at least [`FEW_TILES`] tiles, an inner dimension under two chunks,
/// or one without a divisor between half and twice [`CHUNK_INNER`].
pub fn inner_chunks(m: usize, k: usize, n: usize) -> Option<usize> {
    let tiles = m.div_ceil(64) * n.div_ceil(64);
    if tiles >= FEW_TILES {
        return None;
    }
    RowChunks::for_rows(k, CHUNK_INNER)
        .filter(|c| c.padding == 0)
        .map(|c| c.chunks)
}

/// The chunks x [M, K] · W [K, `n`] is split into on `x`'s device: [`inner_chunks`] on a
/// CubeCL device with the custom operations on ([`crate::ragged::custom_device_path`]) and
/// `FUSIONDET_INNER_SPLIT` not `off`, else `None`.
fn chunks_on_device(x: &Tensor<2>, n: usize) -> Option<usize> {
    static FROM_ENV: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let enabled = crate::place::switch_on_unless_off(
        "FUSIONDET_INNER_SPLIT",
        &FROM_ENV,
        "long inner dimensions stay split on a GPU",
    );
    let [m, k] = x.dims();
    (enabled && crate::ragged::custom_device_path(x))
        .then(|| inner_chunks(m, k, n))
        .flatten()
}

/// x [M, K] · w [K, N]: split along K on a GPU where [`inner_chunks`] says so, else the
/// plain product.
pub fn matmul(x: Tensor<2>, w: Tensor<2>) -> Tensor<2> {
    match chunks_on_device(&x, w.dims()[1]) {
        Some(chunks) => split_matmul(x, w, chunks),
        None => x.matmul(w),
    }
}

/// `layer` on x [M, in] where [`matmul`] splits x·W; `None` where it would not.
pub fn wide_linear(layer: &Linear, x: &Tensor<2>) -> Option<Tensor<2>> {
    let chunks = chunks_on_device(x, layer.weight.dims()[1])?;
    let y = split_matmul(x.clone(), layer.weight.val(), chunks);
    Some(match &layer.bias {
        Some(bias) => y + bias.val().unsqueeze_dim(0),
        None => y,
    })
}

/// x [M, K] · w [K, N] as `chunks` products over K/chunks each, summed: [M, N].
pub fn split_matmul(x: Tensor<2>, w: Tensor<2>, chunks: usize) -> Tensor<2> {
    let ([m, k], [w_k, n]) = (x.dims(), w.dims());
    assert_eq!(k, w_k, "x [M, {k}] and a [{w_k}, N] right-hand side");
    assert!(
        chunks > 0 && k.is_multiple_of(chunks),
        "{chunks} chunks must divide an inner dimension of {k}"
    );
    let len = k / chunks;
    let lhs = x.reshape([m, chunks, len]).swap_dims(0, 1); // [S, M, K/S]
    let rhs = w.reshape([chunks, len, n]); // [S, K/S, N]
    lhs.matmul(rhs).sum_dim(0).reshape([m, n])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_inner_dimensions_of_few_tiles_are_cut_near_the_target() {
        // TDIS's and the head's products at the published widths: 36 chunks of 3,936.
        assert_eq!(inner_chunks(100, 216 * 656, 256), Some(36));
        assert_eq!(inner_chunks(512, 216 * 656, 656), Some(36));
        // Many tiles already: the plain product.
        assert_eq!(inner_chunks(2048, 216 * 656, 256), None);
        // Short, or prime: the plain product.
        assert_eq!(inner_chunks(100, 8191, 256), None);
        assert_eq!(inner_chunks(100, 10_007, 256), None);
    }

    /// Output, x's and w's gradients of a fixed functional of x·w.
    fn run(m: usize, k: usize, n: usize, chunks: Option<usize>, device: &Device) -> Vec<Vec<f32>> {
        let values = |len: usize, a: usize, p: usize| -> Vec<f32> {
            (0..len)
                .map(|i| ((i * a % p) as f32 - (p / 2) as f32) / p as f32)
                .collect()
        };
        let x = Tensor::<2>::from_data(TensorData::new(values(m * k, 53, 211), [m, k]), device)
            .require_grad();
        let w = Tensor::<2>::from_data(TensorData::new(values(k * n, 37, 101), [k, n]), device)
            .require_grad();
        let probe = Tensor::<2>::from_data(TensorData::new(values(m * n, 29, 89), [m, n]), device);
        let y = match chunks {
            Some(chunks) => split_matmul(x.clone(), w.clone(), chunks),
            None => x.clone().matmul(w.clone()),
        };
        let grads = (y.clone() * probe).sum().backward();
        let to_vec = |t: Tensor<2>| t.try_to_vec_as::<f32>().unwrap();
        vec![
            to_vec(y),
            to_vec(x.grad(&grads).unwrap()),
            to_vec(w.grad(&grads).unwrap()),
        ]
    }

    /// On the CPU (where nothing takes it) the split product is the product: output and both
    /// gradients within f32 rounding. A chunk summed twice or x's chunks read as W's layout
    /// (a reshape in place of the transposed view) would be far off.
    #[test]
    fn the_split_product_is_the_product() {
        let device = Device::flex().autodiff();
        for (m, k, n, chunks) in [(3, 12, 2, 3), (7, 4096 * 3, 5, 3), (1, 60, 1, 4)] {
            let diff = crate::linear_chunked::tests::differences(
                &run(m, k, n, Some(chunks), &device),
                &run(m, k, n, None, &device),
            );
            assert!(
                diff.iter().all(|&d| d < 1e-5),
                "{m}x{k}x{n}/{chunks}: {diff:?}"
            );
        }
    }

    /// On wgpu (over lavapipe in CI) a long inner dimension is split, and the output and both
    /// gradients are the CPU's plain product's within f32 rounding; a layer that `linear`
    /// routes there gives the split form's bits, bias added.
    #[cfg(feature = "wgpu")]
    #[test]
    fn on_wgpu_long_inner_dimensions_are_split() {
        let Some(gpu) = crate::cube::working_wgpu_device("the inner split") else {
            return;
        };
        let (gpu, cpu) = (gpu.autodiff(), Device::flex().autodiff());
        let (m, k, n) = (40, 6 * CHUNK_INNER, 24);
        let chunks = inner_chunks(m, k, n).expect("a split shape");
        assert_eq!(chunks, 6);
        let diff = crate::linear_chunked::tests::differences(
            &run(m, k, n, Some(chunks), &gpu),
            &run(m, k, n, None, &cpu),
        );
        assert!(diff.iter().all(|&d| d < 1e-4), "{diff:?}");
        let varied = |len: usize, a: usize| -> Vec<f32> {
            (0..len)
                .map(|i| ((i * a % 97) as f32 - 48.0) / 97.0)
                .collect()
        };
        let x = Tensor::<2>::from_data(TensorData::new(varied(m * k, 31), [m, k]), &gpu);
        let w = Tensor::<2>::from_data(TensorData::new(varied(k * n, 17), [k, n]), &gpu);
        assert_eq!(
            matmul(x.clone(), w.clone()).try_to_vec_as::<f32>().unwrap(),
            split_matmul(x.clone(), w, chunks)
                .try_to_vec_as::<f32>()
                .unwrap()
        );
        let layer = crate::linear_chunked::tests::layer(k, n, true, &gpu);
        let routed = crate::linear::linear(&layer, x.clone());
        let direct = split_matmul(x, layer.weight.val(), chunks)
            + layer.bias.as_ref().unwrap().val().unsqueeze_dim(0);
        assert_eq!(
            routed.try_to_vec_as::<f32>().unwrap(),
            direct.try_to_vec_as::<f32>().unwrap()
        );
    }
}
