//! Batch norm as the detectors use it: settings of their own, and statistics over the
//! real rows of a padded tensor.

use burn::nn::{BatchNorm, BatchNormConfig};
use burn::prelude::*;
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
