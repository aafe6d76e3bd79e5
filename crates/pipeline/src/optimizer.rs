//! The training optimizer: Adam or AdamW as burn defines them (`[train] optimizer`), with
//! per-parameter gradient clipping by norm where configured (`grad_clip_norm` with the
//! `per_parameter` scope), as one burn [`Optimizer`] for burn's `ModuleOptimizer`.
//!
//! Why not burn's `AdamConfig::init()` as before: on a GPU each parameter's step there is
//! about 23 kernel launches (see `fusiondet_nn::adam`), here one to three
//! ([`fusiondet_nn::adam::fused_step`]). On the CPU a step is burn's own, the clipping
//! included, operation for operation, so CPU training is unchanged to the bit. The state
//! is burn's [`AdamState`], so optimizer records written by burn's Adam or AdamW (every run
//! directory made before) load and resume.

use burn::optim::decay::WeightDecayConfig;
use burn::optim::grad_clipping::GradientClipping;
use burn::optim::{
    Adam, AdamConfig, AdamState, AdamW, AdamWConfig, AdamWState, AdaptiveMomentumState,
    LearningRate, ModuleOptimizer, Optimizer,
};
use burn::prelude::*;
use fusiondet_nn::adam::{AdamSettings, AdamStep, fused_step};

/// β₁, β₂ and ε: burn's defaults for both optimizers (OpenPCDet's Adam and AdamW share the
/// betas; its ε of 1e-8 was never taken here, so trained runs stay comparable).
const BETA_1: f32 = 0.9;
const BETA_2: f32 = 0.999;
const EPSILON: f32 = 1e-5;

/// Which update rule.
#[derive(Clone)]
enum Rule {
    Adam(Adam),
    AdamW(AdamW),
}

/// Adam or AdamW (see the module's documentation).
#[derive(Clone)]
pub struct TrainingOptimizer {
    settings: AdamSettings,
    rule: Rule,
}

impl TrainingOptimizer {
    /// Adam with an L2 penalty of `weight_decay` (`decoupled` false) or AdamW with that
    /// decay rate, each parameter's gradient clipped to `clip_norm` first where given.
    pub fn new(decoupled: bool, weight_decay: f32, clip_norm: Option<f32>) -> Self {
        let rule = if decoupled {
            Rule::AdamW(
                AdamWConfig::new()
                    .with_beta_1(BETA_1)
                    .with_beta_2(BETA_2)
                    .with_epsilon(EPSILON)
                    .with_weight_decay(weight_decay)
                    .build(),
            )
        } else {
            Rule::Adam(
                AdamConfig::new()
                    .with_beta_1(BETA_1)
                    .with_beta_2(BETA_2)
                    .with_epsilon(EPSILON)
                    .with_weight_decay(Some(WeightDecayConfig::new(weight_decay)))
                    .build(),
            )
        };
        TrainingOptimizer {
            settings: AdamSettings {
                beta_1: BETA_1,
                beta_2: BETA_2,
                epsilon: EPSILON,
                weight_decay,
                decoupled,
                clip_norm,
            },
            rule,
        }
    }

    /// The module optimizer burn's training step takes (no clipping of its own: this
    /// optimizer clips).
    pub fn into_module_optimizer(self) -> ModuleOptimizer {
        ModuleOptimizer::from(self)
    }

    /// burn's step: clipping, then burn's Adam or AdamW.
    fn burn_step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<AdamState<D>>,
    ) -> (Tensor<D>, Option<AdamState<D>>) {
        let grad = match self.settings.clip_norm {
            Some(norm) => GradientClipping::Norm(norm).clip_gradient(grad),
            None => grad,
        };
        match &self.rule {
            Rule::Adam(adam) => adam.step(lr, tensor, grad, state),
            Rule::AdamW(adamw) => {
                let state = state.map(|s| AdamWState::new(s.momentum));
                let (tensor, state) = adamw.step(lr, tensor, grad, state);
                (tensor, state.map(|s| AdamState::new(s.momentum)))
            }
        }
    }
}

