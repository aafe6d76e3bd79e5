//! One Adam or AdamW step of a parameter ([`crate::adam`]) as CubeCL kernels on burn's GPU
//! backends (cargo features `wgpu` and `cuda`): the parameter's gradient clipped to a norm,
//! both moments and the update in one pass.
//!
//! Why: burn's optimizers take a parameter's step as a chain of tensor operations, each a
//! kernel launch of its own on a GPU (burn's kernel fusion is off in our builds; see
//! `docs/gpus-and-clusters.md`): clipping by norm (square, sum, square root, add, divide,
//! clamp, multiply) and AdamW (two moments, bias corrections, square root, divide, decay,
//! subtract) come to about 23 launches a parameter tensor. Counted with CubeCL's profiler on
//! wgpu, they were about two thirds of the launches of a tiny Voxel R-CNN's training step;
//! here they are one launch a parameter, three where the gradient of a parameter of more
//! than 256 values is clipped (the sum of squares in blocks of about √N values, the blocks'
//! total, then the update; a smaller one's threads each add all its squares).
//!
//! The arithmetic is burn's (`burn_optim`'s `Adam`, `AdamW`, `GradientClipping::Norm`),
//! operation for operation in f32, with every per-step scalar computed on the host as burn
//! computes it. The sum of squares is f32 in a fixed order (blocks in order), so a step is the
//! same bits in every run on one device. Inputs are read by their strides (CUDA pads 2-D
//! rows; a gradient may be a transposed view) and outputs written one-dimensional, as in
//! [`crate::batch_norm_device`].

