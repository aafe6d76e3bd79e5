//! One point-wise MLP layer: Linear + BatchNorm + ReLU on [rows, channels] (point-wise
//! MLPs as `Linear`, which is several times faster than a 1×1 convolution here).

use crate::norm::{NormConfig, batch_norm, masked_batch_norm};
use burn::nn::{BatchNorm, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Linear + BatchNorm + ReLU on [rows, channels].
#[derive(Module, Debug)]
pub struct MlpLayer {
    pub linear: Linear,
    pub norm: BatchNorm,
}

impl MlpLayer {
    pub fn new(d_in: usize, d_out: usize, config: &NormConfig, device: &Device) -> Self {
        Self {
            linear: LinearConfig::new(d_in, d_out)
                .with_bias(config.bias_before_norm)
                .init(device),
            norm: batch_norm(d_out, config, device),
        }
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        relu(self.forward_pre_activation(x))
    }

    /// Linear + BatchNorm, without the ReLU.
    pub fn forward_pre_activation(&self, x: Tensor<2>) -> Tensor<2> {
        self.norm.forward(self.linear.forward(x))
    }

    /// Like [`forward`](Self::forward), with batch-norm statistics over the rows where
    /// `valid` is 1 (in training mode; inference uses the running statistics either way).
    pub fn forward_masked(&self, x: Tensor<2>, valid: &Tensor<2>, count: usize) -> Tensor<2> {
        let x = self.linear.forward(x);
        relu(masked_batch_norm(&self.norm, x, valid, count))
    }

    pub fn out_channels(&self) -> usize {
        self.norm.gamma.shape().dims::<1>()[0]
    }
}

/// A stack of [`MlpLayer`]s from `d_in` through `widths`.
pub fn mlp_stack(
    d_in: usize,
    widths: &[usize],
    config: &NormConfig,
    device: &Device,
) -> Vec<MlpLayer> {
    let mut d = d_in;
    widths
        .iter()
        .map(|&w| {
            let layer = MlpLayer::new(d, w, config, device);
            d = w;
            layer
        })
        .collect()
}
