//! The fully convolutional network over the slice sequence (channels-first [B, C, L]).
//!
//! Block 1 keeps the finest resolution (Car: 280); blocks 2–4 halve it (140, 70, 35) and
//! merge the next scale's slice features with a 1×1 convolution; transposed convolutions
//! bring blocks 2–4 to the block-2 resolution and their outputs are concatenated.

use crate::config::ModelConfig;
use burn::nn::conv::{Conv1d, Conv1dConfig, ConvTranspose1d, ConvTranspose1dConfig};
use burn::nn::{BatchNorm, PaddingConfig1d};
use burn::prelude::*;
use fusiondet_nn::conv2d::conv1d;
use fusiondet_nn::deconv::deconv1d;
use fusiondet_nn::{batch_norm, norm_maps_relu};

/// Conv1d + BatchNorm + ReLU.
#[derive(Module, Debug)]
pub struct ConvBnRelu {
    pub conv: Conv1d,
    pub norm: BatchNorm,
}

impl ConvBnRelu {
    pub fn new(
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        padding: usize,
        config: &ModelConfig,
        device: &Device,
    ) -> Self {
        Self {
            conv: Conv1dConfig::new(c_in, c_out, kernel)
                .with_stride(stride)
                .with_padding(PaddingConfig1d::Explicit(padding, padding))
                .with_bias(config.bias_before_norm)
                .init(device),
            norm: batch_norm(c_out, &config.norm(), device),
        }
    }

    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        norm_maps_relu(&self.norm, conv1d(&self.conv, x))
    }
}

/// ConvTranspose1d (kernel = stride, no padding) + BatchNorm + ReLU.
#[derive(Module, Debug)]
pub struct DeconvBnRelu {
    pub deconv: ConvTranspose1d,
    pub norm: BatchNorm,
}

impl DeconvBnRelu {
    pub fn new(
        c_in: usize,
        c_out: usize,
        stride: usize,
        config: &ModelConfig,
        device: &Device,
    ) -> Self {
        Self {
            deconv: ConvTranspose1dConfig::new([c_in, c_out], stride)
                .with_stride(stride)
                .with_bias(config.bias_before_norm)
                .init(device),
            norm: batch_norm(c_out, &config.norm(), device),
        }
    }

    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        norm_maps_relu(&self.norm, deconv1d(&self.deconv, x))
    }
}

/// Blocks 2–4: a stride-2 convolution, a stride-1 convolution, and the 1×1 merge with
/// the next scale's slice features.
#[derive(Module, Debug)]
pub struct DownBlock {
    pub down: ConvBnRelu,
    pub conv: ConvBnRelu,
    pub merge: ConvBnRelu,
}

impl DownBlock {
    fn new(
        c_in: usize,
        c_out: usize,
        scale_channels: usize,
        config: &ModelConfig,
        device: &Device,
    ) -> Self {
        Self {
            down: ConvBnRelu::new(c_in, c_out, 3, 2, 1, config, device),
            conv: ConvBnRelu::new(c_out, c_out, 3, 1, 1, config, device),
            merge: ConvBnRelu::new(c_out + scale_channels, c_out, 1, 1, 0, config, device),
        }
    }

    /// `x` [B, C_in, L], `scale` [B, C_scale, ceil(L/2)] → [B, C_out, ceil(L/2)].
    pub fn forward(&self, x: Tensor<3>, scale: Tensor<3>) -> Tensor<3> {
        let x = self.conv.forward(self.down.forward(x));
        self.merge.forward(Tensor::cat(vec![x, scale], 1))
    }
}

#[derive(Module, Debug)]
pub struct Fcn {
    pub block1: ConvBnRelu,
    pub block2: DownBlock,
    pub block3: DownBlock,
    pub block4: DownBlock,
    /// Transposed convolutions of blocks 2, 3, 4 (strides 1, 2, 4).
    pub deconv2: DeconvBnRelu,
    pub deconv3: DeconvBnRelu,
    pub deconv4: DeconvBnRelu,
}

impl Fcn {
    pub fn new(config: &ModelConfig, device: &Device) -> Self {
        let c = &config.fcn_channels;
        let s = |k| config.scale_feature_channels(k);
        let d = config.deconv_channels;
        Self {
            block1: ConvBnRelu::new(s(0), c[0], 3, 1, 1, config, device),
            block2: DownBlock::new(c[0], c[1], s(1), config, device),
            block3: DownBlock::new(c[1], c[2], s(2), config, device),
            block4: DownBlock::new(c[2], c[3], s(3), config, device),
            deconv2: DeconvBnRelu::new(c[1], d, 1, config, device),
            deconv3: DeconvBnRelu::new(c[2], d, 2, config, device),
            deconv4: DeconvBnRelu::new(c[3], d, 4, config, device),
        }
    }

    /// The four scales' slice features, [B, C_k, L_k] → [B, 3 · deconv channels, L_2].
    pub fn forward(&self, scales: [Tensor<3>; 4]) -> Tensor<3> {
        let [x1, x2, x3, x4] = scales;
        let x = self.block1.forward(x1);
        let b2 = self.block2.forward(x, x2);
        let b3 = self.block3.forward(b2.clone(), x3);
        let b4 = self.block4.forward(b3.clone(), x4);
        let len = b2.dims()[2];
        let crop = |t: Tensor<3>| {
            if t.dims()[2] == len {
                t
            } else {
                t.narrow(2, 0, len)
            }
        };
        Tensor::cat(
            vec![
                self.deconv2.forward(b2),
                crop(self.deconv3.forward(b3)),
                crop(self.deconv4.forward(b4)),
            ],
            1,
        )
    }
}
