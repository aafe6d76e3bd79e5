//! Gradient clipping over the norm of all of a model's gradients together, as OpenPCDet's
//! trainers clip (`clip_grad_norm_`): when that norm exceeds the bound every gradient is
//! scaled by the same factor, so a step keeps its direction. burn's own clipping bounds
//! each parameter tensor separately, which lets a spike spread over many tensors pass
//! whole; burn has no global form, hence this module.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use fusiondet_nn::reduce::sum_all;

/// L2 norm of all the gradients `grads` holds for `module`'s float parameters. The squared
/// sums stay on the device and are read back once, not once per parameter tensor.
pub fn global_norm<M: Module>(module: &M, grads: &GradientsParams) -> f64 {
    struct SquaredSum<'a> {
        grads: &'a GradientsParams,
        sum: Option<Tensor<1>>,
    }
    impl ModuleVisitor for SquaredSum<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.get::<D>(param.id) {
                // `sum_all`: on a GPU burn's `sum()` adds its blocks atomically, in no fixed
                // order, so the norm (and every clipped weight) would move run to run.
                let part = sum_all(g.powi_scalar(2));
                self.sum = Some(match self.sum.take() {
                    Some(sum) => sum + part,
                    None => part,
                });
            }
        }
    }
    let mut visitor = SquaredSum { grads, sum: None };
    module.visit(&mut visitor);
    visitor
        .sum
        .map_or(0.0, |s| (s.into_scalar::<f32>() as f64).sqrt())
}

/// Scales every gradient by `max_norm / norm` when their global norm exceeds `max_norm`
/// (OpenPCDet adds 1e-6 to the norm, as here); returns the gradients and the norm before
/// clipping.
pub fn clip_global_norm<M: Module>(
    module: &M,
    mut grads: GradientsParams,
    max_norm: f64,
) -> (GradientsParams, f64) {
    struct Scale<'a> {
        grads: &'a mut GradientsParams,
        factor: f32,
    }
    impl ModuleVisitor for Scale<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.remove::<D>(param.id) {
                self.grads.register(param.id, g.mul_scalar(self.factor));
            }
        }
    }
    let norm = global_norm(module, &grads);
    let factor = max_norm / (norm + 1e-6);
    if factor < 1.0 {
        module.visit(&mut Scale {
            grads: &mut grads,
            factor: factor as f32,
        });
    }
    (grads, norm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    /// Gradients of a two-layer sum whose global norm is known from the tensors themselves.
    fn grads_of(scale: f32) -> (Linear, Linear, GradientsParams) {
        let device = Device::flex().autodiff();
        let a = LinearConfig::new(3, 4).init(&device);
        let b = LinearConfig::new(4, 2).init(&device);
        let x = Tensor::<2>::from_data([[1.0f32, -2.0, 0.5], [0.3, 0.7, -1.1]], &device);
        let loss = b.forward(a.forward(x)).sum().mul_scalar(scale);
        let model = (a.clone(), b.clone());
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        (a, b, grads)
    }

    fn by_hand(model: &(Linear, Linear), grads: &GradientsParams) -> Vec<f32> {
        let (a, b) = model;
        let mut all = Vec::new();
        for p in [&a.weight, &b.weight] {
            all.extend(
                grads
                    .get::<2>(p.id)
                    .unwrap()
                    .into_data()
                    .try_to_vec::<f32>()
                    .unwrap(),
            );
        }
        for p in [&a.bias, &b.bias] {
            let id = p.as_ref().unwrap().id;
            all.extend(
                grads
                    .get::<1>(id)
                    .unwrap()
                    .into_data()
                    .try_to_vec::<f32>()
                    .unwrap(),
            );
        }
        all
    }

    #[test]
    fn a_large_step_is_scaled_to_the_bound_and_keeps_its_direction() {
        let (a, b, grads) = grads_of(1000.0);
        let model = (a, b);
        let before = by_hand(&model, &grads);
        let norm: f64 = before
            .iter()
            .map(|g| (*g as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(norm > 10.0, "{norm}");
        assert!((global_norm(&model, &grads) - norm).abs() < 1e-3 * norm);
        let (clipped, reported) = clip_global_norm(&model, grads, 10.0);
        assert!((reported - norm).abs() < 1e-3 * norm);
        let after = by_hand(&model, &clipped);
        let clipped_norm: f64 = after
            .iter()
            .map(|g| (*g as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((clipped_norm - 10.0).abs() < 1e-3, "{clipped_norm}");
        // One factor for every gradient: the direction is kept.
        for (g0, g1) in before.iter().zip(&after) {
            assert!(
                (*g1 as f64 - *g0 as f64 * 10.0 / norm).abs() < 1e-4 * g0.abs().max(1.0) as f64
            );
        }
    }

    #[test]
    fn a_step_within_the_bound_is_left_as_it_is() {
        let (a, b, grads) = grads_of(1e-3);
        let model = (a, b);
        let before = by_hand(&model, &grads);
        let (clipped, _) = clip_global_norm(&model, grads, 10.0);
        assert_eq!(by_hand(&model, &clipped), before);
    }
}
