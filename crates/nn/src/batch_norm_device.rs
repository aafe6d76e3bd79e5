//! Training batch norm ([`crate::batch_norm_ops::BatchNormOps`]) as CubeCL kernels on burn's
//! GPU backends (cargo features `wgpu` and `cuda`), forward and backward, in both layouts.
//!
//! Why: burn 0.22's generic training batch norm takes its statistics with `mean_dim` over
//! [C, B·…] (two forward, four backward: Σ g, Σ g·x̂ and their means), and burn-cubecl
//! reduces an axis, unless kernel autotune is compiled in, with one thread per output value
//! walking the whole axis ("a unit is responsible to reduce a full vector"). A batch norm's
//! output is C values, so each reduction is C threads of up to a million serial steps: in a
//! published Voxel R-CNN training step (batch 2), RoI grid pooling's position layer
//! normalises 256 RoIs × 216 grid points × 16 neighbours = 884,736 rows of 32 channels, six
//! times 32 threads walking 884,736 rows, and every layer of both backbones does the same
//! over its voxels or its map. A GPU runs that as 32 of its ~16,000 lanes. Inference (running
//! statistics) reduces nothing, which fits an H200 running detection near its target while
//! training steps were 5–6 times over theirs (a reading of those figures, not yet a per-kernel
//! measurement).
//!
//! Here each reduction is two launches: blocks of about √N samples per (block, channel)
//! thread, the blocks' partial results then combined per channel in block order, so a sum is
//! at most a few thousand serial steps and the same bits in every run on one device
//! (autotune, where compiled in, may pick burn's reductions differently from run to run).
//! The forward pass is three launches: each block's mean and sum of squared deviations (its
//! thread reads its block twice), their combination per channel (Chan, Golub and LeVeque's
//! pairwise update) with the coefficients the output takes, and the output, written once
//! with the ReLU fused when asked; the backward pass reads once for Σ g and Σ g·x̂ (g through
//! the ReLU's gate, recomputed from the input as the forward pass computed the output) and
//! writes x' once, three launches too. The running statistics' update is one more
//! ([`RunningStatisticsOps`]; burn's operations take six). Sums are f32, where the CPU path
//! sums in f64: tests on wgpu over lavapipe compare the two within rounding.
//!
//! Inputs are read by their strides as 3-D [B, C, S] views ([rows, C] as [rows, C, 1]), and
//! outputs written to one-dimensional buffers, as in `sparse::device_kernels` (CUDA pads
//! 2-D rows).

use crate::batch_norm_ops::{BatchNormOps, NormLayout};
use crate::cube::{f32_buffer as buffer, float_rows, launch_shape};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::Shape;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

mod kernels {
    use crate::cube::block_range;
    use cubecl::prelude::*;
    use cubecl::std::FastDivmod;

    /// Sample j's value of channel c in the [B, C, S] view `t` (j = b·S + s), given (b, s).
    #[cube]
    fn at(t: &Tensor<f32>, b: usize, c: usize, s: usize) -> f32 {
        t[b * t.stride(0) + c * t.stride(1) + s * t.stride(2)]
    }

    /// Packed value `unit` of a [B, C, S] tensor as (b, c, s), the divisions by C and S
    /// precomputed on the host (`FastDivmod`: a multiply and a shift each).
    #[cube]
    fn position(
        unit: usize,
        channels: FastDivmod<u32>,
        spatial: FastDivmod<u32>,
    ) -> (usize, usize, usize) {
        let (rest, s) = spatial.div_mod(u32::cast_from(unit));
        let (b, c) = channels.div_mod(rest);
        (
            usize::cast_from(b),
            usize::cast_from(c),
            usize::cast_from(s),
        )
    }

    /// Packed value `unit` of the [B, C, S] view `t`, at (b, c, s): read by its index when
    /// `packed` (the view's strides are a packed tensor's), else by its strides.
    #[cube]
    fn value_at(
        t: &Tensor<f32>,
        unit: usize,
        b: usize,
        c: usize,
        s: usize,
        #[comptime] packed: bool,
    ) -> f32 {
        if packed { t[unit] } else { at(t, b, c, s) }
    }

    /// Whether a ReLU keeps `v` (flex's: NaN passes).
    #[cube]
    fn kept(v: f32) -> bool {
        v > 0.0 || f32::is_nan(v)
    }

    /// `v` through the ReLU when `relu` (burn's: 0 where `v ≤ 0`, NaN kept), else `v`.
    #[cube]
    fn activated(v: f32, #[comptime] relu: bool) -> f32 {
        let mut out = v;
        if relu && !kept(v) {
            out = 0.0;
        }
        out
    }

    /// The norm's output before the activation, `(x − mean)·scale + β` (the CPU's order of
    /// operations), the same forward and in the ReLU's gate backward.
    #[cube]
    fn affine(value: f32, mean: f32, scale: f32, beta: f32) -> f32 {
        (value - mean) * scale + beta
    }

    /// `value`'s output gradient `grad` through the ReLU's gate when `relu`, the norm's
    /// output recomputed as the forward pass computed it.
    #[cube]
    fn gated(
        grad: f32,
        value: f32,
        mean: f32,
        scale: f32,
        beta: f32,
        #[comptime] relu: bool,
    ) -> f32 {
        let mut keep = true;
        if relu {
            keep = kept(affine(value, mean, scale, beta));
        }
        select(keep, grad, 0.0f32)
    }

