//! Adam and AdamW steps of one parameter as burn's optimizers take them (`burn_optim`'s
//! `Adam`, `AdamW`, and per-parameter `GradientClipping::Norm`), fused into a few kernels
//! on a GPU ([`crate::adam_device`], cargo features `wgpu` and `cuda`). On the CPU the
//! trainer keeps burn's own optimizers ([`fused_step`] says `None` there), so the CPU's
//! training is burn's to the bit.

use burn::prelude::*;

/// One step's settings and its per-step scalars, computed on the host as burn's optimizers
/// compute them (see [`AdamStep::new`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamStep {
    /// Learning rate, as burn's `mul_scalar(lr)` rounds it to f32.
    pub lr: f32,
    pub beta_1: f32,
    pub beta_2: f32,
    /// 1 − β₁ and 1 − β₂.
    pub factor_1: f32,
    pub factor_2: f32,
    /// AdamW (decoupled weight decay) where true, Adam with an L2 penalty where false.
    pub decoupled: bool,
    /// Adam: the penalty added to the gradient (`p · penalty + g`).
    pub penalty: f32,
    /// The update: Adam's `m · scale / (√v + shift)`, scale = √(1 − β₂ᵗ)/(1 − β₁ᵗ) and shift
    /// = ε·√(1 − β₂ᵗ) (burn's combined factor and ε term); AdamW's `(m / scale) / (√(v /
    /// correction_2) + shift)`, scale = 1 − β₁ᵗ, correction_2 = 1 − β₂ᵗ and shift = ε.
    pub scale: f32,
    pub shift: f32,
    pub correction_2: f32,
    /// AdamW: the parameter is first multiplied by `keep` (1 − lr · decay), where decaying.
    pub keep: Option<f32>,
    /// The gradient's largest L2 norm (burn's per-parameter `GradientClipping::Norm`).
    pub clip_norm: Option<f32>,
}

/// An optimizer's settings, as burn's `AdamConfig` and `AdamWConfig` hold them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamSettings {
    pub beta_1: f32,
    pub beta_2: f32,
    pub epsilon: f32,
    /// Adam's L2 penalty or AdamW's decoupled decay rate.
    pub weight_decay: f32,
    pub decoupled: bool,
    pub clip_norm: Option<f32>,
}

impl AdamStep {
    /// Step `time` (1 for a parameter's first) at learning rate `lr`, with burn's scalars:
    /// `β.powi(t)` in f32, the AdamW decay rate `lr · decay` in f64.
    pub fn new(settings: &AdamSettings, lr: f64, time: usize) -> AdamStep {
        let t = time as i32;
        let correction_1 = 1f32 - settings.beta_1.powi(t);
        let correction_2 = 1f32 - settings.beta_2.powi(t);
        let (scale, shift) = if settings.decoupled {
            (correction_1, settings.epsilon)
        } else {
            let root = correction_2.sqrt();
            (root / correction_1, settings.epsilon * root)
        };
        let decay_rate = lr * settings.weight_decay as f64;
        AdamStep {
            lr: lr as f32,
            beta_1: settings.beta_1,
            beta_2: settings.beta_2,
            factor_1: 1.0 - settings.beta_1,
            factor_2: 1.0 - settings.beta_2,
            decoupled: settings.decoupled,
            penalty: settings.weight_decay,
            scale,
            shift,
            correction_2,
            keep: (decay_rate != 0.0).then_some((1.0 - decay_rate) as f32),
            clip_norm: settings.clip_norm,
        }
    }
}

/// Whether [`fused_step`] takes `param`'s step: on a CubeCL device, unless custom
/// operations were turned off ([`crate::ragged::custom_device_path`]).
pub fn fuses<const D: usize>(param: &Tensor<D>) -> bool {
    crate::ragged::custom_device_path(param)
}

/// One step of `param` by `grad` on a CubeCL device, fused ([`crate::adam_device`]): the
/// (parameter, first moment, second moment) after it. `moments` are `None` on a parameter's
/// first step (then zero, and not read). `None` where the fused kernels do not apply
/// (the CPU, a build without GPU backends, or custom operations turned off:
/// [`crate::ragged::custom_device_path`]); the caller then takes burn's optimizer.
pub fn fused_step<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moments: Option<(Tensor<D>, Tensor<D>)>,
    step: AdamStep,
) -> Option<(Tensor<D>, Tensor<D>, Tensor<D>)> {
    if !fuses(&param) {
        return None;
    }
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    return Some(crate::adam_device::step(param, grad, moments, step));
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    {
        let _ = (grad, moments, step);
        None
    }
}
