//! What the models' tests on wgpu share: a fixed upstream gradient, and a device's values
//! held against the CPU's.

use burn::prelude::*;

/// A fixed, varied upstream gradient for an output of `dims` on `device`: the loss
/// `(output · upstream).sum()` sends it back.
pub fn upstream(dims: [usize; 2], device: &Device) -> Tensor<2> {
    let values: Vec<f32> = (0..dims[0] * dims[1])
        .map(|v| ((v * 53) % 97) as f32 / 48.0 - 1.0)
        .collect();
    Tensor::from_data(TensorData::new(values, dims), device)
}

/// Asserts every value of `got` within `tolerance` times the largest |value| of `want` (at
/// least 1) of `want`'s.
pub fn assert_close(got: &[f32], want: &[f32], tolerance: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}");
    let scale = want.iter().fold(1f32, |m, v| m.max(v.abs()));
    let worst = got
        .iter()
        .zip(want)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max);
    assert!(
        worst <= tolerance * scale,
        "{what}: off by {worst} (scale {scale})"
    );
}