    /// One (block, channel) a thread: the block's mean at `partial[block · 2C + c]` and its
    /// sum of squared deviations from it at `partial[block · 2C + C + c]`, over the block's
    /// samples in order (two passes over the block).
    #[cube(launch_unchecked)]
    pub fn norm_block_moments(
        x: &Tensor<f32>,
        partial: &mut Tensor<f32>,
        samples: u32,
        block_len: u32,
    ) {
        let (channels, spatial) = (x.shape(1), x.shape(2));
        let unit = ABSOLUTE_POS;
        if unit * 2 >= partial.shape(0) {
            terminate!();
        }
        let (block, c) = (unit / channels, unit % channels);
        let (first, end) = block_range(block, block_len, samples as usize);
        let (mut b, mut s) = (first / spatial, first % spatial);
        let mut sum = 0f32;
        for _ in first..end {
            sum += at(x, b, c, s);
            s += 1;
            if s == spatial {
                s = 0;
                b += 1;
            }
        }
        let m = sum / f32::cast_from(end - first);
        (b, s) = (first / spatial, first % spatial);
        let mut squares = 0f32;
        for _ in first..end {
            let d = at(x, b, c, s) - m;
            squares += d * d;
            s += 1;
            if s == spatial {
                s = 0;
                b += 1;
            }
        }
        let row = block * 2 * channels;
        partial[row + c] = m;
        partial[row + channels + c] = squares;
    }

    /// One column a thread: `out[k] = Σ_block partial[block · width + k]`, the blocks in
    /// order.
    #[cube(launch_unchecked)]
    pub fn norm_column_totals(partial: &Tensor<f32>, out: &mut Tensor<f32>, blocks: u32) {
        let unit = ABSOLUTE_POS;
        let width = out.shape(0);
        if unit >= width {
            terminate!();
        }
        let mut sum = 0f32;
        for block in 0..blocks as usize {
            sum += partial[block * width + unit];
        }
        out[unit] = sum;
    }

