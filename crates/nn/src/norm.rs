//! Batch norm as the detectors use it: settings of their own, and statistics over the
//! real rows of a padded tensor.

use crate::batch_norm_ops::{NormLayout, batch_norm_train};
use crate::ragged;
use burn::nn::{BatchNorm, BatchNormConfig};
use burn::prelude::*;
use burn::tensor::activation;
use serde::{Deserialize, Serialize};

/// How a layer followed by batch norm is built.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NormConfig {
    /// Whether the layer before the norm carries a bias (redundant before batch norm;
    /// F-ConvNet's published implementation has none).
    pub bias_before_norm: bool,
    pub momentum: f64,
    pub epsilon: f64,
}

impl Default for NormConfig {
    /// PyTorch's defaults: momentum 0.1, epsilon 1e-5, no bias before the norm.
    fn default() -> Self {
        Self {
            bias_before_norm: false,
            momentum: 0.1,
            epsilon: 1e-5,
        }
    }
}

/// A batch norm over `channels` with these settings.
pub fn batch_norm(channels: usize, config: &NormConfig, device: &Device) -> BatchNorm {
    BatchNormConfig::new(channels)
        .with_momentum(config.momentum)
        .with_epsilon(config.epsilon)
        .init(device)
}

/// `bn.forward(x)` on [rows, C]: in training on the flex CPU device the fused custom
/// operation ([`batch_norm_train`] over rows: two passes for the statistics, one for the
/// output, two backward, where burn's generic form transposes the rows and makes about
/// eight passes each way), with the same running-statistics update as `BatchNorm`; in
/// training on a GPU the same operation as CubeCL kernels (`batch_norm_device`, whose
/// reductions burn runs one thread a channel); in inference `bn.forward` itself, on a GPU
/// as one launch that gives its values ([`inference_on_device`]).
pub fn norm_rows(bn: &BatchNorm, x: Tensor<2>) -> Tensor<2> {
    fused_in_training(bn, x, NormLayout::Rows, false)
}

/// `relu(bn.forward(x))` on [rows, C]: in training on the flex CPU device the ReLU is part of
/// the fused operation ([`norm_rows`]), which saves the separate ReLU's pass over the
/// output each way (and flex runs that pass on one core); the same values and gradients.
pub fn norm_rows_relu(bn: &BatchNorm, x: Tensor<2>) -> Tensor<2> {
    fused_in_training(bn, x, NormLayout::Rows, true)
}

/// `bn.forward(x)` on channels-first maps ([B, C, …]: BEV maps, the FCN's slice
/// sequences): in training on the flex CPU device the fused custom operation
/// ([`batch_norm_train`] over maps: statistics read in place, where burn's generic form
/// copies the map into [C, B·…] twice each way), with the same running-statistics update
/// as `BatchNorm`; on a GPU its kernels, as in [`norm_rows`]; in inference `bn.forward`
/// (on a GPU, as in [`norm_rows`], one launch).
pub fn norm_maps<const D: usize>(bn: &BatchNorm, x: Tensor<D>) -> Tensor<D> {
    fused_in_training(bn, x, NormLayout::Maps, false)
}

/// `relu(bn.forward(x))` on channels-first maps, the ReLU fused as in [`norm_rows_relu`].
pub fn norm_maps_relu<const D: usize>(bn: &BatchNorm, x: Tensor<D>) -> Tensor<D> {
    fused_in_training(bn, x, NormLayout::Maps, true)
}

/// The fused operation in `layout` (with a ReLU when `relu`) where training runs on the flex
/// device or a CubeCL one, with `BatchNorm`'s running-statistics update; `bn.forward` (and
/// `relu`) elsewhere — in inference on a GPU as one launch ([`inference_on_device`]) — or
/// wherever the custom operations are off.
fn fused_in_training<const D: usize>(
    bn: &BatchNorm,
    x: Tensor<D>,
    layout: NormLayout,
    relu: bool,
) -> Tensor<D> {
    let fused = ragged::custom_path(&x) || ragged::custom_device_path(&x);
    if !(x.device().is_autodiff() && bn.training.is_enabled() && fused) {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if inference_on_device(&x) {
            return crate::batch_norm_device::inference(bn, x, relu);
        }
        let out = bn.forward(x);
        return if relu { activation::relu(out) } else { out };
    }
    let [channels] = bn.gamma.shape().dims();
    assert_eq!(
        x.dims()[1],
        channels,
        "the second axis holds the norm's channels"
    );
    let (out, mean, variance) =
        batch_norm_train(x, bn.gamma.val(), bn.beta.val(), bn.epsilon, layout, relu);
    update_running_statistics(bn, mean, variance);
    out
}

