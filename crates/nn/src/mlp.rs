//! One point-wise MLP layer: Linear + BatchNorm + ReLU on [rows, channels] (point-wise
//! MLPs as `Linear`, which is several times faster than a 1×1 convolution here).

use crate::norm::{NormConfig, batch_norm, masked_batch_norm, norm_rows, norm_rows_relu};
use burn::nn::{BatchNorm, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Linear + BatchNorm + ReLU on [rows, channels].
#[derive(Module, Debug)]
pub struct MlpLayer {
    pub linear: Linear,
    pub norm: BatchNorm,
    /// For inference only: the linear layer with the batch norm's running statistics and
    /// affine folded in (weight, bias); see [`MlpLayer::fold_norm`].
    #[module(skip)]
    folded: Option<(Tensor<2>, Tensor<1>)>,
}

impl MlpLayer {
    pub fn new(d_in: usize, d_out: usize, config: &NormConfig, device: &Device) -> Self {
        Self {
            linear: LinearConfig::new(d_in, d_out)
                .with_bias(config.bias_before_norm)
                .init(device),
            norm: batch_norm(d_out, config, device),
            folded: None,
        }
    }

    /// Folds the batch norm's inference transform into the linear layer: with
    /// s = γ / √(σ² + ε), W' = W·diag(s) and b' = (b − μ)·s + β, so the layer is one matrix
    /// product and a bias instead of a product and the norm's passes over its output. Only
    /// for inference (training needs the batch statistics); the result differs from the
    /// unfolded layer by float rounding alone. Checkpoints are never written from it.
    pub fn fold_norm(&mut self) {
        let norm = &self.norm;
        let eps = norm.epsilon;
        let scale = norm.gamma.val() / norm.running_var.value().add_scalar(eps).sqrt();
        let d_out = scale.dims()[0];
        let weight = self.linear.weight.val() * scale.clone().reshape([1, d_out]);
        let bias = match &self.linear.bias {
            Some(b) => b.val() - norm.running_mean.value(),
            None => -norm.running_mean.value(),
        };
        let bias = bias * scale + norm.beta.val();
        self.folded = Some((weight, bias));
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let y = self.linear_map(x);
        match &self.folded {
            Some(_) => relu(y),
            None => norm_rows_relu(&self.norm, y),
        }
    }

    /// Linear + BatchNorm, without the ReLU.
    pub fn forward_pre_activation(&self, x: Tensor<2>) -> Tensor<2> {
        self.normalize(self.linear_map(x))
    }

    /// x·W + b: the folded map when the norm is folded, else the `Linear` (in training
    /// through [`crate::linear`]; burn's generic `linear` allocates, copies and transposes
    /// around its product).
    fn linear_map(&self, x: Tensor<2>) -> Tensor<2> {
        match &self.folded {
            Some((weight, bias)) => {
                burn::tensor::module::linear(x, weight.clone(), Some(bias.clone()))
            }
            None => crate::linear::linear(&self.linear, x),
        }
    }

    /// The linear map the layer applies before its norm, (W [in, out], b): the folded one
    /// when the norm is folded. For callers that evaluate the product in parts (a sum of
    /// products over blocks of input columns) and then call
    /// [`normalize`](Self::normalize) on the sum.
    pub fn affine(&self) -> (Tensor<2>, Option<Tensor<1>>) {
        match &self.folded {
            Some((weight, bias)) => (weight.clone(), Some(bias.clone())),
            None => (
                self.linear.weight.val(),
                self.linear.bias.as_ref().map(|b| b.val()),
            ),
        }
    }

    /// The norm applied to the output of [`affine`](Self::affine)'s map (nothing when folded
    /// into it); no ReLU.
    pub fn normalize(&self, y: Tensor<2>) -> Tensor<2> {
        match &self.folded {
            Some(_) => y,
            None => norm_rows(&self.norm, y),
        }
    }

    /// Like [`forward`](Self::forward), with batch-norm statistics over the rows where
    /// `valid` is 1 (in training mode; inference uses the running statistics either way).
    pub fn forward_masked(&self, x: Tensor<2>, valid: &Tensor<2>, count: usize) -> Tensor<2> {
        assert!(
            self.folded.is_none(),
            "the masked form checks training statistics; a folded layer has none"
        );
        let x = crate::linear::linear(&self.linear, x);
        relu(masked_batch_norm(&self.norm, x, valid, count))
    }

    pub fn out_channels(&self) -> usize {
        self.norm.gamma.shape().dims::<1>()[0]
    }

    /// Whether the norm is folded into the linear map ([`MlpLayer::fold_norm`]), so that
    /// [`normalize`](Self::normalize) leaves its input as it is.
    pub fn is_folded(&self) -> bool {
        self.folded.is_some()
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

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;

    /// A layer with non-trivial running statistics and affine, folded, computes what the
    /// unfolded layer does in inference mode (to float rounding).
    #[test]
    fn folding_the_norm_keeps_the_inference_function() {
        let device = Device::flex();
        for bias in [false, true] {
            let config = NormConfig {
                bias_before_norm: bias,
                ..NormConfig::default()
            };
            let mut layer = MlpLayer::new(5, 4, &config, &device);
            layer.norm.gamma =
                Param::from_tensor(Tensor::from_floats([0.5, 2.0, -1.0, 1.5], &device));
            layer.norm.beta =
                Param::from_tensor(Tensor::from_floats([0.1, -0.3, 0.0, 2.0], &device));
            layer.norm.running_mean = burn::module::RunningState::new(Tensor::from_floats(
                [1.0, -2.0, 0.5, 0.0],
                &device,
            ));
            layer.norm.running_var = burn::module::RunningState::new(Tensor::from_floats(
                [0.25, 4.0, 1.0, 9.0],
                &device,
            ));
            let x = Tensor::<2>::from_floats(
                [
                    [0.3, -1.2, 2.0, 0.0, 5.0],
                    [-3.0, 0.7, 0.1, 1.0, -0.5],
                    [10.0, 20.0, -30.0, 4.0, 0.25],
                ],
                &device,
            );
            let plain: Vec<f32> = layer
                .forward_pre_activation(x.clone())
                .into_data()
                .try_to_vec()
                .unwrap();
            layer.fold_norm();
            let folded: Vec<f32> = layer
                .forward_pre_activation(x.clone())
                .into_data()
                .try_to_vec()
                .unwrap();
            for (a, b) in plain.iter().zip(&folded) {
                assert!(
                    (a - b).abs() <= 1e-4 * (1.0 + a.abs()),
                    "{plain:?} vs {folded:?}"
                );
            }
            // The ReLU'd form follows.
            let relu_folded: Vec<f32> = layer.forward(x).into_data().try_to_vec().unwrap();
            for (a, b) in folded.iter().zip(&relu_folded) {
                assert_eq!(a.max(0.0), *b);
            }
        }
    }
}
