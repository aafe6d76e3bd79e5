//! A whole tensor's sum that is the same bits in every run on every device.
//!
//! Why: burn 0.22's `sum()` of a whole tensor on a CubeCL device is one kernel whose cubes
//! each add their share in shared memory and then add it to the result atomically
//! (burn-cubecl's `shared_sum`; under autotune, on CUDA, one of several such cube counts), so
//! the shares land in whatever order the cubes finish: on lavapipe thirty sums of the same
//! 1,000,000 values gave two different results. The losses of the voxel family (the anchor
//! head's three terms, stage two's residuals) and the frustum family's focal loss are such
//! sums, which made a GPU training run's losses differ in their last bits from run to run.
//! Here, on a CubeCL device, the values are laid out as [rows, ≈√n] (zeros appended) and
//! summed row by row and then over the rows, two of burn's `sum_dim`s, each output value made
//! by one unit in a fixed order. On the CPU it is burn's `sum()`, whose bits stay flex's own.

use burn::prelude::*;

/// The sum of all of `x`'s values, [1] (see the module's documentation).
pub fn sum_all<const D: usize>(x: Tensor<D>) -> Tensor<1> {
    if !crate::ragged::custom_device_path(&x) {
        return x.sum();
    }
    let n = x.shape().num_elements();
    if n == 0 {
        return Tensor::zeros([1], &x.device());
    }
    let width = square_width(n);
    let rows = n.div_ceil(width);
    let device = x.device();
    let flat = x.reshape([n]);
    let flat = match rows * width - n {
        0 => flat,
        padding => Tensor::cat(vec![flat, Tensor::zeros([padding], &device)], 0),
    };
    flat.reshape([rows, width])
        .sum_dim(1)
        .sum_dim(0)
        .reshape([1])
}

/// The row width for `n` values: ⌈√n⌉, at least 1, so that neither pass walks more than
/// about √n values one after another.
fn square_width(n: usize) -> usize {
    (n as f64).sqrt().ceil().max(1.0) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values whose f32 sum depends on its order: a spread of magnitudes and signs.
    fn values(n: usize) -> Vec<f32> {
        (0..n)
            .map(|i| ((i * 7919 % 1000) as f32 - 499.5) * 1e-3 * (1 + i % 7) as f32)
            .collect()
    }

    #[test]
    fn square_width_covers_every_count() {
        for n in [0, 1, 2, 3, 4, 15, 16, 17, 140_800, 1_000_001] {
            let w = square_width(n);
            assert!(w >= 1);
            assert!(w * n.div_ceil(w) >= n);
            assert!((w - 1) * (w - 1) < n.max(1), "{n}: {w}");
        }
    }

    /// On the CPU it is burn's `sum()` to the bit.
    #[test]
    fn on_the_cpu_it_is_burns_sum() {
        let device = Device::flex();
        let x = Tensor::<2>::from_data(TensorData::new(values(3_000), [1_000, 3]), &device);
        let ours: f32 = sum_all(x.clone()).into_scalar();
        let burns: f32 = x.sum().into_scalar();
        assert_eq!(ours.to_bits(), burns.to_bits());
    }

    /// On wgpu: the same bits in every run, within f32 rounding of the f64 sum, for counts
    /// that fill the rows and counts that need zeros appended, and a gradient of ones.
    #[cfg(feature = "wgpu")]
    #[test]
    fn on_wgpu_the_same_bits_every_run() {
        let Some(gpu) = crate::cube::working_wgpu_device("the fixed-order sum") else {
            return;
        };
        for n in [1, 1_000_000, 140_801] {
            let v = values(n);
            let exact: f64 = v.iter().map(|&x| x as f64).sum();
            let scale: f64 = v.iter().map(|&x| (x as f64).abs()).sum();
            let x = Tensor::<1>::from_data(TensorData::new(v, [n]), &gpu);
            let runs: std::collections::BTreeSet<u32> = (0..20)
                .map(|_| sum_all(x.clone()).into_scalar::<f32>().to_bits())
                .collect();
            assert_eq!(runs.len(), 1, "{n} values: {runs:?}");
            let sum = f32::from_bits(*runs.first().unwrap()) as f64;
            assert!((sum - exact).abs() <= 1e-6 * scale, "{n}: {sum} vs {exact}");
        }
        let gpu = gpu.autodiff();
        let x =
            Tensor::<2>::from_data(TensorData::new(values(6_001), [6_001, 1]), &gpu).require_grad();
        let grads = sum_all(x.clone().mul_scalar(2.0)).backward();
        let g = x.grad(&grads).unwrap().try_to_vec_as::<f32>().unwrap();
        assert!(g.iter().all(|&g| g == 2.0));
    }
}
