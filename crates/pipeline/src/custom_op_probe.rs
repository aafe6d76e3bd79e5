//! One training operation on a GPU, forward and backward, timed through the project's
//! custom operations and through burn's generic ones, with each path's gradient against the
//! CPU's: what the probes of `bench` ([`crate::batch_norm_probe`], [`crate::linear_probe`])
//! share.

use crate::sparse_gradient_probe::relative_difference;
use burn::prelude::*;
use fusiondet_nn::ragged::{custom_device_path, set_custom_ops};
use std::time::Instant;

/// A probe's figures on one device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathTiming {
    /// Seconds for forward and backward through the custom operations (after a warm-up run).
    pub custom: f64,
    /// The same through burn's generic operations.
    pub generic: f64,
    /// The custom path's gradient: largest difference from the CPU's, relative to the
    /// CPU's largest value.
    pub custom_error: f64,
    /// The same for burn's generic operations.
    pub generic_error: f64,
}

/// `run` (one training pass over its input, returning the gradient it probes, read back) on
/// `input` placed on `device` with autodiff: timed with the custom operations on, then off
/// (they are switched back on after), and compared with the same pass on the CPU. `None`
/// where the custom device operations do not apply (the CPU, or turned off).
pub(crate) fn time_both_paths(
    device: &Device,
    input: TensorData,
    run: fn(&Tensor<2>) -> Vec<f32>,
) -> Option<PathTiming> {
    let device = device.clone().autodiff();
    if !custom_device_path(&Tensor::<1>::zeros([1], &device)) {
        return None;
    }
    let x = Tensor::<2>::from_data(input, &device);
    let timed = |x: &Tensor<2>| {
        run(x);
        let started = Instant::now();
        let gradient = run(x);
        (started.elapsed().as_secs_f64(), gradient)
    };
    let (custom, with_custom) = timed(&x);
    set_custom_ops(false);
    let (generic, with_generic) = timed(&x);
    set_custom_ops(true);
    let cpu = run(&x.to_device(&Device::flex().autodiff()));
    Some(PathTiming {
        custom,
        generic,
        custom_error: relative_difference(&with_custom, &cpu),
        generic_error: relative_difference(&with_generic, &cpu),
    })
}