/// Whether a norm of `x` in inference runs as one CubeCL launch with its ReLU
/// (`batch_norm_device::inference`) rather than burn's eight: on a CubeCL device without
/// autodiff (detection), unless the custom operations are off. A norm left in inference on
/// an autodiff device (a frozen layer) keeps burn's, whose operations carry gradients.
pub fn inference_on_device<const D: usize>(x: &Tensor<D>) -> bool {
    !x.device().is_autodiff() && ragged::custom_device_path(x)
}

/// `BatchNorm`'s running-statistics update from a batch's mean and biased variance
/// (detached): r ← (1 − momentum)·r + momentum·batch.
fn update_running_statistics(bn: &BatchNorm, mean: Tensor<1>, variance: Tensor<1>) {
    let momentum = bn.momentum;
    // On a GPU one launch for both (`batch_norm_device`), where burn's operations take six.
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if ragged::custom_device_path(&mean) {
        let device = mean.device();
        let (running_mean, running_variance) = crate::batch_norm_device::running_statistics(
            bn.running_mean.value_sync().to_device(&device),
            bn.running_var.value_sync().to_device(&device),
            mean.detach(),
            variance.detach(),
            momentum,
        );
        bn.running_mean.update(running_mean.detach());
        bn.running_var.update(running_variance.detach());
        return;
    }
    let update = |state: &burn::module::RunningState<Tensor<1>>, batch: Tensor<1>| {
        let device = batch.device();
        let old = state.value_sync().to_device(&device);
        let new = old
            .mul_scalar(1.0 - momentum)
            .add(batch.detach().mul_scalar(momentum));
        state.update(new.detach());
    };
    update(&bn.running_mean, mean);
    update(&bn.running_var, variance);
}

