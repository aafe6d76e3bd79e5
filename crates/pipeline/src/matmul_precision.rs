//! How exactly a device multiplies f32 matrices: one fixed product, measured against the
//! same product in f64 on the host.
//!
//! Why: a GPU backend may run f32 products on tensor cores that round their inputs to TF32
//! (10 mantissa bits, unit roundoff 2⁻¹¹ ≈ 4.9e-4) where the CPU keeps f32's 23 (2⁻²⁴ ≈
//! 6.0e-8). burn's matmul autotune picks the fastest kernel for each shape and offers no
//! switch to keep f32, so two devices that agree on every other operation can still part by
//! centimetres on a box. `bench` prints this figure beside its speed so that a parity
//! difference can be traced to the arithmetic rather than guessed at.

use burn::prelude::*;

/// The probe's size: square products of this side are large enough for an autotuned
/// backend to prefer its tensor-core kernels, and small enough to take milliseconds.
pub const PROBE_SIDE: usize = 512;

/// The largest error of the device's `a · b` over the probe's entries, each relative to the
/// sum of its terms' magnitudes (Σₖ |aᵢₖ bₖⱼ|), which bounds what rounding the inputs or the
/// partial sums can do to that entry. About 1e-7 where products are computed in f32, about
/// 1e-4 where the inputs are rounded to TF32.
pub fn matmul_relative_error(device: &Device) -> f64 {
    let n = PROBE_SIDE;
    let a = probe_matrix(n, 1);
    let b = probe_matrix(n, 2);
    let on_device =
        |values: &[f32]| Tensor::<2>::from_data(TensorData::new(values.to_vec(), [n, n]), device);
    let product = on_device(&a).matmul(on_device(&b));
    let got: Vec<f32> = product
        .into_data()
        .try_to_vec::<f32>()
        .expect("a matrix product of f32 matrices holds f32");
    largest_relative_error(&a, &b, &got, n)
}

/// Fixed entries in [-1, 1) from a multiplicative hash of (matrix, index): no generator, no
/// seed, the same probe on every machine.
fn probe_matrix(n: usize, which: u64) -> Vec<f32> {
    probe_values(n * n, which)
}

/// `count` fixed values in [-1, 1) from a multiplicative hash of (which, index); the
/// probes' inputs ([`crate::sparse_gradient_probe`] too).
pub(crate) fn probe_values(count: usize, which: u64) -> Vec<f32> {
    (0..count as u64)
        .map(|i| {
            let h = (i ^ (which << 40)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            // The top 24 bits as a fraction in [0, 1), exact in f32.
            ((h >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// max over (i, j) of |got − Σₖ aᵢₖ bₖⱼ| / Σₖ |aᵢₖ bₖⱼ|, the exact sums in f64.
fn largest_relative_error(a: &[f32], b: &[f32], got: &[f32], n: usize) -> f64 {
    let mut worst = 0f64;
    for i in 0..n {
        let row = &a[i * n..][..n];
        let mut exact = vec![0f64; n];
        let mut magnitude = vec![0f64; n];
        for (k, &aik) in row.iter().enumerate() {
            for (j, &bkj) in b[k * n..][..n].iter().enumerate() {
                let term = aik as f64 * bkj as f64;
                exact[j] += term;
                magnitude[j] += term.abs();
            }
        }
        for j in 0..n {
            if magnitude[j] > 0.0 {
                let error = (got[i * n + j] as f64 - exact[j]).abs() / magnitude[j];
                worst = worst.max(error);
            }
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_multiplies_in_f32() {
        let error = matmul_relative_error(&Device::flex());
        // f32 sums of 512 terms: a few units of 2⁻²⁴ relative to the terms' magnitudes.
        assert!(error > 0.0 && error < 2e-6, "{error}");
    }

    #[test]
    fn inputs_rounded_to_tf32_are_told_apart_from_f32() {
        let n = 64;
        let (a, b) = (probe_matrix(n, 1), probe_matrix(n, 2));
        // TF32 keeps 10 of f32's 23 mantissa bits: round the other 13 away.
        let tf32 = |x: f32| f32::from_bits((x.to_bits() + 0x1000) & !0x1fff);
        let (at, bt): (Vec<f32>, Vec<f32>) = (
            a.iter().map(|&x| tf32(x)).collect(),
            b.iter().map(|&x| tf32(x)).collect(),
        );
        let product = |a: &[f32], b: &[f32]| {
            let mut c = vec![0f32; n * n];
            for i in 0..n {
                for k in 0..n {
                    for j in 0..n {
                        c[i * n + j] += a[i * n + k] * b[k * n + j];
                    }
                }
            }
            c
        };
        let f32_error = largest_relative_error(&a, &b, &product(&a, &b), n);
        let tf32_error = largest_relative_error(&a, &b, &product(&at, &bt), n);
        assert!(f32_error < 1e-6, "{f32_error}");
        assert!(tf32_error > 3e-5 && tf32_error < 1e-3, "{tf32_error}");
    }
}
