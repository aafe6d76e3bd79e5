//! Training's point-wise linear layers on a GPU over many rows: the same product, written so
//! that the weight gradient is summed over chunks of rows that run side by side.
//!
//! Why: a point-wise layer x [rows, in] · W [in, out] has the weight gradient
//! dW = Xᵀ·dY, a matrix product whose inner dimension is the rows. burn differentiates
//! `linear` with one such product, and cubek's matrix products (burn 0.22's on CUDA and wgpu)
//! spread their cubes over the output's (m, n) tiles and the batch only, never over the inner
//! dimension: an [in, out] of 3 × 32 or 32 × 32 is one or a few cubes, each walking every
//! row in turn. RoI grid pooling's position layer in a published Voxel R-CNN step runs over
//! 884,736 rows (256 RoIs × 216 grid points × 16 neighbours) and DASANet's over twice that, so
//! those products left all but a few of a GPU's multiprocessors idle.
//!
//! Here the rows are cut into [`RowChunks`] (about [`CHUNK_ROWS`] rows each, zero rows
//! appended where no divisor of the row count fits) and the layer is computed as the
//! batched product [chunks, rows/chunk, in] · [1, in, out]. Its forward pass is the same
//! single product (burn-cubecl folds a broadcast right-hand side into one matrix product);
//! its backward pass makes dW as one product per chunk, all launched together, and adds the
//! chunks' [in, out] partial products with one reduction over the chunk axis. The bias, when
//! there is one, is broadcast per chunk first so that its gradient is summed the same way in
//! two steps (over each chunk's rows, then over the chunks) rather than one walk over all
//! rows. The sums run in another order than one product's, so values agree with
//! [`crate::linear::linear`] to float rounding, not to the bit (tests); the CPU never takes
//! this path, whose results stay flex's own.

use burn::nn::Linear;
use burn::prelude::*;

/// The rows a chunk is aimed at: enough for a matrix product's cube to stream, few enough
/// that a published step's position layer makes a couple of hundred chunks.
pub const CHUNK_ROWS: usize = 4096;

/// How the rows of a layer's input are cut: `chunks` chunks of `rows_per_chunk`, the last
/// `padding` of them zero rows appended to the input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowChunks {
    pub chunks: usize,
    pub rows_per_chunk: usize,
    pub padding: usize,
}

impl RowChunks {
    /// The chunks for `rows` rows aimed at `target` rows each, or `None` below two chunks'
    /// worth (one product then walks few rows). A divisor of `rows`
    /// between `target / 2` and `2 · target`, the nearest to `target`, avoids padding;
    /// otherwise chunks of `target` rows with the last one padded.
    pub fn for_rows(rows: usize, target: usize) -> Option<RowChunks> {
        let target = target.max(1);
        if rows < 2 * target {
            return None;
        }
        let divisor = (0..=target).find_map(|d| {
            [target.checked_sub(d), Some(target + d)]
                .into_iter()
                .flatten()
                .find(|&r| r >= target.div_ceil(2) && r <= 2 * target && rows.is_multiple_of(r))
        });
        Some(match divisor {
            Some(r) => RowChunks {
                chunks: rows / r,
                rows_per_chunk: r,
                padding: 0,
            },
            None => {
                let chunks = rows.div_ceil(target);
                RowChunks {
                    chunks,
                    rows_per_chunk: target,
                    padding: chunks * target - rows,
                }
            }
        })
    }
}

/// `layer` on x [rows, in] in training on a GPU: through [`chunked_linear`] when the rows
/// make at least two [`CHUNK_ROWS`] chunks, else burn's `Linear::forward`.
pub fn device_linear(layer: &Linear, x: Tensor<2>) -> Tensor<2> {
    match RowChunks::for_rows(x.dims()[0], CHUNK_ROWS) {
        Some(chunks) => chunked_linear(
            x,
            layer.weight.val(),
            layer.bias.as_ref().map(|b| b.val()),
            chunks,
        ),
        None => layer.forward(x),
    }
}

