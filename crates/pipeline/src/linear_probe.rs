//! How long training's widest point-wise layer takes on a GPU, forward and backward, with
//! its weight gradient summed over chunks of rows (`fusiondet_nn::linear_chunked`) and as
//! burn's one product, and how far each path's weight gradient is from the CPU's.
//!
//! Why: cubek's matrix products split their work over output tiles only, so the weight
//! gradient Xᵀ·dY of a layer over hundreds of thousands of rows and a few dozen channels is
//! one or a few cubes walking every row. The probe is RoI grid pooling's position layer in
//! a published Voxel R-CNN training step (3 → 32 channels over [`PROBE_ROWS`] rows), so
//! `bench` on a GPU says what each way costs there.

use crate::batch_norm_probe::PROBE_ROWS;
use crate::custom_op_probe::{PathTiming, time_both_paths};
use crate::matmul_precision::probe_values;
use burn::module::Param;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

/// Input channels of the probe (a grid point's offset to a neighbour).
pub const PROBE_IN: usize = 3;
/// Output channels of the probe (that layer's width).
pub const PROBE_OUT: usize = 32;

/// The probe on `device` (`custom`: the weight gradient in chunks; `generic`: burn's one
/// product), or `None` where the chunked form does not apply (the CPU, or custom operations
/// turned off).
pub fn linear_timing(device: &Device) -> Option<PathTiming> {
    let input = TensorData::new(
        probe_values(PROBE_ROWS * PROBE_IN, 7),
        [PROBE_ROWS, PROBE_IN],
    );
    time_both_paths(device, input, run)
}

/// One training pass of the probe's layer over `x` with a fixed upstream gradient: the
/// weight gradient, read back (which waits for the device).
fn run(x: &Tensor<2>) -> Vec<f32> {
    let device = x.device();
    let layer = probe_layer(&device);
    let out = fusiondet_nn::linear::linear(&layer, x.clone());
    let upstream = out.clone().detach().cos();
    let grads = (out * upstream).sum().backward();
    layer
        .weight
        .grad(&grads)
        .expect("the weight takes part")
        .into_data()
        .try_to_vec::<f32>()
        .expect("f32 gradients")
}

/// The layer with fixed weights (each backend would draw its own), no bias, as in the
/// pooling.
fn probe_layer(device: &Device) -> Linear {
    let mut layer = LinearConfig::new(PROBE_IN, PROBE_OUT)
        .with_bias(false)
        .init(device);
    layer.weight = Param::from_tensor(Tensor::from_data(
        TensorData::new(probe_values(PROBE_IN * PROBE_OUT, 8), [PROBE_IN, PROBE_OUT]),
        device,
    ));
    layer
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the CPU the probe does not apply (flex has its own linear operation).
    #[test]
    fn the_cpu_is_not_probed() {
        assert_eq!(linear_timing(&Device::flex()), None);
    }

    /// On wgpu (over lavapipe in CI) both paths run, and the chunked weight gradient is the
    /// CPU's within f32 rounding of sums over the probe's rows.
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_linear_probe_on_wgpu() {
        crate::kernel_cache::configure();
        let Some(device) = fusiondet_nn::cube::working_wgpu_device("the linear probe") else {
            return;
        };
        let timing = linear_timing(&device).expect("the chunked form applies on wgpu");
        eprintln!("{timing:?}");
        assert!(timing.custom > 0.0 && timing.generic > 0.0);
        assert!(timing.custom_error < 1e-3, "{timing:?}");
    }
}