/// Batch norm over [rows, C] whose statistics use only the rows where `valid` ([rows, 1])
/// is 1, `count` of them. Mirrors `BatchNorm::forward`: batch statistics (biased
/// variance) and a running-statistics update when training on an autodiff device, the
/// running statistics otherwise.
pub fn masked_batch_norm(
    bn: &BatchNorm,
    x: Tensor<2>,
    valid: &Tensor<2>,
    count: usize,
) -> Tensor<2> {
    if !(x.device().is_autodiff() && bn.training.is_enabled()) {
        return bn.forward(x);
    }
    let [channels] = bn.gamma.shape().dims();
    let n = count.max(1) as f64;
    let mean = (x.clone() * valid.clone()).sum_dim(0).div_scalar(n); // [1, C]
    let centered = x - mean.clone();
    let var = (centered.clone().square() * valid.clone())
        .sum_dim(0)
        .div_scalar(n);
    let out = centered / var.clone().add_scalar(bn.epsilon).sqrt()
        * bn.gamma.val().reshape([1, channels])
        + bn.beta.val().reshape([1, channels]);
    let momentum = bn.momentum;
    let update = |state: &burn::module::RunningState<Tensor<1>>, batch: Tensor<2>| {
        let device = batch.device();
        let old = state.value_sync().to_device(&device);
        let new = old
            .mul_scalar(1.0 - momentum)
            .add(batch.detach().reshape([channels]).mul_scalar(momentum));
        state.update(new.detach());
    };
    update(&bn.running_mean, mean);
    update(&bn.running_var, var);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;

    fn values(t: Tensor<2>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    fn close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}");
        for (x, y) in a.iter().zip(b) {
            assert!(
                (x - y).abs() <= 2e-5 * (1.0 + y.abs()),
                "{what}: {x} vs {y}"
            );
        }
    }

    /// The fused training norm against burn's `BatchNorm::forward`: output, the input's,
    /// γ's and β's gradients and the running statistics, for one row, a few and many,
    /// with offsets that make the variance small against the mean.
    #[test]
    fn norm_rows_matches_burns_batch_norm_in_training() {
        let device = Device::flex().autodiff();
        for (rows, c) in [(1, 3), (3, 4), (700, 9)] {
            let x: Vec<f32> = (0..rows * c)
                .map(|i| 100.0 + ((i * 37) % 23) as f32 * 0.125 - (i % c) as f32 * 3.0)
                .collect();
            let g: Vec<f32> = (0..rows * c).map(|i| ((i * 13) % 7) as f32 - 3.0).collect();
            let run = |fused: bool| {
                let mut bn = batch_norm(c, &NormConfig::default(), &device);
                let gamma: Vec<f32> = (0..c).map(|i| 0.5 + i as f32 * 0.25).collect();
                let beta: Vec<f32> = (0..c).map(|i| i as f32 * 0.1 - 0.2).collect();
                bn.gamma =
                    Param::from_tensor(Tensor::from_data(TensorData::new(gamma, [c]), &device));
                bn.beta =
                    Param::from_tensor(Tensor::from_data(TensorData::new(beta, [c]), &device));
                let input = Tensor::<2>::from_data(TensorData::new(x.clone(), [rows, c]), &device)
                    .require_grad();
                let out = if fused {
                    assert!(ragged::custom_path(&input));
                    norm_rows(&bn, input.clone())
                } else {
                    bn.forward(input.clone())
                };
                let weights =
                    Tensor::<2>::from_data(TensorData::new(g.clone(), [rows, c]), &device);
                let grads = (out.clone() * weights).sum().backward();
                let grad1 = |t: Tensor<1>| t.try_into_vec_as::<f32>().unwrap();
                (
                    values(out),
                    values(input.grad(&grads).unwrap()),
                    grad1(bn.gamma.val().grad(&grads).unwrap()),
                    grad1(bn.beta.val().grad(&grads).unwrap()),
                    grad1(bn.running_mean.value()),
                    grad1(bn.running_var.value()),
                )
            };
            let (fused, generic) = (run(true), run(false));
            close(&fused.0, &generic.0, "output");
            close(&fused.1, &generic.1, "input gradient");
            close(&fused.2, &generic.2, "γ gradient");
            close(&fused.3, &generic.3, "β gradient");
            close(&fused.4, &generic.4, "running mean");
            close(&fused.5, &generic.5, "running variance");
        }
    }

    /// Norm + ReLU as one operation against the norm followed by burn's ReLU, both layouts:
    /// output and the three gradients to the bit (about half the outputs are cut).
    #[test]
    fn the_fused_relu_gives_the_separate_relus_bits() {
        let device = Device::flex().autodiff();
        let (rows, c) = (600, 5);
        let x: Vec<f32> = (0..rows * c)
            .map(|i| ((i * 37) % 23) as f32 * 0.125 - (i % c) as f32 * 0.5)
            .collect();
        let g: Vec<f32> = (0..rows * c).map(|i| ((i * 13) % 7) as f32 - 3.0).collect();
        let run = |layout: NormLayout, fused: bool| {
            let mut bn = batch_norm(c, &NormConfig::default(), &device);
            let beta: Vec<f32> = (0..c).map(|i| i as f32 * 0.1 - 0.2).collect();
            bn.beta = Param::from_tensor(Tensor::from_data(TensorData::new(beta, [c]), &device));
            let shape = match layout {
                NormLayout::Rows => vec![rows, c],
                NormLayout::Maps => vec![4, c, rows / 4],
            };
            let input = Tensor::<2>::from_data(TensorData::new(x.clone(), [rows, c]), &device)
                .require_grad();
            assert!(ragged::custom_path(&input) && bn.training.is_enabled());
            let (out, weights_shape) = match layout {
                NormLayout::Rows => {
                    let out = if fused {
                        norm_rows_relu(&bn, input.clone())
                    } else {
                        activation::relu(norm_rows(&bn, input.clone()))
                    };
                    (out, [rows, c])
                }
                NormLayout::Maps => {
                    let maps = input.clone().reshape([shape[0], shape[1], shape[2]]);
                    let out = if fused {
                        norm_maps_relu(&bn, maps)
                    } else {
                        activation::relu(norm_maps(&bn, maps))
                    };
                    (out.reshape([rows, c]), [rows, c])
                }
            };
            let weights =
                Tensor::<2>::from_data(TensorData::new(g.clone(), weights_shape), &device);
            let grads = (out.clone() * weights).sum().backward();
            let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
            let grad1 = |t: Tensor<1>| bits(t.try_into_vec_as::<f32>().unwrap());
            let out = values(out);
            let cut = out.iter().filter(|&&v| v == 0.0).count();
            assert!(cut > rows * c / 4 && cut < rows * c * 3 / 4, "{cut} cut");
            (
                bits(out),
                bits(values(input.grad(&grads).unwrap())),
                grad1(bn.gamma.val().grad(&grads).unwrap()),
                grad1(bn.beta.val().grad(&grads).unwrap()),
            )
        };
        for layout in [NormLayout::Rows, NormLayout::Maps] {
            assert_eq!(run(layout, true), run(layout, false), "{layout:?}");
        }
    }

    /// The fused map norm against burn's `BatchNorm::forward` on [B, C, …] maps of rank 3
    /// and 4 (a frame of one value, odd sizes, a map large enough to be split into many
    /// tasks): output, gradients of the input, γ and β, and the running statistics.
    #[test]
    fn norm_maps_matches_burns_batch_norm_in_training() {
        let device = Device::flex().autodiff();
        fn check<const D: usize>(shape: [usize; D], device: &Device) {
            let c = shape[1];
            let n: usize = shape.iter().product();
            let x: Vec<f32> = (0..n)
                .map(|i| 50.0 + ((i * 37) % 23) as f32 * 0.125 - ((i / 3) % c) as f32 * 2.0)
                .collect();
            let g: Vec<f32> = (0..n).map(|i| ((i * 13) % 7) as f32 - 3.0).collect();
            let run = |fused: bool| {
                let mut bn = batch_norm(c, &NormConfig::default(), device);
                let gamma: Vec<f32> = (0..c).map(|i| 0.5 + i as f32 * 0.25).collect();
                let beta: Vec<f32> = (0..c).map(|i| i as f32 * 0.1 - 0.2).collect();
                bn.gamma =
                    Param::from_tensor(Tensor::from_data(TensorData::new(gamma, [c]), device));
                bn.beta = Param::from_tensor(Tensor::from_data(TensorData::new(beta, [c]), device));
                let input = Tensor::<D>::from_data(TensorData::new(x.clone(), shape), device)
                    .require_grad();
                let out = if fused {
                    assert!(ragged::custom_path(&input));
                    norm_maps(&bn, input.clone())
                } else {
                    bn.forward(input.clone())
                };
                let weights = Tensor::<D>::from_data(TensorData::new(g.clone(), shape), device);
                let grads = (out.clone() * weights).sum().backward();
                let vec = |t: Tensor<1>| t.try_into_vec_as::<f32>().unwrap();
                let flat = |t: Tensor<D>| t.try_into_vec_as::<f32>().unwrap();
                (
                    flat(out),
                    flat(input.grad(&grads).unwrap()),
                    vec(bn.gamma.val().grad(&grads).unwrap()),
                    vec(bn.beta.val().grad(&grads).unwrap()),
                    vec(bn.running_mean.value()),
                    vec(bn.running_var.value()),
                )
            };
            let (fused, generic) = (run(true), run(false));
            let what = format!("{shape:?}");
            close(&fused.0, &generic.0, &format!("{what} output"));
            close(&fused.1, &generic.1, &format!("{what} input gradient"));
            close(&fused.2, &generic.2, &format!("{what} γ gradient"));
            close(&fused.3, &generic.3, &format!("{what} β gradient"));
            close(&fused.4, &generic.4, &format!("{what} running mean"));
            close(&fused.5, &generic.5, &format!("{what} running variance"));
        }
        check([1, 2, 1], &device);
        check([3, 4, 7], &device);
        check([2, 3, 4, 5], &device);
        check([2, 5, 33, 40], &device);
    }

    /// Inference keeps burn's own norm on maps too.
    #[test]
    fn norm_maps_in_inference_keeps_burns_norm() {
        let device = Device::flex();
        let bn = batch_norm(2, &NormConfig::default(), &device);
        let x = Tensor::<3>::from_floats([[[1.0, 2.0], [3.0, 5.0]]], &device);
        let flat = |t: Tensor<3>| t.try_into_vec_as::<f32>().unwrap();
        assert_eq!(flat(norm_maps(&bn, x.clone())), flat(bn.forward(x)));
    }

    /// Inference (no autodiff) keeps burn's own norm: the running statistics.
    #[test]
    fn inference_keeps_burns_norm() {
        let device = Device::flex();
        let bn = batch_norm(2, &NormConfig::default(), &device);
        let x = Tensor::<2>::from_floats([[1.0, 2.0], [3.0, 5.0]], &device);
        assert_eq!(values(norm_rows(&bn, x.clone())), values(bn.forward(x)));
    }
}