    /// One channel a thread: the blocks' moments (`norm_block_moments`) combined in block
    /// order (Chan, Golub and LeVeque's pairwise update: no sum of squares of raw values, so no
    /// cancellation), the batch `mean` and biased `variance` [C], and `out` [3C] = γ/σ, β and
    /// 1/σ, σ = √(σ² + ε): what the forward pass multiplies and adds, and what x̂ takes
    /// backward.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn norm_statistics(
        partial: &Tensor<f32>,
        gamma: &Tensor<f32>,
        beta: &Tensor<f32>,
        mean: &mut Tensor<f32>,
        variance: &mut Tensor<f32>,
        out: &mut Tensor<f32>,
        samples: u32,
        block_len: u32,
        epsilon: f32,
    ) {
        let c = ABSOLUTE_POS;
        let channels = mean.shape(0);
        if c >= channels {
            terminate!();
        }
        let blocks = partial.shape(0) / (2 * channels);
        let mut count = 0f32;
        let mut m = 0f32;
        let mut squares = 0f32;
        for block in 0..blocks {
            let (first, end) = block_range(block, block_len, samples as usize);
            // An empty batch has one block of no samples, whose moments were not written.
            if end > first {
                let n_b = f32::cast_from(end - first);
                let row = block * 2 * channels;
                let delta = partial[row + c] - m;
                let n = count + n_b;
                m += delta * (n_b / n);
                squares += partial[row + channels + c] + delta * delta * (count * n_b / n);
                count = n;
            }
        }
        let var = squares / f32::max(count, 1.0f32);
        mean[c] = m;
        variance[c] = var;
        let inv_std = 1.0f32 / f32::sqrt(var + epsilon);
        let scale = gamma[c * gamma.stride(0)] * inv_std;
        out[c] = scale;
        out[channels + c] = beta[c * beta.stride(0)];
        out[2 * channels + c] = inv_std;
    }

    /// One channel a thread: burn's running-statistics update, `r · keep + batch · take`
    /// (keep = 1 − momentum, take = momentum) for the mean and the variance.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn norm_running_statistics(
        running_mean: &Tensor<f32>,
        running_variance: &Tensor<f32>,
        mean: &Tensor<f32>,
        variance: &Tensor<f32>,
        new_mean: &mut Tensor<f32>,
        new_variance: &mut Tensor<f32>,
        keep: f32,
        take: f32,
    ) {
        let c = ABSOLUTE_POS;
        if c >= new_mean.shape(0) {
            terminate!();
        }
        new_mean[c] =
            running_mean[c * running_mean.stride(0)] * keep + mean[c * mean.stride(0)] * take;
        new_variance[c] = running_variance[c * running_variance.stride(0)] * keep
            + variance[c * variance.stride(0)] * take;
    }

    /// One output value a thread, `out[(b · C + c) · S + s]` = (x − mean)·scale + β, through
    /// a ReLU when `relu`.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn norm_output(
        x: &Tensor<f32>,
        mean: &Tensor<f32>,
        coefficients: &Tensor<f32>,
        out: &mut Tensor<f32>,
        channels: FastDivmod<u32>,
        spatial: FastDivmod<u32>,
        #[comptime] relu: bool,
        #[comptime] packed: bool,
    ) {
        let unit = ABSOLUTE_POS;
        if unit >= out.shape(0) {
            terminate!();
        }
        let (b, c, s) = position(unit, channels, spatial);
        let v = affine(
            value_at(x, unit, b, c, s, packed),
            mean[c],
            coefficients[c],
            coefficients[x.shape(1) + c],
        );
        out[unit] = activated(v, relu);
    }

    /// One output value a thread: burn's inference batch norm from the running statistics,
    /// ((x − mean) / √(variance + ε))·γ + β in burn's order of operations (its six launches
    /// and four passes over the tensor: a square root, a subtraction, a division, a product
    /// and a sum), through a ReLU when `relu` (burn's two more: a comparison and a fill).
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn norm_inference_output(
        x: &Tensor<f32>,
        mean: &Tensor<f32>,
        variance: &Tensor<f32>,
        gamma: &Tensor<f32>,
        beta: &Tensor<f32>,
        out: &mut Tensor<f32>,
        epsilon: f32,
        channels: FastDivmod<u32>,
        spatial: FastDivmod<u32>,
        #[comptime] relu: bool,
        #[comptime] packed: bool,
    ) {
        let unit = ABSOLUTE_POS;
        if unit >= out.shape(0) {
            terminate!();
        }
        let (b, c, s) = position(unit, channels, spatial);
        let std = f32::sqrt(variance[c * variance.stride(0)] + epsilon);
        let centred = value_at(x, unit, b, c, s, packed) - mean[c * mean.stride(0)];
        let v = centred / std * gamma[c * gamma.stride(0)] + beta[c * beta.stride(0)];
        out[unit] = activated(v, relu);
    }

    /// One (block, channel) a thread: `partial[block · 2C + c]` = Σ g and
    /// `partial[block · 2C + C + c]` = Σ g·x̂ over the block's samples in order (g through the
    /// ReLU's gate when `relu`).
    #[cube(launch_unchecked)]
    pub fn norm_gradient_sums(
        x: &Tensor<f32>,
        g: &Tensor<f32>,
        mean: &Tensor<f32>,
        coefficients: &Tensor<f32>,
        partial: &mut Tensor<f32>,
        samples: u32,
        block_len: u32,
        #[comptime] relu: bool,
    ) {
        let (channels, spatial) = (x.shape(1), x.shape(2));
        let unit = ABSOLUTE_POS;
        if unit * 2 >= partial.shape(0) {
            terminate!();
        }
        let (block, c) = (unit / channels, unit % channels);
        let (first, end) = block_range(block, block_len, samples as usize);
        let m = mean[c];
        let (scale, beta) = (coefficients[c], coefficients[channels + c]);
        let inv_std = coefficients[2 * channels + c];
        let (mut b, mut s) = (first / spatial, first % spatial);
        let mut sum_g = 0f32;
        let mut sum_gx = 0f32;
        for _ in first..end {
            let v = at(x, b, c, s);
            let grad = gated(at(g, b, c, s), v, m, scale, beta, relu);
            sum_g += grad;
            sum_gx += grad * ((v - m) * inv_std);
            s += 1;
            if s == spatial {
                s = 0;
                b += 1;
            }
        }
        let row = block * 2 * channels;
        partial[row + c] = sum_g;
        partial[row + channels + c] = sum_gx;
    }

    /// One input value a thread, `dx[(b · C + c) · S + s]` = γ/σ · ((g − Σg/N) − x̂·Σgx̂/N),
    /// `sums` [2C] holding Σ g then Σ g·x̂; the divisors C and S.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn norm_input_gradient(
        x: &Tensor<f32>,
        g: &Tensor<f32>,
        mean: &Tensor<f32>,
        coefficients: &Tensor<f32>,
        sums: &Tensor<f32>,
        dx: &mut Tensor<f32>,
        samples: f32,
        channel_divisor: FastDivmod<u32>,
        spatial_divisor: FastDivmod<u32>,
        #[comptime] relu: bool,
        #[comptime] packed: bool,
    ) {
        let unit = ABSOLUTE_POS;
        if unit >= dx.shape(0) {
            terminate!();
        }
        let channels = x.shape(1);
        let (b, c, s) = position(unit, channel_divisor, spatial_divisor);
        let v = value_at(x, unit, b, c, s, packed);
        let (m, scale, beta) = (mean[c], coefficients[c], coefficients[channels + c]);
        let x_hat = (v - m) * coefficients[2 * channels + c];
        let grad = gated(value_at(g, unit, b, c, s, packed), v, m, scale, beta, relu);
        let mean_g = sums[c] / samples;
        let mean_gx = sums[channels + c] / samples;
        dx[unit] = scale * ((grad - mean_g) - x_hat * mean_gx);
    }
}

/// `t` as the kernels' [B, C, S] view: [rows, C] → [rows, C, 1], [B, C, …] → [B, C, Π …].
fn view3(t: CubeTensor) -> CubeTensor {
    let shape = t.meta.shape().clone();
    assert!(shape.num_dims() >= 2, "a [rows, C] or [B, C, …] tensor");
    let spatial = (2..shape.num_dims()).map(|d| shape[d]).product::<usize>();
    CubeBackend::float_reshape(float_rows(t), [shape[0], shape[1], spatial].into())
}

/// `x` as the [B, C, S] view the element-wise kernels read, and its number of values, which
/// they index in 32 bits.
fn element_view(x: CubeTensor) -> (CubeTensor, usize) {
    let view = view3(x);
    let len = dims3(&view).iter().product::<usize>();
    assert!(
        len <= u32::MAX as usize,
        "a batch norm over {len} values: the kernels index them in 32 bits"
    );
    (view, len)
}

