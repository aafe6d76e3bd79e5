//! Training's dense 2D convolutions (and 1D ones, as [B, C, 1, L] maps: [`conv1d`]) on the
//! flex CPU device, with the weight gradient as one matrix product.
//!
//! Why: burn 0.22 differentiates a convolution's weight as another convolution — of the
//! input with batch and channels swapped, by the output gradient used as a kernel the size
//! of the whole map — and flex has no own weight gradient. With a batch of 2 taken for "2
//! input channels", flex picks its direct small-channel path for every layer with at most
//! 16 outputs (the anchor head's 2-, 4- and 14-wide 1×1 convolutions): one pass per tap of a
//! map-sized kernel, each producing a single value. In the Voxel R-CNN CPU row's training
//! step those three weight gradients took about a sixth of the time for 37 M multiply-adds.
//! Here the weight gradient is an im2col of the input ([C_in·k_h·k_w, H_out·W_out] per
//! frame; the input itself for a 1×1 stride-1 convolution) and one batched matrix product
//! with the output gradient. The forward pass is the same patches multiplied by the weight,
//! one product per frame ([`crate::matmul`]): flex's `conv2d` ran the BEV backbone's 3×3
//! layers at about half the rate of the products they consist of (bench `conv2d`). The
//! input gradient, at stride 1 with symmetric padding, is that forward pass over the output
//! gradient with the kernel flipped; elsewhere flex's own. Values differ from burn's in
//! the order of their sums only (tests); the bias gradient is flex's own.
//!
//! The same `#[backend_extension]` route as [`crate::ragged`]: flex without autodiff runs
//! the forward pass above; `Autodiff<Flex>` adds the backward step below; other devices (and
//! grouped convolutions) keep `Conv2d::forward`. [`crate::ragged::set_custom_ops`] turns
//! this off with the other custom operations.

use crate::buffers::par_chunks_filled;
use crate::matmul::{MatrixRef, product, product_into};
use crate::ragged::{custom_path, values};
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ops::conv::calculate_conv_output_size_asymmetric;
use burn::backend::ops::{ConvOptions, ModuleOps};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::nn::conv::{Conv1d, Conv2d};
use burn::nn::{PaddingConfig1d, PaddingConfig2d};
use burn::prelude::*;
use rayon::prelude::*;
use std::borrow::Cow;

/// The custom operations (see the module's documentation): burn's `conv2d` (x [B, C_in, H,
/// W], weight [C_out, C_in, k_h, k_w], bias [C_out]), without and with a bias.
#[backend_extension(Flex, Autodiff)]
pub trait DenseConvOps: Backend {
    fn conv2d_gemm_grad(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self>;

    fn conv2d_gemm_grad_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self>;
}

/// `conv.forward(x)`; in training on the flex device, with the weight gradient as one
/// matrix product (see the module's documentation).
pub fn conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let options = match options(conv, &x) {
        Some(options) if custom_path(&x) && x.device().is_autodiff() => options,
        _ => return conv.forward(x),
    };
    custom_conv(
        x,
        conv.weight.val(),
        conv.bias.as_ref().map(|b| b.val()),
        options,
    )
}

/// The custom operation on [B, C, H, W] `x` with `weight` [C_out, C_in, k_h, k_w].
fn custom_conv(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    options: ConvOptions<2>,
) -> Tensor<4> {
    let (x, weight) = (x.into_dispatch(), weight.into_dispatch());
    Tensor::from_dispatch(match bias {
        Some(bias) => <Dispatch as DenseConvOps>::conv2d_gemm_grad_bias(
            x,
            weight,
            bias.into_dispatch(),
            options,
        ),
        None => <Dispatch as DenseConvOps>::conv2d_gemm_grad(x, weight, options),
    })
}