/// x [rows, in] · `weight` [in, out] (+ `bias` [out]) as a batched product over `chunks` of
/// the rows (see the module's documentation); [rows, out].
pub fn chunked_linear(
    x: Tensor<2>,
    weight: Tensor<2>,
    bias: Option<Tensor<1>>,
    chunks: RowChunks,
) -> Tensor<2> {
    let [rows, d_in] = x.dims();
    let [w_in, d_out] = weight.dims();
    assert_eq!(
        d_in, w_in,
        "x [rows, {d_in}] and a [{w_in}, {d_out}] weight"
    );
    let RowChunks {
        chunks,
        rows_per_chunk,
        padding,
    } = chunks;
    assert_eq!(
        chunks * rows_per_chunk,
        rows + padding,
        "chunks must cover the rows"
    );
    let device = x.device();
    let x = match padding {
        0 => x,
        _ => Tensor::cat(vec![x, Tensor::zeros([padding, d_in], &device)], 0),
    };
    let y = x
        .reshape([chunks, rows_per_chunk, d_in])
        .matmul(weight.unsqueeze_dim::<3>(0));
    let y = match bias {
        // Broadcast per chunk, so that its gradient is summed over each chunk's rows and
        // then over the chunks.
        Some(bias) => y + bias.reshape([1, 1, d_out]).repeat_dim(0, chunks),
        None => y,
    };
    let y = y.reshape([chunks * rows_per_chunk, d_out]);
    match padding {
        0 => y,
        _ => y.slice([0..rows, 0..d_out]),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use burn::module::Param;
    use burn::nn::LinearConfig;

    #[test]
    fn chunks_divide_the_rows_where_a_divisor_is_near_the_target() {
        // A published step's position layer: 216 chunks of 4096.
        assert_eq!(
            RowChunks::for_rows(256 * 216 * 16, CHUNK_ROWS),
            Some(RowChunks {
                chunks: 216,
                rows_per_chunk: 4096,
                padding: 0
            })
        );
        // 2 · 3 · 5 · 7 · 11 · 13 = 30,030 rows: 30030 / 4290 = 7 chunks.
        assert_eq!(
            RowChunks::for_rows(30_030, CHUNK_ROWS),
            Some(RowChunks {
                chunks: 7,
                rows_per_chunk: 4290,
                padding: 0
            })
        );
        // A prime: chunks of the target, the last padded.
        assert_eq!(
            RowChunks::for_rows(10_007, CHUNK_ROWS),
            Some(RowChunks {
                chunks: 3,
                rows_per_chunk: 4096,
                padding: 3 * 4096 - 10_007
            })
        );
        // Below two chunks' worth: one product.
        assert_eq!(RowChunks::for_rows(8191, CHUNK_ROWS), None);
        assert_eq!(RowChunks::for_rows(0, CHUNK_ROWS), None);
    }

    pub(crate) fn layer(d_in: usize, d_out: usize, bias: bool, device: &Device) -> Linear {
        let mut layer = LinearConfig::new(d_in, d_out).with_bias(bias).init(device);
        let weight: Vec<f32> = (0..d_in * d_out)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) / 97.0)
            .collect();
        layer.weight = Param::from_tensor(Tensor::from_data(
            TensorData::new(weight, [d_in, d_out]),
            device,
        ));
        // Fixed too: each backend draws its own initial values.
        layer.bias = layer.bias.map(|_| {
            let bias: Vec<f32> = (0..d_out).map(|i| (i as f32 - 3.0) / 7.0).collect();
            Param::from_tensor(Tensor::from_data(TensorData::new(bias, [d_out]), device))
        });
        layer
    }

    /// Output and the input, weight and bias gradients of a fixed linear functional of the
    /// output, through `chunks` or (`None`) burn's `Linear::forward`.
    pub(crate) fn run(
        layer: &Linear,
        rows: usize,
        chunks: Option<RowChunks>,
        device: &Device,
    ) -> Vec<Vec<f32>> {
        let [d_in, d_out] = layer.weight.dims();
        let x: Vec<f32> = (0..rows * d_in)
            .map(|i| ((i * 53 % 211) as f32 - 105.0) / 31.0)
            .collect();
        let x = Tensor::<2>::from_data(TensorData::new(x, [rows, d_in]), device).require_grad();
        let probe: Vec<f32> = (0..rows * d_out)
            .map(|i| ((i * 29 % 89) as f32 - 44.0) / 13.0)
            .collect();
        let probe = Tensor::<2>::from_data(TensorData::new(probe, [rows, d_out]), device);
        let out = match chunks {
            Some(chunks) => chunked_linear(
                x.clone(),
                layer.weight.val(),
                layer.bias.as_ref().map(|b| b.val()),
                chunks,
            ),
            None => layer.forward(x.clone()),
        };
        let grads = (out.clone() * probe).sum().backward();
        let to_vec = |t: Tensor<2>| t.try_to_vec_as::<f32>().unwrap();
        let mut all = vec![
            to_vec(out),
            to_vec(x.grad(&grads).unwrap()),
            to_vec(layer.weight.val().grad(&grads).unwrap()),
        ];
        if let Some(b) = &layer.bias {
            all.push(
                b.val()
                    .grad(&grads)
                    .unwrap()
                    .try_to_vec_as::<f32>()
                    .unwrap(),
            );
        }
        all
    }

    /// The largest difference of each part, relative to the reference part's largest value.
    pub(crate) fn differences(ours: &[Vec<f32>], reference: &[Vec<f32>]) -> Vec<f64> {
        assert_eq!(ours.len(), reference.len());
        ours.iter()
            .zip(reference)
            .map(|(a, b)| {
                assert_eq!(a.len(), b.len());
                let scale = b.iter().fold(0f64, |m, v| m.max(v.abs() as f64)).max(1e-30);
                a.iter()
                    .zip(b)
                    .fold(0f64, |m, (p, q)| m.max((*p as f64 - *q as f64).abs()))
                    / scale
            })
            .collect()
    }

    /// On the CPU (where training never takes it) the chunked form is the same layer: the
    /// output, input gradient, weight gradient and bias gradient within f32 rounding of
    /// burn's, with and without padding and bias. A chunking that drops the padding's slice
    /// or sums a chunk twice would be far off.
    #[test]
    fn the_chunked_layer_is_the_layer() {
        let device = Device::flex().autodiff();
        for (rows, d_in, d_out, bias, target) in [
            (1000, 3, 8, false, 100),
            (1009, 5, 4, true, 100),
            (4096, 16, 8, true, 512),
        ] {
            let layer = layer(d_in, d_out, bias, &device);
            let chunks = RowChunks::for_rows(rows, target).unwrap();
            let diff = differences(
                &run(&layer, rows, Some(chunks), &device),
                &run(&layer, rows, None, &device),
            );
            assert!(
                diff.iter().all(|&d| d < 1e-5),
                "{rows}x{d_in}->{d_out} {chunks:?}: {diff:?}"
            );
        }
    }

    /// On wgpu (over lavapipe in CI) training's point-wise layers take the chunked form once
    /// the rows make two chunks, and its output and gradients are the CPU's (burn's layer on
    /// flex) within f32 rounding of sums over the rows: a position-layer shape (3 → 32, no
    /// bias, chunks dividing the rows) and a padded one with a bias.
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_chunked_layer_on_wgpu() {
        let Some(gpu) = crate::cube::working_wgpu_device("the chunked linear layer") else {
            return;
        };
        let (gpu, cpu) = (gpu.autodiff(), Device::flex().autodiff());
        for (rows, d_in, d_out, bias) in [(20_000, 3, 32, false), (10_007, 16, 8, true)] {
            let chunks = RowChunks::for_rows(rows, CHUNK_ROWS).unwrap();
            let on_gpu = layer(d_in, d_out, bias, &gpu);
            let chunked = run(&on_gpu, rows, Some(chunks), &gpu);
            let diff = differences(
                &chunked,
                &run(&layer(d_in, d_out, bias, &cpu), rows, None, &cpu),
            );
            assert!(
                diff.iter().all(|&d| d < 1e-4),
                "{rows}x{d_in}->{d_out} {chunks:?}: {diff:?}"
            );
            // `linear` takes this form in training on the device.
            let x = Tensor::<2>::ones([rows, d_in], &gpu);
            let routed = crate::linear::linear(&on_gpu, x.clone());
            let direct = device_linear(&on_gpu, x);
            assert_eq!(
                routed.try_to_vec_as::<f32>().unwrap(),
                direct.try_to_vec_as::<f32>().unwrap()
            );
        }
    }
}