/// How a reduction over `samples` samples of `channels` channels is split: (blocks, samples
/// a block). About √N samples a block, so that neither a block's thread nor a channel's
/// total walks more than a few thousand values, with at least 16,384 threads in all where
/// there are samples enough to give them work.
fn blocks_of(samples: usize, channels: usize) -> (usize, usize) {
    let root = (samples as f64).sqrt().ceil() as usize;
    let wide = (1usize << 14).div_ceil(channels.max(1));
    let blocks = root.max(wide).clamp(1, samples.max(1));
    let block_len = samples.div_ceil(blocks).max(1);
    (samples.div_ceil(block_len).max(1), block_len)
}

/// The per-column totals of `partial` [blocks · width] → [width].
fn totals(partial: CubeTensor, blocks: usize, width: usize) -> CubeTensor {
    let out = buffer(&partial, width);
    let client = partial.client.clone();
    let (count, dim) = launch_shape(&client, width);
    // SAFETY: threads past the last column return first; block · width + k < blocks · width,
    // the partial sums' length.
    unsafe {
        kernels::norm_column_totals::launch_unchecked(
            &client,
            count,
            dim,
            partial.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            blocks as u32,
        );
    }
    out
}

/// Per channel, the batch mean and biased variance [C] of the [B, C, S] view's samples, and
/// the coefficients [3C] (γ/σ, β, 1/σ) from γ and β: two launches, the blocks' moments then
/// their combination per channel.
fn statistics(
    x: &CubeTensor,
    gamma: CubeTensor,
    beta: CubeTensor,
    epsilon: f64,
) -> (CubeTensor, CubeTensor, CubeTensor) {
    let [batch, channels, spatial] = dims3(x);
    let samples = batch * spatial;
    let (blocks, block_len) = blocks_of(samples, channels);
    let partial = buffer(x, blocks * 2 * channels);
    let client = x.client.clone();
    if samples > 0 && channels > 0 {
        let (count, dim) = launch_shape(&client, blocks * channels);
        // SAFETY: threads past the last (block, channel) return first; a block's samples are
        // clipped to B·S (at least one each: blocks ≤ samples), so (b, s) stays within the
        // view; the two moments of (block, c) lie below blocks · 2C.
        unsafe {
            kernels::norm_block_moments::launch_unchecked(
                &client,
                count,
                dim,
                x.clone().into_tensor_arg(),
                partial.clone().into_tensor_arg(),
                samples as u32,
                block_len as u32,
            );
        }
    }
    let mean = buffer(x, channels);
    let variance = buffer(x, channels);
    let coefficients = buffer(x, 3 * channels);
    if channels > 0 {
        let (count, dim) = launch_shape(&client, channels);
        // SAFETY: threads past the last channel return first; the partial moments hold
        // blocks · 2C values, γ and β C each, the outputs C, C and 3C.
        unsafe {
            kernels::norm_statistics::launch_unchecked(
                &client,
                count,
                dim,
                partial.into_tensor_arg(),
                float_rows(gamma).into_tensor_arg(),
                float_rows(beta).into_tensor_arg(),
                mean.clone().into_tensor_arg(),
                variance.clone().into_tensor_arg(),
                coefficients.clone().into_tensor_arg(),
                samples as u32,
                block_len as u32,
                epsilon as f32,
            );
        }
    }
    (mean, variance, coefficients)
}

/// Whether the [B, C, S] view `t` lies as a packed tensor (value (b, c, s) at (b·C + c)·S
/// + s), so that the element-wise kernels can read it by index.
fn is_packed(t: &CubeTensor) -> bool {
    let [_, channels, spatial] = dims3(t);
    let strides = t.meta.strides();
    strides[0] == channels * spatial
        && (channels <= 1 || strides[1] == spatial)
        && (spatial <= 1 || strides[2] == 1)
}

fn dims3(t: &CubeTensor) -> [usize; 3] {
    let shape = t.meta.shape();
    assert_eq!(shape.num_dims(), 3, "a [B, C, S] view");
    [shape[0], shape[1], shape[2]]
}

/// What a forward pass leaves for its backward pass: the input as the kernels' [B, C, S] view
/// and its own shape, the batch mean [C], the per-channel coefficients [3C] (γ/σ, β, 1/σ) and
/// whether a ReLU followed.
type BatchNormState = (CubeTensor, Shape, CubeTensor, CubeTensor, bool);

/// (output in `x`'s shape, mean [C], biased variance [C], what the backward pass reads).
fn forward(
    x: CubeTensor,
    gamma: CubeTensor,
    beta: CubeTensor,
    epsilon: f64,
    relu: bool,
) -> (CubeTensor, CubeTensor, CubeTensor, BatchNormState) {
    let shape = x.meta.shape().clone();
    let (view, len) = element_view(x);
    let [_, channels, spatial] = dims3(&view);
    let (mean, variance, coefficients) = statistics(&view, gamma, beta, epsilon);
    let client = view.client.clone();
    let out = buffer(&view, len);
    let packed = is_packed(&view);
    if len > 0 {
        let (count, dim) = launch_shape(&client, len);
        // SAFETY: threads past the last value return first; a unit below B·C·S addresses the
        // view within its shape; the coefficients hold 3C values.
        unsafe {
            kernels::norm_output::launch_unchecked(
                &client,
                count,
                dim,
                view.clone().into_tensor_arg(),
                mean.clone().into_tensor_arg(),
                coefficients.clone().into_tensor_arg(),
                out.clone().into_tensor_arg(),
                channels as u32,
                spatial as u32,
                relu,
                packed,
            );
        }
    }
    let state = (view, shape.clone(), mean.clone(), coefficients, relu);
    (
        CubeBackend::float_reshape(out, shape),
        mean,
        variance,
        state,
    )
}

