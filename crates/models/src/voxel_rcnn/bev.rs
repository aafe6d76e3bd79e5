//! From the sparse backbone to a dense bird's-eye view (HeightCompression) and
//! OpenPCDet's BaseBEVBackbone over it: per block a strided 3×3 convolution and more 3×3
//! convolutions, each block's output brought back to the first block's resolution by a
//! transposed convolution, all concatenated.

use super::backbone3d::SparseMap;
use super::config::BevConfig;
use burn::nn::BatchNorm;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::prelude::*;
use fusiondet_nn::NormConfig;
use fusiondet_nn::conv2d::conv2d;
use fusiondet_nn::sparse::to_dense_bev;
use fusiondet_nn::{batch_norm, norm_maps_relu};

/// The backbone's output map as a dense [B, C·heights, Y, X] image.
pub fn height_compression(map: &SparseMap) -> Tensor<4> {
    to_dense_bev(map.features.clone(), &map.sites)
}

/// 3×3 convolution (no bias) → BN → ReLU.
#[derive(Module, Debug)]
pub struct ConvBnRelu {
    pub conv: Conv2d,
    pub norm: BatchNorm,
}

impl ConvBnRelu {
    fn new(channels: [usize; 2], stride: usize, norm: &NormConfig, device: &Device) -> Self {
        Self {
            conv: Conv2dConfig::new(channels, [3, 3])
                .with_stride([stride, stride])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .with_bias(false)
                .init(device),
            norm: batch_norm(channels[1], norm, device),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        norm_maps_relu(&self.norm, conv2d(&self.conv, x))
    }
}

/// Transposed convolution (kernel = stride, no bias) → BN → ReLU.
#[derive(Module, Debug)]
pub struct UpsampleBnRelu {
    pub deconv: ConvTranspose2d,
    pub norm: BatchNorm,
}

#[derive(Module, Debug)]
pub struct BevBackbone {
    pub blocks: Vec<Vec<ConvBnRelu>>,
    pub upsample: Vec<UpsampleBnRelu>,
}

impl BevBackbone {
    pub fn new(
        config: &BevConfig,
        input_channels: usize,
        norm: &NormConfig,
        device: &Device,
    ) -> Self {
        let mut c_in = input_channels;
        let mut blocks = Vec::new();
        let mut upsample = Vec::new();
        for i in 0..config.layer_nums.len() {
            let f = config.num_filters[i];
            let mut block = vec![ConvBnRelu::new(
                [c_in, f],
                config.layer_strides[i],
                norm,
                device,
            )];
            block.extend(
                (0..config.layer_nums[i]).map(|_| ConvBnRelu::new([f, f], 1, norm, device)),
            );
            blocks.push(block);
            let (s, u) = (config.upsample_strides[i], config.num_upsample_filters[i]);
            upsample.push(UpsampleBnRelu {
                deconv: ConvTranspose2dConfig::new([f, u], [s, s])
                    .with_stride([s, s])
                    .with_bias(false)
                    .init(device),
                norm: batch_norm(u, norm, device),
            });
            c_in = f;
        }
        Self { blocks, upsample }
    }

    /// Channels of the concatenated output.
    pub fn output_channels(config: &BevConfig) -> usize {
        config.num_upsample_filters.iter().sum()
    }

    pub fn forward(&self, bev: Tensor<4>) -> Tensor<4> {
        let mut x = bev;
        let mut ups = Vec::with_capacity(self.blocks.len());
        for (block, up) in self.blocks.iter().zip(&self.upsample) {
            for layer in block {
                x = layer.forward(x);
            }
            ups.push(norm_maps_relu(&up.norm, up.deconv.forward(x.clone())));
        }
        Tensor::cat(ups, 1)
    }

    /// Multiply-adds of one forward pass on a [heights·C, Y, X] input.
    pub fn multiply_adds(config: &BevConfig, input_channels: usize, [y, x]: [usize; 2]) -> u64 {
        let (mut c_in, mut hw) = (input_channels as u64, (y as u64, x as u64));
        let mut total = 0;
        for i in 0..config.layer_nums.len() {
            let s = config.layer_strides[i] as u64;
            hw = (hw.0.div_ceil(s), hw.1.div_ceil(s));
            let f = config.num_filters[i] as u64;
            let cells = hw.0 * hw.1;
            total += cells * 9 * (c_in * f + config.layer_nums[i] as u64 * f * f);
            // The transposed convolution writes `stride²` outputs per input cell.
            total += cells
                * f
                * config.num_upsample_filters[i] as u64
                * (config.upsample_strides[i] as u64).pow(2);
            c_in = f;
        }
        total
    }
}