/// `conv.forward(x)` for a [`Conv1d`] on [B, C, L]: in training on the flex CPU device
/// through [`conv2d`]'s operation as a [B, C, 1, L] map with a [1, k] kernel, so its weight
/// gradient is the same one matrix product (burn differentiates a 1D convolution's weight as
/// a convolution too; the frustum FCN's ran on one core).
pub fn conv1d(conv: &Conv1d, x: Tensor<3>) -> Tensor<3> {
    let explicit = match conv.padding {
        PaddingConfig1d::Valid => Some((0, 0)),
        PaddingConfig1d::Explicit(left, right) => Some((left, right)),
        PaddingConfig1d::Same => None,
    };
    let usable = conv.groups == 1 && x.dims()[1] == conv.weight.dims()[1];
    let padding = match explicit {
        Some(padding) if usable && custom_path(&x) && x.device().is_autodiff() => padding,
        _ => return conv.forward(x),
    };
    // The sequence along the width: each patch row is then one contiguous run of the input
    // (one copy per row; along the height it was one copy per element).
    let options =
        ConvOptions::new_with_padding([1, conv.stride], [(0, 0), padding], [1, conv.dilation], 1);
    let [batch, channels, length] = x.dims();
    let [c_out, c_in, kernel] = conv.weight.dims();
    let out = custom_conv(
        x.reshape([batch, channels, 1, length]),
        conv.weight.val().reshape([c_out, c_in, 1, kernel]),
        conv.bias.as_ref().map(|b| b.val()),
        options,
    );
    let [b, c, _, l] = out.dims();
    out.reshape([b, c, l])
}

/// The convolution options `Conv2d::forward` builds, for the layers this path takes
/// (ungrouped, explicit or no padding); `None` for the others.
fn options(conv: &Conv2d, x: &Tensor<4>) -> Option<ConvOptions<2>> {
    let padding = match conv.padding {
        PaddingConfig2d::Valid => [(0, 0), (0, 0)],
        PaddingConfig2d::Explicit(top, left, bottom, right) => [(top, bottom), (left, right)],
        PaddingConfig2d::Same => return None,
    };
    (conv.groups == 1 && x.dims()[1] == conv.weight.dims()[1])
        .then(|| ConvOptions::new_with_padding(conv.stride, padding, conv.dilation, conv.groups))
}

fn dims4(x: &FlexTensor) -> [usize; 4] {
    let shape = x.layout().shape();
    assert_eq!(shape.num_dims(), 4, "a [B, C, H, W] tensor");
    [shape[0], shape[1], shape[2], shape[3]]
}

/// The input's patches, [B, C_in·k_h·k_w, H_out·W_out]: row (c, i, j) of frame b holds
/// `x[b, c, oh·s_h − p_h + i·d_h, ow·s_w − p_w + j·d_w]` over the output positions (zero
/// in the padding). One row is written per task.
fn im2col(
    x: &[f32],
    [batch, channels, height, width]: [usize; 4],
    [kh, kw]: [usize; 2],
    [ho, wo]: [usize; 2],
    options: &ConvOptions<2>,
) -> Vec<f32> {
    let [sh, sw] = options.stride;
    let [dh, dw] = options.dilation;
    let (ph, pw) = (options.padding[0].0 as isize, options.padding[1].0 as isize);
    par_chunks_filled(batch * channels * kh * kw * ho * wo, ho * wo, |row, out| {
        let (j, rest) = (row % kw, row / kw);
        let (i, rest) = (rest % kh, rest / kh);
        let (c, b) = (rest % channels, rest / channels);
        let plane = &x[(b * channels + c) * height * width..][..height * width];
        for oh in 0..ho {
            let y = (oh * sh) as isize - ph + (i * dh) as isize;
            if y < 0 || y >= height as isize {
                continue; // stays zero
            }
            let src = &plane[y as usize * width..][..width];
            let dst = &mut out[oh * wo..][..wo];
            // Output columns ow whose input column ow·s_w − p_w + j·d_w lies in the row.
            let shift = (j * dw) as isize - pw;
            let first = ((-shift).max(0) as usize).div_ceil(sw).min(wo);
            let end = ((width as isize - shift).max(0) as usize)
                .div_ceil(sw)
                .min(wo);
            if sw == 1 && first < end {
                let start = (first as isize + shift) as usize;
                dst[first..end].copy_from_slice(&src[start..start + (end - first)]);
            } else {
                for ow in first..end.max(first) {
                    dst[ow] = src[((ow * sw) as isize + shift) as usize];
                }
            }
        }
    })
}

