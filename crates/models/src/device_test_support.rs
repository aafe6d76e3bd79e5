//! What the models' tests on wgpu share: `nn`'s fixed upstream gradient and its check of a
//! device's values against the CPU's.

pub use fusiondet_nn::cube::{assert_close, upstream};