/// (x', γ', β') from the output gradient `grad`.
fn backward(
    (view, shape, mean, coefficients, relu): BatchNormState,
    grad: CubeTensor,
) -> [CubeTensor; 3] {
    let g = view3(grad);
    let [batch, channels, spatial] = dims3(&view);
    assert_eq!(
        dims3(&g),
        [batch, channels, spatial],
        "a gradient per output"
    );
    let samples = batch * spatial;
    let (blocks, block_len) = blocks_of(samples, channels);
    let partial = buffer(&view, blocks * 2 * channels);
    let client = view.client.clone();
    let (count, dim) = launch_shape(&client, blocks * channels);
    // SAFETY: threads past the last (block, channel) return first; a block's samples are
    // clipped to B·S; the two sums of (block, c) lie below blocks · 2C; the mean holds C
    // values, the coefficients 3C.
    unsafe {
        kernels::norm_gradient_sums::launch_unchecked(
            &client,
            count,
            dim,
            view.clone().into_tensor_arg(),
            g.clone().into_tensor_arg(),
            mean.clone().into_tensor_arg(),
            coefficients.clone().into_tensor_arg(),
            partial.clone().into_tensor_arg(),
            samples as u32,
            block_len as u32,
            relu,
        );
    }
    let sums = totals(partial, blocks, 2 * channels);
    // The forward pass checked that this many values fit 32-bit indices.
    let len = batch * channels * spatial;
    let dx = buffer(&view, len);
    let packed = is_packed(&view) && is_packed(&g);
    if len > 0 {
        let (count, dim) = launch_shape(&client, len);
        // SAFETY: threads past the last value return first; a unit below B·C·S addresses
        // both views within their shapes; `sums` holds 2C values, the coefficients 3C.
        unsafe {
            kernels::norm_input_gradient::launch_unchecked(
                &client,
                count,
                dim,
                view.into_tensor_arg(),
                g.into_tensor_arg(),
                mean.into_tensor_arg(),
                coefficients.into_tensor_arg(),
                sums.clone().into_tensor_arg(),
                dx.clone().into_tensor_arg(),
                samples.max(1) as f32,
                channels as u32,
                spatial as u32,
                relu,
                packed,
            );
        }
    }
    let half = |range: std::ops::Range<usize>| {
        CubeBackend::float_slice(sums.clone(), &[burn::tensor::Slice::from(range)])
    };
    [
        CubeBackend::float_reshape(dx, shape),
        half(channels..2 * channels),
        half(0..channels),
    ]
}

impl BatchNormOps for CubeBackend {
    fn batch_norm_train_fused(
        x: CubeTensor,
        gamma: CubeTensor,
        beta: CubeTensor,
        epsilon: f64,
        _layout: NormLayout,
        relu: bool,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        let (out, mean, variance, _) = forward(x, gamma, beta, epsilon, relu);
        (out, mean, variance)
    }
}

/// The backward step of [`BatchNormOps::batch_norm_train_fused`] on a CubeCL device.
#[derive(Debug)]
struct BatchNormDeviceBackward;

impl Backward<CubeBackend, 3> for BatchNormDeviceBackward {
    type State = BatchNormState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<CubeBackend>(&ops.node);
        let gradients = backward(ops.state, grad);
        for (node, g) in ops.parents.into_iter().zip(gradients) {
            if let Some(node) = node {
                grads.register::<CubeBackend>(node.id, g);
            }
        }
    }
}

impl<C: CheckpointStrategy> BatchNormOps for Autodiff<CubeBackend, C> {
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
        _layout: NormLayout,
        relu: bool,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (x, a) = x.into_parts();
        let (gamma, b) = gamma.into_parts();
        let (beta, c) = beta.into_parts();
        let (out, mean, variance, state) = forward(x, gamma, beta, epsilon, relu);
        let out = match BatchNormDeviceBackward
            .prepare::<C>([a, b, c])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(state, out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        // The statistics are constants (the running statistics' update detaches them).
        (out, Self::from_inner(mean), Self::from_inner(variance))
    }
}

