//! Per-slice encoders: a shared PointNet over each scale's (point, sub-frustum) pairs,
//! max-pooled into one feature vector per sub-frustum.
//!
//! The ragged form runs the MLP on exactly the real pairs ([pairs, C]), then max-pools
//! through gather indices (see [`SegmentPool`](fusiondet_nn::SegmentPool)); batch-norm
//! statistics are over the real pairs. The last ReLU is applied after the pool
//! (max and ReLU commute, gradients included), on slices instead of pairs. The padded form (every slice padded to the cap, masked) computes the
//! same function with far more work and exists to check the ragged one.

use crate::attention::Cbam;
use crate::config::{CoordinateInit, ModelConfig, SliceEncoderKind};
use crate::inputs::{PaddedScaleInputs, ScaleInputs};
use burn::module::Param;
use burn::nn::LinearConfig;
use burn::prelude::*;
use burn::tensor::activation::relu;
use fusiondet_nn::{MlpLayer, mlp_stack};

/// Redraws the first 3 rows of `layer`'s weight (the pair coordinates) as a linear layer
/// with those 3 inputs alone draws them (see [`CoordinateInit::Own`]).
fn draw_coordinate_rows_alone(layer: &mut MlpLayer, device: &Device) {
    let weight = layer.linear.weight.val();
    let [d_in, d_out] = weight.dims();
    let own = LinearConfig::new(3, d_out).init(device).weight.val();
    let features = weight.slice([3..d_in, 0..d_out]);
    // Detached: on an autodiff device the concatenation is not a leaf, and a parameter must be.
    layer.linear.weight = Param::from_tensor(Tensor::cat(vec![own, features], 0).detach());
}

/// The PointNet of F-ConvNet: a shared MLP on pair coordinates relative to the slice
/// centre, max-pooled per slice (empty slices give zeros). FCAM's variants attend the
/// outputs of some hidden layers with CBAM ([`Cbam`]).
#[derive(Module, Debug)]
pub struct PointNet {
    pub layers: Vec<MlpLayer>,
    /// One block per entry of `attention_after`.
    pub attention: Vec<Cbam>,
    #[module(skip)]
    attention_after: Vec<usize>,
}

impl PointNet {
    pub fn new(widths: &[usize], config: &ModelConfig, device: &Device) -> Self {
        let mut layers = mlp_stack(
            config.pointnet_input_channels(),
            widths,
            &config.norm(),
            device,
        );
        if config
            .lfa
            .as_ref()
            .is_some_and(|l| l.coordinate_init == CoordinateInit::Own)
        {
            draw_coordinate_rows_alone(&mut layers[0], device);
        }
        let attention_after = if config.slice_encoder.uses_attention() {
            config.attention.after_layers.clone()
        } else {
            Vec::new()
        };
        let improved = config.slice_encoder == SliceEncoderKind::ImprovedCbam;
        let attention = attention_after
            .iter()
            .map(|&l| Cbam::new(widths[l], improved, &config.attention, device))
            .collect();
        Self {
            layers,
            attention,
            attention_after,
        }
    }

    /// Hidden layer `l`'s output, attended when a block follows that layer.
    fn attend(&self, l: usize, x: Tensor<2>, scale: &ScaleInputs) -> Tensor<2> {
        match self.attention_after.iter().position(|&a| a == l) {
            Some(k) => {
                let index = scale
                    .attention
                    .as_ref()
                    .expect("inputs built for an attention encoder carry the attention index");
                self.attention[k].forward(x, index)
            }
            None => x,
        }
    }

    pub fn out_channels(&self) -> usize {
        self.layers.last().map_or(3, MlpLayer::out_channels)
    }