use crate::adam::AdamStep;
use crate::cube::{f32_buffer as buffer, float_rows, launch_shape, root_blocks};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The step (see the module's documentation).
#[backend_extension(Cube)]
pub trait AdamStepOps: Backend {
    /// (parameter, first moment, second moment) after one step of `param` by `grad`, from
    /// the moments `moment_1`, `moment_2` (zero, and not read, on the `first` step), all
    /// one shape.
    fn adam_step(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        step: AdamStep,
        first: bool,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// One step on tensors of a CubeCL device: (parameter, first moment, second moment). `moments`
/// are `None` on a parameter's first step.
pub fn step<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moments: Option<(Tensor<D>, Tensor<D>)>,
    step: AdamStep,
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    let first = moments.is_none();
    // On the first step the moments are not read: the gradient stands in for them.
    let (moment_1, moment_2) = moments.unwrap_or_else(|| (grad.clone(), grad.clone()));
    let (param, moment_1, moment_2) = <Dispatch as AdamStepOps>::adam_step(
        param.into_dispatch(),
        grad.into_dispatch(),
        moment_1.into_dispatch(),
        moment_2.into_dispatch(),
        step,
        first,
    );
    (
        Tensor::from_dispatch(param),
        Tensor::from_dispatch(moment_1),
        Tensor::from_dispatch(moment_2),
    )
}

mod kernels {
    use crate::cube::block_range;
    use cubecl::prelude::*;

    /// Where logical value `index` (row-major over `t`'s shape) lies in `t`: the index
    /// itself when `packed`, else through `t`'s strides.
    #[cube]
    fn offset(t: &Tensor<f32>, index: usize, #[comptime] packed: bool) -> usize {
        let mut at = index;
        if !packed {
            let rank = t.rank();
            let mut rest = index;
            at = 0;
            for k in 0..rank {
                let d = rank - 1 - k;
                let size = t.shape(d);
                at += (rest % size) * t.stride(d);
                rest /= size;
            }
        }
        at
    }

    /// One block a thread: `partial[block]`, the sum of g² over the block's values in order.
    #[cube(launch_unchecked)]
    pub fn square_partial_sums(
        grad: &Tensor<f32>,
        partial: &mut Tensor<f32>,
        len: u32,
        block_len: u32,
        #[comptime] packed: bool,
    ) {
        let block = ABSOLUTE_POS;
        if block >= partial.shape(0) {
            terminate!();
        }
        let (first, end) = block_range(block, block_len, len as usize);
        let mut sum = 0f32;
        for i in first..end {
            let g = grad[offset(grad, i, packed)];
            sum += g * g;
        }
        partial[block] = sum;
    }

    /// One thread: `coefficient[0]`, the clipping factor ([`clip_factor`]) of the blocks'
    /// sums added in order.
    #[cube(launch_unchecked)]
    pub fn clip_coefficient(partial: &Tensor<f32>, coefficient: &mut Tensor<f32>, max_norm: f32) {
        if ABSOLUTE_POS >= 1 {
            terminate!();
        }
        let mut sum = 0f32;
        for block in 0..partial.shape(0) {
            sum += partial[block];
        }
        coefficient[0] = clip_factor(sum, max_norm);
    }

    /// burn's `clip_by_norm` factor from the sum of squares: min(max_norm / (‖g‖ + the
    /// smallest positive f32), 1).
    #[cube]
    fn clip_factor(sum_of_squares: f32, max_norm: f32) -> f32 {
        // f32::MIN_POSITIVE, burn's `min_positive` of f32.
        let coef = max_norm / (f32::sqrt(sum_of_squares) + 1.1754944e-38f32);
        select(coef > 1.0f32, 1.0f32, coef)
    }

    /// One value a thread: burn's Adam (`decoupled` false: L2 `penalty`, bias corrections
    /// folded into `scale` and `shift`) or AdamW (`decoupled` true, the decay multiplying by
    /// `keep`), as `crate::adam::AdamStep` says, on the gradient times `coefficient[0]`
    /// where `clipped`.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn adam_update(
        param: &Tensor<f32>,
        grad: &Tensor<f32>,
        moment_1: &Tensor<f32>,
        moment_2: &Tensor<f32>,
        coefficient: &Tensor<f32>,
        out_param: &mut Tensor<f32>,
        out_moment_1: &mut Tensor<f32>,
        out_moment_2: &mut Tensor<f32>,
        lr: f32,
        beta_1: f32,
        beta_2: f32,
        factor_1: f32,
        factor_2: f32,
        penalty: f32,
        scale: f32,
        shift: f32,
        correction_2: f32,
        keep: f32,
        max_norm: f32,
        #[comptime] flags: AdamFlags,
    ) {
        let i = ABSOLUTE_POS;
        if i >= out_param.shape(0) {
            terminate!();
        }
        let p = param[offset(param, i, flags.packed)];
        let mut g = grad[offset(grad, i, flags.packed)];
        if flags.clipped {
            if flags.inline_norm {
                // A small parameter: every thread adds all of it, in order (one value).
                let mut sum = 0f32;
                for j in 0..out_param.shape(0) {
                    let h = grad[offset(grad, j, flags.packed)];
                    sum += h * h;
                }
                g *= clip_factor(sum, max_norm);
            } else {
                g *= coefficient[0];
            }
        }
        if !flags.decoupled {
            g += p * penalty;
        }
        let mut m = g * factor_1;
        let mut v = g * g * factor_2;
        if !flags.first {
            m += moment_1[offset(moment_1, i, flags.packed)] * beta_1;
            v += moment_2[offset(moment_2, i, flags.packed)] * beta_2;
        }
        let mut next = p;
        if flags.decoupled {
            let update = (m / scale) / (f32::sqrt(v / correction_2) + shift);
            if flags.decay {
                next = p * keep;
            }
            next -= update * lr;
        } else {
            let update = (m * scale) / (f32::sqrt(v) + shift);
            next -= update * lr;
        }
        out_param[i] = next;
        out_moment_1[i] = m;
        out_moment_2[i] = v;
    }

    /// What [`adam_update`] is compiled for.
    #[derive(Clone, Copy, Debug, Hash, PartialEq, Eq)]
    pub struct AdamFlags {
        pub first: bool,
        pub clipped: bool,
        pub decoupled: bool,
        pub decay: bool,
        /// Parameter, gradient and moments all packed row-major (read by index).
        pub packed: bool,
        /// Clipped with the norm taken by every thread itself (a small parameter), not read
        /// from `coefficient`.
        pub inline_norm: bool,
    }
}

impl AdamStepOps for CubeBackend {
    fn adam_step(
        param: CubeTensor,
        grad: CubeTensor,
        moment_1: CubeTensor,
        moment_2: CubeTensor,
        step: AdamStep,
        first: bool,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        step_on_device(param, grad, moment_1, moment_2, &step, first)
    }
}

fn step_on_device(
    param: CubeTensor,
    grad: CubeTensor,
    moment_1: CubeTensor,
    moment_2: CubeTensor,
    step: &AdamStep,
    first: bool,
) -> (CubeTensor, CubeTensor, CubeTensor) {
    let shape = param.meta.shape().clone();
    let len = shape.num_elements();
    assert!(
        len <= u32::MAX as usize,
        "a parameter of {len} values: the kernels index them in 32 bits"
    );
    let (param, grad) = (float_rows(param), float_rows(grad));
    let (moment_1, moment_2) = (float_rows(moment_1), float_rows(moment_2));
    let client = param.client.clone();
    let packed = [&param, &grad, &moment_1, &moment_2]
        .iter()
        .all(|t| t.is_contiguous());
    let inline_norm = len <= INLINE_NORM_VALUES;
    let coefficient = match step.clip_norm {
        Some(max_norm) if len > 0 && !inline_norm => {
            Some(clip_coefficient(&grad, len, max_norm, packed))
        }
        _ => None,
    };
    let outputs = [
        buffer(&param, len),
        buffer(&param, len),
        buffer(&param, len),
    ];
    if len > 0 {
        let flags = kernels::AdamFlags {
            first,
            clipped: step.clip_norm.is_some(),
            decoupled: step.decoupled,
            decay: step.keep.is_some(),
            packed,
            inline_norm,
        };
        let (count, dim) = launch_shape(&client, len);
        // SAFETY: threads past the last value return first; a value below the shape's count
        // addresses each input within its shape (by index where packed, else by its strides);
        // the outputs hold `len` values, the coefficient 1 (read only when clipped, and not
        // inline).
        unsafe {
            kernels::adam_update::launch_unchecked(
                &client,
                count,
                dim,
                param.clone().into_tensor_arg(),
                grad.clone().into_tensor_arg(),
                moment_1.into_tensor_arg(),
                moment_2.into_tensor_arg(),
                coefficient
                    .unwrap_or_else(|| grad.clone())
                    .into_tensor_arg(),
                outputs[0].clone().into_tensor_arg(),
                outputs[1].clone().into_tensor_arg(),
                outputs[2].clone().into_tensor_arg(),
                step.lr,
                step.beta_1,
                step.beta_2,
                step.factor_1,
                step.factor_2,
                step.penalty,
                step.scale,
                step.shift,
                step.correction_2,
                step.keep.unwrap_or(1.0),
                step.clip_norm.unwrap_or(f32::INFINITY),
                flags,
            );
        }
    }
    let [p, m, v] = outputs.map(|t| CubeBackend::float_reshape(t, shape.clone()));
    (p, m, v)
}

/// Parameters of at most this many values (batch norms' γ and β, biases) are clipped in the
/// update's one launch, each thread adding all their squares, instead of two launches more.
const INLINE_NORM_VALUES: usize = 256;

/// burn's per-parameter clipping coefficient of `grad` ([1] on the device): the sum of
/// squares in blocks of about √N values, then the blocks in order.
fn clip_coefficient(grad: &CubeTensor, len: usize, max_norm: f32, packed: bool) -> CubeTensor {
    let client = grad.client.clone();
    let (blocks, block_len) = root_blocks(len);
    let partial = buffer(grad, blocks);
    let (count, dim) = launch_shape(&client, blocks);
    // SAFETY: threads past the last block return first; a block's values are clipped to
    // `len`, each addressed within the gradient's shape.
    unsafe {
        kernels::square_partial_sums::launch_unchecked(
            &client,
            count,
            dim,
            grad.clone().into_tensor_arg(),
            partial.clone().into_tensor_arg(),
            len as u32,
            block_len as u32,
            packed,
        );
    }
    let coefficient = buffer(grad, 1);
    let (count, dim) = launch_shape(&client, 1);
    // SAFETY: one thread reads the `blocks` partial sums and writes the one value.
    unsafe {
        kernels::clip_coefficient::launch_unchecked(
            &client,
            count,
            dim,
            partial.into_tensor_arg(),
            coefficient.clone().into_tensor_arg(),
            max_norm,
        );
    }
    coefficient
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use crate::adam::{AdamSettings, AdamStep};
    use crate::cube::{assert_close, working_wgpu_device};
    use burn::optim::grad_clipping::GradientClipping;
    use burn::optim::{
        AdamConfig, AdamState, AdamWConfig, AdamWState, AdaptiveMomentumState, Optimizer,
    };
    use burn::prelude::*;

    fn flat<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    /// Varied values in [−scale, scale).
    fn values(len: usize, seed: usize, scale: f32) -> Vec<f32> {
        (0..len)
            .map(|i| ((i * 7919 + seed * 104_729) % 1009) as f32 / 504.5 * scale - scale)
            .collect()
    }

    const LEARNING_RATES: [f64; 3] = [1e-2, 3e-3, 2e-2];

    /// (parameter, first moment, second moment) after three steps of burn's own optimizer
    /// and clipping on the CPU.
    fn burn_steps<const D: usize>(
        settings: &AdamSettings,
        shape: [usize; D],
        param: &[f32],
        grads: &[Vec<f32>],
    ) -> [Vec<f32>; 3] {
        let cpu = Device::flex();
        let tensor = |v: &[f32]| Tensor::<D>::from_data(TensorData::new(v.to_vec(), shape), &cpu);
        let mut p = tensor(param);
        let mut state: Option<AdaptiveMomentumState<D>> = None;
        for (grad, &lr) in grads.iter().zip(&LEARNING_RATES) {
            let mut g = tensor(grad);
            if let Some(norm) = settings.clip_norm {
                g = GradientClipping::Norm(norm).clip_gradient(g);
            }
            let config = |beta_1, beta_2, epsilon| (beta_1, beta_2, epsilon);
            let (b1, b2, eps) = config(settings.beta_1, settings.beta_2, settings.epsilon);
            (p, state) = if settings.decoupled {
                let adamw = AdamWConfig::new()
                    .with_beta_1(b1)
                    .with_beta_2(b2)
                    .with_epsilon(eps)
                    .with_weight_decay(settings.weight_decay)
                    .build();
                let (p, s) = adamw.step(lr, p, g, state.map(AdamWState::new));
                (p, s.map(|s| s.momentum))
            } else {
                let adam = AdamConfig::new()
                    .with_beta_1(b1)
                    .with_beta_2(b2)
                    .with_epsilon(eps)
                    .with_weight_decay(Some(burn::optim::decay::WeightDecayConfig::new(
                        settings.weight_decay,
                    )))
                    .build();
                let (p, s) = adam.step(lr, p, g, state.map(AdamState::new));
                (p, s.map(|s| s.momentum))
            };
        }
        let state = state.expect("three steps leave moments");
        [flat(p), flat(state.moment_1), flat(state.moment_2)]
    }

    /// The same three steps through the kernels on `device`; `transposed` hands each
    /// gradient over as a transposed view (read by its strides).
    fn fused_steps<const D: usize>(
        settings: &AdamSettings,
        shape: [usize; D],
        param: &[f32],
        grads: &[Vec<f32>],
        transposed: bool,
        device: &Device,
    ) -> [Vec<f32>; 3] {
        let tensor = |v: &[f32]| Tensor::<D>::from_data(TensorData::new(v.to_vec(), shape), device);
        let mut p = tensor(param);
        let mut moments = None;
        for (time, (grad, &lr)) in grads.iter().zip(&LEARNING_RATES).enumerate() {
            let g = if transposed {
                // The same values, laid out with the last two axes swapped.
                let mut swapped_shape = shape;
                swapped_shape.swap(D - 2, D - 1);
                let [rows, cols] = [shape[D - 2], shape[D - 1]];
                let block = rows * cols;
                let laid: Vec<f32> = (0..grad.len())
                    .map(|j| {
                        let (b, k) = (j / block, j % block);
                        let (c, r) = (k / rows, k % rows);
                        grad[b * block + r * cols + c]
                    })
                    .collect();
                Tensor::<D>::from_data(TensorData::new(laid, swapped_shape), device)
                    .swap_dims(D - 2, D - 1)
            } else {
                tensor(grad)
            };
            let step = AdamStep::new(settings, lr, time + 1);
            let (next, m, v) = super::step(p, g, moments, step);
            p = next;
            moments = Some((m, v));
        }
        let (m, v) = moments.expect("three steps leave moments");
        [flat(p), flat(m), flat(v)]
    }

    /// The kernels against burn's Adam and AdamW on the CPU over three steps (the first
    /// without moments), with the clipping active, idle and absent, for parameters of rank
    /// 1, 2 and 4 (the 2-D and 4-D gradients also as transposed views): within rounding, and
    /// the same bits in a second run.
    #[test]
    fn fused_adam_matches_burns_optimizers() {
        let Some(gpu) = working_wgpu_device("the fused Adam step") else {
            return;
        };
        fn case<const D: usize>(shape: [usize; D], gpu: &Device) {
            let len: usize = shape.iter().product();
            let param = values(len, 1, 0.5);
            let grads: Vec<Vec<f32>> = (0..3).map(|k| values(len, k + 2, 1.0)).collect();
            for decoupled in [false, true] {
                // Norm ≈ √(len / 3): 1.0 clips every step, 1e6 never.
                for clip_norm in [None, Some(1.0), Some(1e6)] {
                    let settings = AdamSettings {
                        beta_1: 0.9,
                        beta_2: 0.999,
                        epsilon: 1e-5,
                        weight_decay: 0.01,
                        decoupled,
                        clip_norm,
                    };
                    let want = burn_steps(&settings, shape, &param, &grads);
                    for transposed in [false, true] {
                        if transposed && D < 2 {
                            continue;
                        }
                        let what = format!(
                            "{shape:?}, AdamW {decoupled}, clip {clip_norm:?}, transposed {transposed}"
                        );
                        let got = fused_steps(&settings, shape, &param, &grads, transposed, gpu);
                        for (name, (got, want)) in ["parameter", "moment 1", "moment 2"]
                            .iter()
                            .zip(got.iter().zip(&want))
                        {
                            assert_close(got, want, 2e-6, &format!("{what}: {name}"));
                        }
                        let again = fused_steps(&settings, shape, &param, &grads, transposed, gpu);
                        assert_eq!(got, again, "{what}: a second run");
                    }
                }
            }
        }
        case([7], &gpu);
        case([33, 65], &gpu);
        case([4, 3, 5, 2], &gpu);
    }
}