/// dL/dweight = Σ_b grad_b [C_out, H_out·W_out] · patches_bᵀ: one product per frame (frames
/// in parallel), summed over the frames in order.
fn weight_grad(
    x: &FlexTensor,
    grad: &FlexTensor,
    weight_shape: [usize; 4],
    options: &ConvOptions<2>,
) -> FlexTensor {
    let [batch, c_in, _, _] = dims4(x);
    let [_, c_out, ho, wo] = dims4(grad);
    let [_, _, kh, kw] = weight_shape;
    let k = c_in * kh * kw;
    let patches = patches(x, [kh, kw], [ho, wo], options);
    let (g, positions) = (values(grad), ho * wo);
    let per_frame: Vec<Vec<f32>> = (0..batch)
        .into_par_iter()
        .map(|b| {
            let grad_b = MatrixRef::new(
                &g[b * c_out * positions..][..c_out * positions],
                [c_out, positions],
            );
            let patches_b = MatrixRef::new(
                &patches[b * k * positions..][..k * positions],
                [k, positions],
            );
            product(grad_b, patches_b.t())
        })
        .collect();
    let mut frames = per_frame.into_iter();
    let mut summed = frames.next().unwrap_or_else(|| vec![0.0; c_out * k]);
    for frame in frames {
        summed.iter_mut().zip(&frame).for_each(|(s, v)| *s += v);
    }
    FlexTensor::from_data(TensorData::new(summed, weight_shape))
}

/// The convolution as one product per frame of the weight [C_out, C_in·k_h·k_w] with the
/// frame's patches ([`im2col`]; the frame itself for a 1×1 stride-1 convolution), plus the
/// bias; frames in parallel, each product on more threads where it is large.
fn forward(
    x: &FlexTensor,
    weight: &FlexTensor,
    bias: Option<&FlexTensor>,
    options: &ConvOptions<2>,
) -> FlexTensor {
    let [batch, c_in, height, width] = dims4(x);
    let [c_out, _, kh, kw] = dims4(weight);
    let out_size = |axis: usize, kernel: usize, size: usize| {
        let (stride, dilation) = (options.stride[axis], options.dilation[axis]);
        calculate_conv_output_size_asymmetric(kernel, stride, options.padding[axis], dilation, size)
    };
    let [ho, wo] = [out_size(0, kh, height), out_size(1, kw, width)];
    let (k, positions) = (c_in * kh * kw, ho * wo);
    let patches = patches(x, [kh, kw], [ho, wo], options);
    let w = values(weight);
    let w = MatrixRef::new(&w, [c_out, k]);
    let bias = bias.map(values);
    let frame_len = c_out * positions;
    let out = par_chunks_filled(batch * frame_len, frame_len, |b, frame| {
        let frame_patches = &patches[b * k * positions..][..k * positions];
        product_into(w, MatrixRef::new(frame_patches, [k, positions]), frame);
        if let Some(bias) = &bias {
            for (channel, &beta) in frame.chunks_exact_mut(positions).zip(bias.iter()) {
                channel.iter_mut().for_each(|v| *v += beta);
            }
        }
    });
    FlexTensor::from_data(TensorData::new(out, [batch, c_out, ho, wo]))
}

/// The patch matrix of `x` for a `kernel` convolution with an `out`-sized output,
/// [B, C_in·k_h·k_w, H_out·W_out] ([`im2col`]); for a 1×1 kernel at stride 1 without
/// padding, `x`'s own values.
fn patches<'a>(
    x: &'a FlexTensor,
    kernel @ [kh, kw]: [usize; 2],
    out: [usize; 2],
    options: &ConvOptions<2>,
) -> Cow<'a, [f32]> {
    let x_values = values(x);
    let one_by_one =
        kh == 1 && kw == 1 && options.stride == [1, 1] && options.padding == [(0, 0), (0, 0)];
    if one_by_one {
        x_values
    } else {
        Cow::Owned(im2col(&x_values, dims4(x), kernel, out, options))
    }
}

