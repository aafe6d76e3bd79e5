//! How long one training batch norm takes on a GPU, through the project's kernels
//! (`fusiondet_nn::batch_norm_device`) and through burn's generic operations, and how far
//! each path's gradients are from the CPU's.
//!
//! Why: a published Voxel R-CNN training step took 2.80 s on an H200 (2026-11-29) where the
//! machine's 16 CPU cores took 1.92, while detection ran near its target. Training differs
//! from detection in its batch norms, whose statistics burn reduces, without kernel
//! autotune, with one thread per channel walking every row. The probe is the largest norm
//! of that step: RoI grid pooling's position layer, [`PROBE_ROWS`] rows (256 RoIs × 216 grid
//! points × 16 neighbours) of [`PROBE_CHANNELS`] channels, forward and backward, so `bench`
//! on a GPU says what that costs each way.

use crate::matmul_precision::probe_values;
use crate::sparse_gradient_probe::relative_difference;
use burn::prelude::*;
use fusiondet_nn::ragged::{custom_device_path, set_custom_ops};
use fusiondet_nn::{NormConfig, batch_norm, norm_rows_relu};
use std::time::Instant;

/// Rows of the probe: RoI grid pooling's neighbours in a published Voxel R-CNN step.
pub const PROBE_ROWS: usize = 256 * 216 * 16;
/// Channels of the probe (that layer's width).
pub const PROBE_CHANNELS: usize = 32;

/// The probe's figures on one device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatchNormTiming {
    /// Seconds for forward and backward through the kernels (after a warm-up run).
    pub kernels: f64,
    /// The same through burn's generic operations.
    pub generic: f64,
    /// The kernels' γ and β gradients: largest difference from the CPU's, relative to the
    /// CPU's largest value.
    pub kernels_error: f64,
    /// The same for burn's generic operations.
    pub generic_error: f64,
}

/// The probe on `device`, or `None` where the kernels do not apply (the CPU, or custom
/// operations turned off). It switches the custom operations off for its generic runs and
/// back on after.
pub fn batch_norm_timing(device: &Device) -> Option<BatchNormTiming> {
    let device = device.clone().autodiff();
    if !custom_device_path(&Tensor::<1>::zeros([1], &device)) {
        return None;
    }
    let x = Tensor::<2>::from_data(
        TensorData::new(
            probe_values(PROBE_ROWS * PROBE_CHANNELS, 5),
            [PROBE_ROWS, PROBE_CHANNELS],
        ),
        &device,
    );
    let timed = |x: &Tensor<2>| {
        run(x);
        let started = Instant::now();
        let gradients = run(x);
        (started.elapsed().as_secs_f64(), gradients)
    };
    let (kernels, with_kernels) = timed(&x);
    set_custom_ops(false);
    let (generic, with_burn) = timed(&x);
    set_custom_ops(true);
    let cpu = run(&x.to_device(&Device::flex().autodiff()));
    Some(BatchNormTiming {
        kernels,
        generic,
        kernels_error: relative_difference(&with_kernels, &cpu),
        generic_error: relative_difference(&with_burn, &cpu),
    })
}

/// One training pass of a fresh norm + ReLU over `x` with a fixed upstream gradient:
/// γ' then β', read back (which waits for the device).
fn run(x: &Tensor<2>) -> Vec<f32> {
    let device = x.device();
    let bn = batch_norm(PROBE_CHANNELS, &NormConfig::default(), &device);
    let x = x.clone().require_grad();
    let out = norm_rows_relu(&bn, x);
    let upstream = out.clone().detach().cos();
    let grads = (out * upstream).sum().backward();
    let gamma = bn.gamma.grad(&grads).expect("γ takes part");
    let beta = bn.beta.grad(&grads).expect("β takes part");
    Tensor::cat(vec![gamma, beta], 0)
        .into_data()
        .try_to_vec::<f32>()
        .expect("f32 gradients")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the CPU the probe does not apply (flex has its own fused norm, timed by `cargo
    /// bench`).
    #[test]
    fn the_cpu_is_not_probed() {
        assert_eq!(batch_norm_timing(&Device::flex()), None);
    }

    /// On wgpu (over lavapipe in CI) both paths run, and the kernels' gradients are the CPU's
    /// within f32 rounding of sums over the probe's rows. (burn's generic path is not held
    /// to it: on lavapipe its reductions over this many rows come out wrong, its γ and β
    /// gradients up to about 95 times their largest value apart from the CPU's.)
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_batch_norm_probe_on_wgpu() {
        crate::kernel_cache::configure();
        let Some(device) = fusiondet_nn::cube::working_wgpu_device("the batch norm probe") else {
            return;
        };
        let timing = batch_norm_timing(&device).expect("the kernels apply on wgpu");
        eprintln!("{timing:?}");
        assert!(timing.kernels > 0.0 && timing.generic > 0.0);
        assert!(timing.kernels_error < 1e-3, "{timing:?}");
    }
}
