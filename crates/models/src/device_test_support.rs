//! What the models' tests on wgpu share: a fixed upstream gradient, and `nn`'s check of a
//! device's values against the CPU's.

use burn::prelude::*;

/// A fixed, varied upstream gradient for an output of `dims` on `device`: the loss
/// `(output · upstream).sum()` sends it back.
pub fn upstream(dims: [usize; 2], device: &Device) -> Tensor<2> {
    let values: Vec<f32> = (0..dims[0] * dims[1])
        .map(|v| ((v * 53) % 97) as f32 / 48.0 - 1.0)
        .collect();
    Tensor::from_data(TensorData::new(values, dims), device)
}

pub use fusiondet_nn::cube::assert_close;