/// dL/dx. At stride 1 without dilation and with the same padding p ≤ k − 1 on both sides of
/// each axis (every 3×3 and 1×1 layer of the BEV backbones and heads), the forward
/// convolution ([`forward`]) of the output gradient, padded by k − 1 − p, with the kernel
/// flipped in both axes and its channel axes swapped; elsewhere flex's own (a transposed
/// convolution). Why: flex's transposed convolution makes one [C_in·k_h·k_w, H·W] product
/// per frame with a reduction only C_out deep and scatters it back element by element.
fn input_grad(
    x: &FlexTensor,
    weight: &FlexTensor,
    grad: &FlexTensor,
    options: &ConvOptions<2>,
) -> FlexTensor {
    let [c_out, c_in, kh, kw] = dims4(weight);
    let [(top, bottom), (left, right)] = options.padding;
    let flippable = options.stride == [1, 1]
        && options.dilation == [1, 1]
        && top == bottom
        && left == right
        && top < kh
        && left < kw;
    if !flippable {
        return Flex::conv2d_x_backward(x.clone(), weight.clone(), grad.clone(), options.clone());
    }
    let flipped = flipped_kernel(&values(weight), [c_out, c_in, kh, kw]);
    let flipped = FlexTensor::from_data(TensorData::new(flipped, [c_in, c_out, kh, kw]));
    let padding = [kh - 1 - top, kw - 1 - left];
    let options = ConvOptions::new([1, 1], padding, [1, 1], 1);
    forward(grad, &flipped, None, &options)
}

/// A [C_out, C_in, k_h, k_w] kernel as the kernel of its input gradient's forward
/// convolution: [C_in, C_out, k_h, k_w], flipped in both spatial axes.
pub fn flipped_kernel(weight: &[f32], [c_out, c_in, kh, kw]: [usize; 4]) -> Vec<f32> {
    let mut flipped = vec![0f32; weight.len()];
    for o in 0..c_out {
        for i in 0..c_in {
            for y in 0..kh {
                for x in 0..kw {
                    flipped[((i * c_out + o) * kh + (kh - 1 - y)) * kw + (kw - 1 - x)] =
                        weight[((o * c_in + i) * kh + y) * kw + x];
                }
            }
        }
    }
    flipped
}

impl DenseConvOps for Flex {
    fn conv2d_gemm_grad(x: FlexTensor, weight: FlexTensor, options: ConvOptions<2>) -> FlexTensor {
        forward(&x, &weight, None, &options)
    }

    fn conv2d_gemm_grad_bias(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        options: ConvOptions<2>,
    ) -> FlexTensor {
        forward(&x, &weight, Some(&bias), &options)
    }
}

/// The input and weight gradients, each where its node asks for it.
fn register_input_and_weight_grads(
    grads: &mut Gradients,
    [node_x, node_weight]: [Option<NodeId>; 2],
    (x, weight, options): (&FlexTensor, &FlexTensor, &ConvOptions<2>),
    grad: &FlexTensor,
) {
    if let Some(node) = node_x {
        let dx = input_grad(x, weight, grad, options);
        grads.register::<Flex>(node, dx);
    }
    if let Some(node) = node_weight {
        let dw = weight_grad(x, grad, dims4(weight), options);
        grads.register::<Flex>(node, dw);
    }
}

/// The backward step of [`DenseConvOps::conv2d_gemm_grad`].
#[derive(Debug)]
struct Conv2dBackward;

impl Backward<Flex, 2> for Conv2dBackward {
    /// The input, the weight and the options.
    type State = (FlexTensor, FlexTensor, ConvOptions<2>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, weight, options) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let nodes = ops.parents.map(|p| p.map(|p| p.id));
        register_input_and_weight_grads(grads, nodes, (&x, &weight, &options), &grad);
    }
}

/// The backward step of [`DenseConvOps::conv2d_gemm_grad_bias`].
#[derive(Debug)]
struct Conv2dBiasBackward;

