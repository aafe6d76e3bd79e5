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

use crate::custom_op_probe::{PathTiming, time_both_paths};
use crate::matmul_precision::probe_values;
use burn::prelude::*;
use fusiondet_nn::{NormConfig, batch_norm, norm_rows_relu};

/// Rows of the probe: RoI grid pooling's neighbours in a published Voxel R-CNN step.
pub const PROBE_ROWS: usize = 256 * 216 * 16;
/// Channels of the probe (that layer's width).
pub const PROBE_CHANNELS: usize = 32;

/// The probe on `device` (`custom`: the kernels), or `None` where the kernels do not apply
/// (the CPU, or custom operations turned off).
pub fn batch_norm_timing(device: &Device) -> Option<PathTiming> {
    let input = TensorData::new(
        probe_values(PROBE_ROWS * PROBE_CHANNELS, 5),
        [PROBE_ROWS, PROBE_CHANNELS],
    );
    time_both_paths(device, input, run)
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
        assert!(timing.custom > 0.0 && timing.generic > 0.0);
        assert!(timing.custom_error < 1e-3, "{timing:?}");
    }
}
