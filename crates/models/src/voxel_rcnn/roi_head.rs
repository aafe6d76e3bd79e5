//! The RoI head: pooled grid features through shared fully connected layers, then a
//! confidence branch (one IoU-guided score per RoI) and a class-agnostic box-refinement
//! branch (7 residuals in the RoI's canonical frame). FC layers have no bias (BN
//! follows); dropout between the layers of a branch, as OpenPCDet's VoxelRCNNHead.

use super::config::RoiHeadConfig;
use super::roi_pool::LinearBn;
use burn::module::Param;
use burn::nn::{Dropout, DropoutConfig, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::Distribution;

/// FC + BN + ReLU layers with dropout between them (not after the last).
#[derive(Module, Debug)]
pub struct FcStack {
    pub layers: Vec<LinearBn>,
    pub dropout: Dropout,
}

impl FcStack {
    fn new(input: usize, widths: &[usize], dropout: f64, device: &Device) -> Self {
        let mut c = input;
        let layers = widths
            .iter()
            .map(|&w| {
                let layer = LinearBn::new([c, w], device);
                c = w;
                layer
            })
            .collect();
        Self {
            layers,
            dropout: DropoutConfig::new(dropout).init(),
        }
    }

    pub fn forward(&self, mut x: Tensor<2>) -> Tensor<2> {
        let n = self.layers.len();
        for (i, layer) in self.layers.iter().enumerate() {
            x = layer.forward_relu(x);
            if i + 1 < n {
                x = self.dropout.forward(x);
            }
        }
        x
    }

    fn output_width(&self, input: usize) -> usize {
        self.layers
            .last()
            .map_or(input, |l| l.linear.weight.dims()[1])
    }
}

#[derive(Module, Debug)]
pub struct RoiHead {
    pub shared: FcStack,
    pub cls: FcStack,
    pub cls_out: Linear,
    pub reg: FcStack,
    pub reg_out: Linear,
}

/// Per RoI: [RoIs, 1] confidence logit and [RoIs, code size] residuals.
#[derive(Debug, Clone)]
pub struct RoiPredictions {
    pub cls: Tensor<2>,
    pub boxes: Tensor<2>,
}

impl RoiHead {
    pub fn new(config: &RoiHeadConfig, input: usize, device: &Device) -> Self {
        let shared = FcStack::new(input, &config.shared_fc, config.dropout, device);
        let c = shared.output_width(input);
        let cls = FcStack::new(c, &config.cls_fc, config.dropout, device);
        let reg = FcStack::new(c, &config.reg_fc, config.dropout, device);
        let out = |stack: &FcStack, n: usize, std: f64| {
            let mut layer = LinearConfig::new(stack.output_width(c), n).init(device);
            layer.weight = Param::from_tensor(Tensor::random(
                [stack.output_width(c), n],
                Distribution::Normal(0.0, std),
                device,
            ));
            layer.bias = Some(Param::from_tensor(Tensor::zeros([n], device)));
            layer
        };
        // Small output initialisations, as OpenPCDet's: the refinement starts near zero.
        Self {
            cls_out: out(&cls, 1, 0.01),
            reg_out: out(&reg, config.code_size, 0.001),
            shared,
            cls,
            reg,
        }
    }

    pub fn forward(&self, pooled: Tensor<2>) -> RoiPredictions {
        let shared = self.shared.forward(pooled);
        RoiPredictions {
            cls: self.cls_out.forward(self.cls.forward(shared.clone())),
            boxes: self.reg_out.forward(self.reg.forward(shared)),
        }
    }

    /// Multiply-adds per RoI.
    pub fn multiply_adds_per_roi(&self) -> u64 {
        let linear = |l: &Linear| {
            let [a, b] = l.weight.dims();
            (a * b) as u64
        };
        let stack = |s: &FcStack| s.layers.iter().map(|l| linear(&l.linear)).sum::<u64>();
        stack(&self.shared)
            + stack(&self.cls)
            + stack(&self.reg)
            + linear(&self.cls_out)
            + linear(&self.reg_out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::activation::relu;

    /// Trained to tell two kinds of rows apart, the head still tells them apart in
    /// inference mode (batch norm on running statistics, no dropout).
    #[test]
    fn a_trained_head_separates_its_inputs_at_inference() {
        let device = Device::flex().autodiff();
        let config = RoiHeadConfig {
            shared_fc: vec![16],
            cls_fc: vec![16],
            reg_fc: vec![16],
            ..RoiHeadConfig::default()
        };
        let mut head = RoiHead::new(&config, 4, &device);
        let rows: Vec<f32> = (0..32)
            .flat_map(|i| {
                let s = if i % 2 == 0 { 1.0 } else { -1.0 };
                [s, 0.5 * s, (i as f32 * 0.37).sin(), 0.2]
            })
            .collect();
        let x = Tensor::<2>::from_data(TensorData::new(rows, [32, 4]), &device);
        let t: Vec<f32> = (0..32)
            .map(|i| if i % 2 == 0 { 1.0 } else { 0.0 })
            .collect();
        let t = Tensor::<2>::from_data(TensorData::new(t, [32, 1]), &device);
        let mut optim = AdamConfig::new().init();
        for _ in 0..150 {
            let logits = head.forward(x.clone()).cls;
            let loss = (relu(logits.clone()) - logits.clone() * t.clone()
                + logits.abs().neg().exp().log1p())
            .mean();
            let grads = GradientsParams::from_grads(loss.backward(), &head);
            head = optim.step(1e-2, head, grads);
        }
        let valid = head.valid();
        let out: Vec<f32> = valid
            .forward(x.inner())
            .cls
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        for (i, v) in out.iter().enumerate() {
            assert!(
                if i % 2 == 0 { *v > 1.0 } else { *v < -1.0 },
                "row {i}: {out:?}"
            );
        }
    }
}