impl Backward<Flex, 3> for Conv2dBiasBackward {
    /// The input, the weight, the bias (for its shape) and the options.
    type State = (FlexTensor, FlexTensor, FlexTensor, ConvOptions<2>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, weight, bias, options) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let [node_x, node_weight, node_bias] = ops.parents;
        let inputs = (&x, &weight, &options);
        let nodes = [node_x, node_weight].map(|p| p.map(|p| p.id));
        register_input_and_weight_grads(grads, nodes, inputs, &grad);
        if let Some(node) = node_bias {
            grads.register::<Flex>(node.id, Flex::conv2d_bias_backward(x, bias, grad));
        }
    }
}

impl<C: CheckpointStrategy> DenseConvOps for Autodiff<Flex, C> {
    fn conv2d_gemm_grad(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        let (x, node_x) = x.into_parts();
        let (weight, node_weight) = weight.into_parts();
        let out = forward(&x, &weight, None, &options);
        match Conv2dBackward
            .prepare::<C>([node_x, node_weight])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((x, weight, options), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }

    fn conv2d_gemm_grad_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        let (x, node_x) = x.into_parts();
        let (weight, node_weight) = weight.into_parts();
        let (bias, node_bias) = bias.into_parts();
        let out = forward(&x, &weight, Some(&bias), &options);
        match Conv2dBiasBackward
            .prepare::<C>([node_x, node_weight, node_bias])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((x, weight, bias, options), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::conv::Conv2dConfig;

    fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_to_vec_as::<f32>().unwrap()
    }

    fn assert_close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}: lengths");
        let scale = b.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(
            worst <= 1e-5 * scale,
            "{what}: max |diff| {worst} against {scale}"
        );
    }

    /// Output and input, weight and bias gradients of a random linear functional of the
    /// output, through [`conv2d`] or burn's `Conv2d::forward`. (Not through
    /// `set_custom_ops`: the switch is process-wide and other tests run beside this one.)
    fn run(conv: &Conv2d, x: &Tensor<4>, w: &Tensor<4>, custom: bool) -> [Vec<f32>; 4] {
        let x = x.clone().require_grad();
        let out = if custom {
            assert!(custom_path(&x) && x.device().is_autodiff() && options(conv, &x).is_some());
            conv2d(conv, x.clone())
        } else {
            conv.forward(x.clone())
        };
        let grads = (out.clone() * w.clone()).sum().backward();
        let g = |t: Tensor<4>| to_vec(t.grad(&grads).expect("a gradient"));
        let bias = conv
            .bias
            .as_ref()
            .map(|b| to_vec(b.val().grad(&grads).unwrap()))
            .unwrap_or_default();
        [to_vec(out), g(x), g(conv.weight.val()), bias]
    }

    #[test]
    fn values_and_gradients_match_burns_convolution() {
        let device = Device::flex().autodiff();
        // (batch, c_in, c_out, h, w, kernel, stride, padding (t, l, b, r), dilation, bias)
        let cases = [
            (2, 8, 14, 6, 7, [1, 1], 1, None, 1, true),
            (2, 8, 2, 5, 5, [1, 1], 1, None, 1, true),
            (2, 6, 20, 9, 8, [3, 3], 1, Some((1, 1, 1, 1)), 1, false),
            (1, 5, 7, 9, 11, [3, 3], 2, Some((1, 1, 1, 1)), 1, false),
            (2, 3, 4, 8, 8, [3, 2], 1, Some((2, 0, 1, 1)), 2, true),
            (3, 4, 3, 7, 6, [1, 1], 2, None, 1, false),
            (2, 16, 8, 10, 12, [3, 3], 1, Some((0, 0, 0, 0)), 1, true),
            (2, 5, 6, 7, 9, [3, 1], 1, Some((1, 0, 1, 0)), 1, true),
            // Large enough for the products to run on several threads.
            (2, 32, 32, 32, 32, [3, 3], 1, Some((1, 1, 1, 1)), 1, true),
        ];
        for (k, &(b, c_in, c_out, h, w, kernel, s, pad, d, bias)) in cases.iter().enumerate() {
            let padding = match pad {
                Some((t, l, bo, r)) => PaddingConfig2d::Explicit(t, l, bo, r),
                None => PaddingConfig2d::Valid,
            };
            let conv = Conv2dConfig::new([c_in, c_out], kernel)
                .with_stride([s, s])
                .with_dilation([d, d])
                .with_padding(padding)
                .with_bias(bias)
                .init(&device);
            let normal = burn::tensor::Distribution::Normal(0.0, 1.0);
            let x = Tensor::<4>::random([b, c_in, h, w], normal, &device);
            let out_dims = conv.forward(x.clone()).dims();
            let weights = Tensor::<4>::random(out_dims, normal, &device);
            let custom = run(&conv, &x, &weights, true);
            let generic = run(&conv, &x, &weights, false);
            for (i, what) in ["forward values", "input gradient", "weight gradient"]
                .iter()
                .enumerate()
            {
                assert_close(&custom[i], &generic[i], &format!("case {k}: {what}"));
            }
            assert_eq!(
                custom[3], generic[3],
                "case {k}: bias gradient is flex's own"
            );
            assert_eq!(custom[3].is_empty(), !bias);
        }
    }

    /// A `Conv1d` through the operation as a [B, C, 1, L] map against burn's `Conv1d`:
    /// forward values, input, weight and bias gradients, as the FCN uses it (kernel 3 at
    /// strides 1 and 2, the 1×1 merge, with and without a bias).
    #[test]
    fn conv1d_values_and_gradients_match_burns() {
        use burn::nn::PaddingConfig1d;
        use burn::nn::conv::Conv1dConfig;
        let device = Device::flex().autodiff();
        // (batch, c_in, c_out, length, kernel, stride, padding, bias)
        let cases = [
            (3, 8, 12, 35, 3, 1, 1, true),
            (2, 6, 10, 28, 3, 2, 1, false),
            (2, 20, 7, 9, 1, 1, 0, true),
        ];
        for (k, &(b, c_in, c_out, len, kernel, s, p, bias)) in cases.iter().enumerate() {
            let conv = Conv1dConfig::new(c_in, c_out, kernel)
                .with_stride(s)
                .with_padding(PaddingConfig1d::Explicit(p, p))
                .with_bias(bias)
                .init(&device);
            let normal = burn::tensor::Distribution::Normal(0.0, 1.0);
            let x = Tensor::<3>::random([b, c_in, len], normal, &device);
            let out_dims = conv.forward(x.clone()).dims();
            let w = Tensor::<3>::random(out_dims, normal, &device);
            let run = |custom: bool| {
                let x = x.clone().require_grad();
                let out = if custom {
                    assert!(custom_path(&x));
                    conv1d(&conv, x.clone())
                } else {
                    conv.forward(x.clone())
                };
                assert_eq!(out.dims(), out_dims);
                let grads = (out.clone() * w.clone()).sum().backward();
                let bias = conv
                    .bias
                    .as_ref()
                    .map(|b| to_vec(b.val().grad(&grads).unwrap()))
                    .unwrap_or_default();
                let g = |t: Tensor<3>| to_vec(t.grad(&grads).expect("a gradient"));
                [to_vec(out), g(x), g(conv.weight.val()), bias]
            };
            let (custom, generic) = (run(true), run(false));
            for (i, what) in [
                "forward",
                "input gradient",
                "weight gradient",
                "bias gradient",
            ]
            .iter()
            .enumerate()
            {
                assert_close(&custom[i], &generic[i], &format!("case {k}: {what}"));
            }
            assert_eq!(custom[3].is_empty(), !bias);
        }
    }

    #[test]
    fn inference_and_other_padding_keep_burns_forward() {
        let device = Device::flex();
        let conv = Conv2dConfig::new([3, 4], [3, 3]).init(&device);
        assert!(options(&conv, &Tensor::zeros([1, 3, 5, 5], &device)).is_some());
        let same = Conv2dConfig::new([3, 4], [3, 3])
            .with_padding(PaddingConfig2d::Same)
            .init(&device);
        assert!(options(&same, &Tensor::zeros([1, 3, 5, 5], &device)).is_none());
        let x = Tensor::<4>::random(
            [1, 3, 5, 5],
            burn::tensor::Distribution::Normal(0.0, 1.0),
            &device,
        );
        assert_eq!(to_vec(conv2d(&conv, x.clone())), to_vec(conv.forward(x)));
    }
}