/// Training's running-statistics update, `r ← r · (1 − momentum) + batch · momentum` for the
/// mean and the variance, as one launch on a CubeCL device (burn's tensor operations take
/// six: two scalar products and an addition each).
#[backend_extension(Cube, Autodiff)]
pub trait RunningStatisticsOps: Backend {
    /// (running mean, running variance) after the batch's `mean` and `variance` ([C] each).
    fn running_statistics(
        running_mean: FloatTensor<Self>,
        running_variance: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        momentum: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

/// [`RunningStatisticsOps::running_statistics`] on tensors of a CubeCL device (constants:
/// nothing is differentiated through them).
pub fn running_statistics(
    running_mean: Tensor<1>,
    running_variance: Tensor<1>,
    mean: Tensor<1>,
    variance: Tensor<1>,
    momentum: f64,
) -> (Tensor<1>, Tensor<1>) {
    let (m, v) = <Dispatch as RunningStatisticsOps>::running_statistics(
        running_mean.into_dispatch(),
        running_variance.into_dispatch(),
        mean.into_dispatch(),
        variance.into_dispatch(),
        momentum,
    );
    (Tensor::from_dispatch(m), Tensor::from_dispatch(v))
}

impl RunningStatisticsOps for CubeBackend {
    fn running_statistics(
        running_mean: CubeTensor,
        running_variance: CubeTensor,
        mean: CubeTensor,
        variance: CubeTensor,
        momentum: f64,
    ) -> (CubeTensor, CubeTensor) {
        let channels = mean.meta.shape().num_elements();
        let outputs = [buffer(&mean, channels), buffer(&mean, channels)];
        if channels > 0 {
            let client = mean.client.clone();
            let (count, dim) = launch_shape(&client, channels);
            // SAFETY: threads past the last channel return first; every input holds C
            // values (read by its stride), each output C.
            unsafe {
                kernels::norm_running_statistics::launch_unchecked(
                    &client,
                    count,
                    dim,
                    float_rows(running_mean).into_tensor_arg(),
                    float_rows(running_variance).into_tensor_arg(),
                    float_rows(mean).into_tensor_arg(),
                    float_rows(variance).into_tensor_arg(),
                    outputs[0].clone().into_tensor_arg(),
                    outputs[1].clone().into_tensor_arg(),
                    (1.0 - momentum) as f32,
                    momentum as f32,
                );
            }
        }
        let [m, v] = outputs;
        (m, v)
    }
}

impl<C: CheckpointStrategy> RunningStatisticsOps for Autodiff<CubeBackend, C> {
    fn running_statistics(
        running_mean: FloatTensor<Self>,
        running_variance: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        momentum: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (m, v) = CubeBackend::running_statistics(
            Self::inner(running_mean),
            Self::inner(running_variance),
            Self::inner(mean),
            Self::inner(variance),
            momentum,
        );
        (Self::from_inner(m), Self::from_inner(v))
    }
}

/// Inference's batch norm (the running statistics) with the ReLU after it when `relu`, as
/// one launch on a CubeCL device where burn's operations take eight, six of them passes over
/// the whole tensor (`norm_inference_output`). Inference only: nothing is differentiated.
#[backend_extension(Cube)]
pub trait InferenceNormOps: Backend {
    /// `x` [B, C, …] or [rows, C] normalised per channel (the second axis).
    #[allow(clippy::too_many_arguments)]
    fn batch_norm_inference(
        x: FloatTensor<Self>,
        mean: FloatTensor<Self>,
        variance: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
        relu: bool,
    ) -> FloatTensor<Self>;
}

/// `bn` in inference on `x` (a tensor of a CubeCL device without autodiff), through a ReLU
/// when `relu`: the values burn's `BatchNorm::forward` and `relu` give, in one launch.
pub fn inference<const D: usize>(bn: &burn::nn::BatchNorm, x: Tensor<D>, relu: bool) -> Tensor<D> {
    let device = x.device();
    let out = <Dispatch as InferenceNormOps>::batch_norm_inference(
        x.into_dispatch(),
        bn.running_mean.value().to_device(&device).into_dispatch(),
        bn.running_var.value().to_device(&device).into_dispatch(),
        bn.gamma.val().into_dispatch(),
        bn.beta.val().into_dispatch(),
        bn.epsilon,
        relu,
    );
    Tensor::from_dispatch(out)
}

impl InferenceNormOps for CubeBackend {
    fn batch_norm_inference(
        x: CubeTensor,
        mean: CubeTensor,
        variance: CubeTensor,
        gamma: CubeTensor,
        beta: CubeTensor,
        epsilon: f64,
        relu: bool,
    ) -> CubeTensor {
        let shape = x.meta.shape().clone();
        let (view, len) = element_view(x);
        let [_, channels, spatial] = dims3(&view);
        let per_channel = [mean, variance, gamma, beta].map(float_rows);
        for t in &per_channel {
            assert_eq!(
                t.meta.shape().num_elements(),
                channels,
                "one value a channel"
            );
        }
        let out = buffer(&view, len);
        let packed = is_packed(&view);
        if len > 0 {
            let client = view.client.clone();
            let (count, dim) = launch_shape(&client, len);
            let [mean, variance, gamma, beta] = per_channel;
            // SAFETY: threads past the last value return first; a unit below B·C·S addresses
            // the view within its shape; the per-channel inputs hold C values each (checked
            // above), read by their strides.
            unsafe {
                kernels::norm_inference_output::launch_unchecked(
                    &client,
                    count,
                    dim,
                    view.into_tensor_arg(),
                    mean.into_tensor_arg(),
                    variance.into_tensor_arg(),
                    gamma.into_tensor_arg(),
                    beta.into_tensor_arg(),
                    out.clone().into_tensor_arg(),
                    epsilon as f32,
                    channels as u32,
                    spatial as u32,
                    relu,
                    packed,
                );
            }
        }
        CubeBackend::float_reshape(out, shape)
    }
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use crate::batch_norm_ops::{NormLayout, batch_norm_train};
    use crate::cube::{assert_close, working_wgpu_device};
    use crate::norm::{
        NormConfig, batch_norm, inference_on_device, norm_maps, norm_maps_relu, norm_rows,
        norm_rows_relu,
    };
    use crate::ragged;
    use burn::nn::BatchNorm;
    use burn::prelude::*;
    use burn::tensor::activation::relu;

    fn flat<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    /// Inputs with a mean well away from zero per channel (so a one-pass variance would
    /// lose digits) and a varied upstream gradient.
    fn input(len: usize, channel: impl Fn(usize) -> usize, seed: usize) -> (Vec<f32>, Vec<f32>) {
        let x = (0..len)
            .map(|i| ((i * 7919 + seed) % 613) as f32 * 0.0137 + 3.0 + channel(i) as f32)
            .collect();
        let g = (0..len)
            .map(|i| ((i * 104_729 + seed) % 211) as f32 / 50.0 - 2.0)
            .collect();
        (x, g)
    }

    /// (output, mean, variance, x', γ', β') of a training batch norm on `device`;
    /// `transposed` hands a [rows, C] input over as a transposed view of [C, rows].
    fn run<const D: usize>(
        (x, g): &(Vec<f32>, Vec<f32>),
        shape: [usize; D],
        (layout, relu, transposed): (NormLayout, bool, bool),
        device: &Device,
    ) -> [Vec<f32>; 6] {
        let channels = shape[1];
        let x = if transposed {
            let [rows, c] = [shape[0], shape[1]];
            let by_channel: Vec<f32> = (0..c * rows)
                .map(|j| x[(j % rows) * c + j / rows])
                .collect();
            Tensor::<2>::from_data(TensorData::new(by_channel, [c, rows]), device)
                .transpose()
                .reshape(shape)
        } else {
            Tensor::<D>::from_data(TensorData::new(x.clone(), shape), device)
        }
        .require_grad();
        let per_channel = |f: fn(usize) -> f32| {
            let v: Vec<f32> = (0..channels).map(f).collect();
            Tensor::<1>::from_data(TensorData::new(v, [channels]), device).require_grad()
        };
        let gamma = per_channel(|c| 0.75 + c as f32 * 0.125);
        let beta = per_channel(|c| c as f32 * 0.25 - 0.5);
        let (out, mean, variance) =
            batch_norm_train(x.clone(), gamma.clone(), beta.clone(), 1e-3, layout, relu);
        let upstream = Tensor::<D>::from_data(TensorData::new(g.clone(), shape), device);
        let grads = (out.clone() * upstream).sum().backward();
        [
            flat(out),
            flat(mean),
            flat(variance),
            flat(x.grad(&grads).unwrap()),
            flat(gamma.grad(&grads).unwrap()),
            flat(beta.grad(&grads).unwrap()),
        ]
    }

    /// Within rounding of the CPU's f64 sums: 2e-5 of the largest value for the output, the
    /// statistics and x'; γ' and β' are sums of `samples` f32 terms of either sign, good to
    /// about `samples` units of rounding of the terms.
    fn compare(case: &str, samples: usize, got: &[Vec<f32>; 6], want: &[Vec<f32>; 6]) {
        let names = ["output", "mean", "variance", "x'", "γ'", "β'"];
        let sums = (samples as f32 * 1e-7).max(2e-5);
        for (k, (name, (got, want))) in names.iter().zip(got.iter().zip(want)).enumerate() {
            let tolerance = if k < 4 { 2e-5 } else { sums };
            assert_close(got, want, tolerance, &format!("{case}: {name}"));
        }
    }

    /// The kernels against the flex CPU path (f64 sums): outputs, statistics and all three
    /// gradients within rounding, rows and maps (3-D and 4-D), with and without the ReLU, at
    /// sizes below one block and across many; the same bits for a transposed view of the
    /// rows and in a second run.
    #[test]
    fn device_batch_norm_matches_the_cpu() {
        let Some(gpu) = working_wgpu_device("the batch norm's kernels") else {
            return;
        };
        let gpu = gpu.autodiff();
        let cpu = Device::flex().autodiff();
        for (seed, [rows, c]) in [[5, 3], [700, 37], [20_000, 16]].into_iter().enumerate() {
            let data = input(rows * c, |i| i % c, seed);
            for relu in [false, true] {
                let case = format!("rows {rows}×{c}, ReLU {relu}");
                let options = (NormLayout::Rows, relu, false);
                let want = run(&data, [rows, c], options, &cpu);
                let got = run(&data, [rows, c], options, &gpu);
                compare(&case, rows, &got, &want);
                let transposed = run(&data, [rows, c], (NormLayout::Rows, relu, true), &gpu);
                assert_eq!(transposed, got, "{case}: a transposed view");
                let again = run(&data, [rows, c], options, &gpu);
                assert_eq!(again, got, "{case}: a second run");
            }
        }
        for relu in [false, true] {
            let options = (NormLayout::Maps, relu, false);
            let shape = [3, 4, 35];
            let data = input(shape.iter().product(), |i| i / 35 % 4, 7);
            let want = run(&data, shape, options, &cpu);
            let got = run(&data, shape, options, &gpu);
            compare(&format!("maps {shape:?}, ReLU {relu}"), 3 * 35, &got, &want);
            let shape = [2, 8, 30, 26];
            let data = input(shape.iter().product(), |i| i / (30 * 26) % 8, 11);
            let want = run(&data, shape, options, &cpu);
            let got = run(&data, shape, options, &gpu);
            compare(
                &format!("maps {shape:?}, ReLU {relu}"),
                2 * 30 * 26,
                &got,
                &want,
            );
        }
    }

    /// Training's norms take the kernels on a CubeCL device (unless the custom operations
    /// are off) and update the running statistics as on the CPU; a norm over no rows gives
    /// an empty output and zero statistics.
    #[test]
    fn training_norms_take_the_kernels() {
        let Some(gpu) = working_wgpu_device("the batch norm's kernels") else {
            return;
        };
        let gpu = gpu.autodiff();
        let cpu = Device::flex().autodiff();
        let (x, _) = input(300 * 6, |i| i % 6, 3);
        let on = |device: &Device| {
            let bn = batch_norm(6, &NormConfig::default(), device);
            let rows = Tensor::<2>::from_data(TensorData::new(x.clone(), [300, 6]), device);
            assert!(ragged::custom_device_path(&rows) == (*device == gpu));
            let out = norm_rows(&bn, rows);
            let maps = Tensor::<4>::from_data(TensorData::new(x.clone(), [2, 6, 10, 15]), device);
            let maps_out = norm_maps_relu(&bn, maps);
            [
                flat(out),
                flat(maps_out),
                flat(bn.running_mean.value()),
                flat(bn.running_var.value()),
            ]
        };
        let (want, got) = (on(&cpu), on(&gpu));
        for (what, (got, want)) in ["rows", "maps", "running mean", "running variance"]
            .iter()
            .zip(got.iter().zip(&want))
        {
            assert_close(got, want, 2e-5, what);
        }
        let bn = batch_norm(3, &NormConfig::default(), &gpu);
        let out = norm_rows(&bn, Tensor::<2>::zeros([0, 3], &gpu));
        assert_eq!(out.dims(), [0, 3]);
        assert_eq!(flat(bn.running_mean.value()), vec![0.0; 3]);
    }

    /// A norm with running statistics of its own (not the initial zeros and ones), the same
    /// on every device.
    fn trained_norm(channels: usize, device: &Device) -> BatchNorm {
        let mut bn = batch_norm(channels, &NormConfig::default(), device);
        let per_channel = |f: &dyn Fn(f32) -> f32| {
            let v: Vec<f32> = (0..channels).map(|c| f(c as f32)).collect();
            Tensor::<1>::from_data(TensorData::new(v, [channels]), device)
        };
        bn.gamma = burn::module::Param::from_tensor(per_channel(&|c| 0.75 + c * 0.125));
        bn.beta = burn::module::Param::from_tensor(per_channel(&|c| c * 0.25 - 0.5));
        bn.running_mean = burn::module::RunningState::new(per_channel(&|c| 3.5 + c));
        bn.running_var = burn::module::RunningState::new(per_channel(&|c| 0.05 + c * 0.3));
        bn
    }

    /// Inference's norms take the one-launch kernel on a CubeCL device without autodiff (not
    /// with autodiff, nor on the CPU) and give burn's values there, rows and maps, with and
    /// without the ReLU, from a packed tensor and from a transposed view.
    #[test]
    fn inference_norms_take_one_launch_and_give_burns_values() {
        let Some(gpu) = working_wgpu_device("the inference batch norm's kernel") else {
            return;
        };
        let cpu = Device::flex();
        let (rows, c) = (1_000, 7);
        let (x, _) = input(rows * c, |i| i % c, 5);
        let probe = Tensor::<2>::zeros([1, c], &gpu);
        assert!(inference_on_device(&probe));
        let elsewhere = |device: &Device| Tensor::<2>::zeros([1, c], device);
        assert!(!inference_on_device(&elsewhere(&gpu.clone().autodiff())));
        assert!(!inference_on_device(&elsewhere(&cpu)));
        let by_burn = |bn: &BatchNorm, x: Tensor<2>, with_relu: bool| {
            let out = bn.forward(x);
            flat(if with_relu { relu(out) } else { out })
        };
        for with_relu in [false, true] {
            let case = format!("rows {rows}×{c}, ReLU {with_relu}");
            let on = |device: &Device| {
                let bn = trained_norm(c, device);
                let t = Tensor::<2>::from_data(TensorData::new(x.clone(), [rows, c]), device);
                let ours = if with_relu {
                    norm_rows_relu(&bn, t.clone())
                } else {
                    norm_rows(&bn, t.clone())
                };
                (flat(ours), by_burn(&bn, t, with_relu))
            };
            let (got, burns_on_gpu) = on(&gpu);
            let (_, want) = on(&cpu);
            assert_close(&got, &want, 1e-6, &format!("{case}: against the CPU"));
            // The same bits on lavapipe; a GPU's compiler may fuse the product and the sum
            // into one rounding where burn's separate launches round twice.
            assert_close(
                &got,
                &burns_on_gpu,
                1e-6,
                &format!("{case}: against burn's"),
            );
            let bn = trained_norm(c, &gpu);
            let by_channel: Vec<f32> = (0..c * rows)
                .map(|j| x[(j % rows) * c + j / rows])
                .collect();
            let view =
                Tensor::<2>::from_data(TensorData::new(by_channel, [c, rows]), &gpu).transpose();
            let transposed = if with_relu {
                norm_rows_relu(&bn, view)
            } else {
                norm_rows(&bn, view)
            };
            assert_eq!(flat(transposed), got, "{case}: a transposed view");
            let shape = [2, c, 9, 11];
            let (maps, _) = input(shape.iter().product(), |i| i / 99 % c, 9);
            let on = |device: &Device| {
                let bn = trained_norm(c, device);
                let t = Tensor::<4>::from_data(TensorData::new(maps.clone(), shape), device);
                flat(if with_relu {
                    norm_maps_relu(&bn, t)
                } else {
                    norm_maps(&bn, t)
                })
            };
            assert_close(
                &on(&gpu),
                &on(&cpu),
                1e-6,
                &format!("maps {shape:?}, ReLU {with_relu}"),
            );
        }
        let bn = trained_norm(3, &gpu);
        assert_eq!(
            norm_rows_relu(&bn, Tensor::<2>::zeros([0, 3], &gpu)).dims(),
            [0, 3]
        );
    }
}
