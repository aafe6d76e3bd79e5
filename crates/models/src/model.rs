//! The F-ConvNet first-stage network: per-scale slice encoders → FCN → heads.

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::fcn::Fcn;
use crate::heads::Heads;
use crate::inputs::BatchInputs;
use crate::lfa::Lfa;
use crate::pointnet::SliceEncoder;
use burn::prelude::*;
use fusiondet_frustum::FrustumBatch;

/// Network outputs for a batch.
#[derive(Debug, Clone)]
pub struct FConvNetOutput {
    /// [batch, positions, 2]: logits of (background, object) per output position.
    pub cls_logits: Tensor<3>,
    /// [batch, positions, R]: see [`RegressionLayout`](crate::heads::RegressionLayout).
    pub regression: Tensor<3>,
}

#[derive(Module, Debug)]
pub struct FConvNet {
    /// SAF's local feature aggregation (absent in F-ConvNet and FCAM).
    pub lfa: Option<Lfa>,
    /// One encoder per scale, finest first.
    pub encoders: Vec<SliceEncoder>,
    pub fcn: Fcn,
    pub heads: Heads,
    #[module(skip)]
    config: ModelConfig,
}

impl FConvNet {
    /// A freshly initialised network on `device` (use `device.autodiff()` for training).
    pub fn new(config: &ModelConfig, device: &Device) -> Result<Self, ModelError> {
        config.validate()?;
        Ok(Self {
            lfa: config.lfa.as_ref().map(|l| Lfa::new(config, l, device)),
            encoders: config
                .pointnet_widths
                .iter()
                .map(|w| SliceEncoder::new(w, config, device))
                .collect(),
            fcn: Fcn::new(config, device),
            heads: Heads::new(config, device),
            config: config.clone(),
        })
    }

    /// For inference: folds every point-wise MLP layer's batch norm into its linear layer
    /// (LFA and the per-scale PointNets, where the norms run over every point or pair;
    /// see [`MlpLayer::fold_norm`](fusiondet_nn::MlpLayer::fold_norm)). The FCN's norms
    /// run over a few hundred positions per frustum and stay as they are.
    pub fn fold_norms(&mut self) {
        let lfa_layers = self
            .lfa
            .iter_mut()
            .flat_map(|l| l.stages.iter_mut())
            .flat_map(|s| s.local.iter_mut().chain(s.point.iter_mut()));
        let encoder_layers = self.encoders.iter_mut().flat_map(|e| match e {
            SliceEncoder::PointNet(p) => p.layers.iter_mut(),
        });
        for layer in lfa_layers.chain(encoder_layers) {
            layer.fold_norm();
        }
    }

    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// Validates the batch and builds its tensors on `device` (see [`BatchInputs::new`]).
    pub fn inputs(&self, batch: &FrustumBatch, device: &Device) -> Result<BatchInputs, ModelError> {
        BatchInputs::new(batch, &self.config, device)
    }

    /// Convenience: [`inputs`](Self::inputs) then [`forward_inputs`](Self::forward_inputs) on
    /// `device`.
    pub fn forward(
        &self,
        batch: &FrustumBatch,
        device: &Device,
    ) -> Result<FConvNetOutput, ModelError> {
        Ok(self.forward_inputs(&self.inputs(batch, device)?))
    }

    /// The forward pass (ragged PointNets).
    pub fn forward_inputs(&self, inputs: &BatchInputs) -> FConvNetOutput {
        let point_features = match (&self.lfa, &inputs.lfa) {
            (Some(lfa), Some(li)) => Some(lfa.forward(li)),
            _ => None,
        };
        let feats: Vec<Tensor<2>> = self
            .encoders
            .iter()
            .zip(&inputs.scales)
            .map(|(enc, scale)| enc.forward(scale, point_features.as_ref()))
            .collect();
        self.forward_from_slice_features(inputs, feats)
    }

    /// The forward pass with the padded PointNet form (slow; for checking the ragged one).
    pub fn forward_inputs_padded(&self, inputs: &BatchInputs) -> FConvNetOutput {
        let feats: Vec<Tensor<2>> = self
            .encoders
            .iter()
            .zip(&inputs.scales)
            .map(|(enc, scale)| enc.forward_padded(&scale.padded(inputs.device())))
            .collect();
        self.forward_from_slice_features(inputs, feats)
    }

    /// Slice features [B · L_k, C_k] per scale → heads.
    fn forward_from_slice_features(
        &self,
        inputs: &BatchInputs,
        feats: Vec<Tensor<2>>,
    ) -> FConvNetOutput {
        let b = inputs.batch_size;
        let one_hot = inputs.class_one_hot.clone();
        let classes = one_hot.dims()[1];
        let mut seq = feats.into_iter().zip(&inputs.scales).map(|(f, scale)| {
            let len = scale.slices_per_frustum;
            let c = f.dims()[1];
            let f = f.reshape([b, len, c]).swap_dims(1, 2);
            let oh = one_hot
                .clone()
                .reshape([b, classes, 1])
                .expand([b, classes, len]);
            Tensor::cat(vec![f, oh], 1)
        });
        let scales = std::array::from_fn(|_| seq.next().expect("four scales"));
        let x = self.fcn.forward(scales);
        let (cls_logits, regression) = self.heads.forward(x);
        FConvNetOutput {
            cls_logits,
            regression,
        }
    }
}