    /// Ragged form: [num_slices, C]. `point_features` ([points, C_f], SAF's LFA) are
    /// appended to each pair's relative coordinates.
    pub fn forward(&self, scale: &ScaleInputs, point_features: Option<&Tensor<2>>) -> Tensor<2> {
        let device = scale.rel_coords.device();
        let c = self.out_channels();
        if scale.num_pairs == 0 {
            return Tensor::zeros([scale.num_slices, c], &device);
        }
        let (last, rest) = self.layers.split_last().expect("at least one layer");
        let mut x = match (point_features, &scale.pair_feature_row) {
            (Some(f), Some(rows)) => {
                Tensor::cat(vec![scale.rel_coords.clone(), rows.gather(f.clone())], 1)
            }
            _ => scale.rel_coords.clone(),
        };
        for (l, layer) in rest.iter().enumerate() {
            x = self.attend(l, layer.forward(x), scale);
        }
        relu(scale.pool.max_pool(last.forward_pre_activation(x)))
    }

    /// Padded form: the same function computed on every slice padded to the cap (the plain
    /// PointNet only: it exists to check the ragged form's pooling and batch norm).
    pub fn forward_padded(&self, scale: &PaddedScaleInputs) -> Tensor<2> {
        assert!(
            self.attention.is_empty(),
            "the padded form checks the plain PointNet; attention runs on the ragged form only"
        );
        let c = self.out_channels();
        let mut x = scale.coords.clone();
        for layer in &self.layers {
            x = layer.forward_masked(x, &scale.valid, scale.num_pairs);
        }
        let x = x
            .mask_fill(
                scale
                    .padding
                    .clone()
                    .expand([scale.num_slices * scale.cap, c]),
                f32::NEG_INFINITY,
            )
            .reshape([scale.num_slices, scale.cap, c])
            .max_dim(1)
            .reshape([scale.num_slices, c]);
        x.mask_fill(scale.empty.clone().expand([scale.num_slices, c]), 0.0)
    }
}

/// The swappable per-slice encoder of one scale (see [`SliceEncoderKind`]).
#[derive(Module, Debug)]
pub enum SliceEncoder {
    PointNet(PointNet),
}

impl SliceEncoder {
    pub fn new(widths: &[usize], config: &ModelConfig, device: &Device) -> Self {
        Self::PointNet(PointNet::new(widths, config, device))
    }

    /// Per-slice features, [num_slices, C].
    pub fn forward(&self, scale: &ScaleInputs, point_features: Option<&Tensor<2>>) -> Tensor<2> {
        match self {
            Self::PointNet(p) => p.forward(scale, point_features),
        }
    }

    pub fn forward_padded(&self, scale: &PaddedScaleInputs) -> Tensor<2> {
        match self {
            Self::PointNet(p) => p.forward_padded(scale),
        }
    }

    pub fn out_channels(&self) -> usize {
        match self {
            Self::PointNet(p) => p.out_channels(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::LfaConfig;

    /// With LFA the first layer has 3 + C inputs; `coordinate_init = "own"` draws the three
    /// coordinate rows at ±1/√3 (F-ConvNet's range) and leaves the feature rows at the
    /// layer's ±1/√(3 + C); `shared` draws every row at the layer's.
    #[test]
    fn coordinate_rows_are_drawn_at_their_own_fan_in() {
        let device = Device::flex();
        device.seed(3);
        let largest = |coordinate_init| {
            let config = ModelConfig {
                lfa: Some(LfaConfig {
                    coordinate_init,
                    ..LfaConfig::paper()
                }),
                ..ModelConfig::car()
            };
            let net = PointNet::new(&[128, 128], &config, &device);
            let w = net.layers[0].linear.weight.val();
            let [d_in, d_out] = w.dims();
            assert_eq!(d_in, 515);
            let max = |r: std::ops::Range<usize>| -> f32 {
                w.clone().slice([r, 0..d_out]).abs().max().into_scalar()
            };
            (max(0..3), max(3..d_in))
        };
        let layer_bound = 1.0 / 515f32.sqrt();
        let (coords, features) = largest(CoordinateInit::Shared);
        assert!(coords <= layer_bound && features <= layer_bound);
        let (coords, features) = largest(CoordinateInit::Own);
        assert!(features <= layer_bound, "{features}");
        assert!(
            coords > 5.0 * layer_bound && coords <= 1.0 / 3f32.sqrt(),
            "{coords}"
        );
    }
}