impl Optimizer for TrainingOptimizer {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        if !fusiondet_nn::adam::fuses(&tensor) {
            return self.burn_step(lr, tensor, grad, state);
        }
        let (time, moments) = match state {
            Some(AdamState { momentum }) => (
                momentum.time + 1,
                Some((momentum.moment_1, momentum.moment_2)),
            ),
            None => (1, None),
        };
        let step = AdamStep::new(&self.settings, lr, time);
        let (tensor, moment_1, moment_2) =
            fused_step(tensor, grad, moments, step).expect("the fused step applies");
        let momentum = AdaptiveMomentumState::new(time, moment_1, moment_2);
        (tensor, Some(AdamState::new(momentum)))
    }

    fn to_device<const D: usize>(mut state: Self::State<D>, device: &Device) -> Self::State<D> {
        state.momentum = state.momentum.to_device(device);
        state
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::GradientsParams;
    use burn::optim::grad_clipping::GradientClippingConfig;

    /// A small network with fixed weights (a bias included: a rank-1 parameter).
    fn network(device: &Device) -> Linear {
        let mut linear = LinearConfig::new(6, 5).init(device);
        let w: Vec<f32> = (0..30)
            .map(|i| ((i * 37) % 23) as f32 / 23.0 - 0.5)
            .collect();
        let b: Vec<f32> = (0..5).map(|i| i as f32 * 0.1 - 0.2).collect();
        linear.weight = Param::from_tensor(Tensor::from_data(TensorData::new(w, [6, 5]), device));
        linear.bias = Some(Param::from_tensor(Tensor::from_data(
            TensorData::new(b, [5]),
            device,
        )));
        linear
    }

    /// Gradients of a loss that varies with `k`, large enough to be clipped at norm 1.
    fn grads(net: &Linear, k: usize, device: &Device) -> GradientsParams {
        let x: Vec<f32> = (0..12)
            .map(|i| ((i * 13 + k * 7) % 11) as f32 - 5.0)
            .collect();
        let x = Tensor::<2>::from_data(TensorData::new(x, [2, 6]), device);
        let loss = net.forward(x).powf_scalar(2.0).sum();
        GradientsParams::from_grads(loss.backward(), net)
    }

    fn weights(net: &Linear) -> Vec<f32> {
        let mut v = net.weight.val().try_into_vec_as::<f32>().unwrap();
        v.extend(
            net.bias
                .as_ref()
                .unwrap()
                .val()
                .try_into_vec_as::<f32>()
                .unwrap(),
        );
        v
    }

    /// burn's module optimizer as the trainer configured it before this one.
    fn burns(decoupled: bool, clip: Option<f32>) -> ModuleOptimizer {
        let clipping = clip.map(GradientClippingConfig::Norm);
        if decoupled {
            AdamWConfig::new()
                .with_weight_decay(0.01)
                .with_grad_clipping(clipping)
                .init()
        } else {
            AdamConfig::new()
                .with_weight_decay(Some(WeightDecayConfig::new(0.01)))
                .with_grad_clipping(clipping)
                .init()
        }
    }

    /// On the CPU, three steps are burn's own Adam and AdamW with burn's clipping, to the
    /// bit, with the clipping active, idle and absent.
    #[test]
    fn cpu_steps_are_burns_to_the_bit() {
        let device = Device::flex().autodiff();
        for decoupled in [false, true] {
            for clip in [None, Some(1.0), Some(1e6)] {
                let mut ours =
                    TrainingOptimizer::new(decoupled, 0.01, clip).into_module_optimizer();
                let mut theirs = burns(decoupled, clip);
                let (mut a, mut b) = (network(&device), network(&device));
                for (k, lr) in [1e-2, 3e-3, 2e-2].into_iter().enumerate() {
                    let (ga, gb) = (grads(&a, k, &device), grads(&b, k, &device));
                    a = ours.step(lr, a, ga);
                    b = theirs.step(lr, b, gb);
                    assert_eq!(weights(&a), weights(&b), "AdamW {decoupled}, clip {clip:?}");
                }
                assert_ne!(weights(&a), weights(&network(&device)));
            }
        }
    }

    /// A run directory's optimizer state written by burn's optimizers (every run before
    /// this one) loads here, and the next step is the one burn's would have taken.
    #[test]
    fn burns_optimizer_records_resume_here() {
        let device = Device::flex().autodiff();
        for decoupled in [false, true] {
            let mut theirs = burns(decoupled, Some(10.0));
            let mut net = network(&device);
            for k in 0..2 {
                let g = grads(&net, k, &device);
                net = theirs.step(1e-2, net, g);
            }
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("optimizer.bpk");
            theirs.to_record().save(&path).unwrap();
            let record = burn::optim::OptimizerRecord::load(&path).unwrap();
            let mut ours = TrainingOptimizer::new(decoupled, 0.01, Some(10.0))
                .into_module_optimizer()
                .load_record(record);
            let want = theirs.step(1e-2, net.clone(), grads(&net, 2, &device));
            let got = ours.step(1e-2, net.clone(), grads(&net, 2, &device));
            assert_eq!(weights(&got), weights(&want), "AdamW {decoupled}");
        }
    }
}
