//! Max over contiguous runs of rows, computed on the host for inference on the CPU.
//!
//! Written by hand because burn-flex 0.22 reduces any axis but the last one element by
//! element, with an index division and a NaN test per element and the runs gathered into
//! a padded copy first: in LFA's [M, K, C] max over the K = 16 neighbours that took a
//! fifth of LFA's time (`cargo bench -p fusiondet-models --bench fconvnet -- middle_max`).
//! Here one pass reads each row once, in place. Only for tensors on the flex device
//! without autodiff (inference); training on the flex device takes the custom operations of
//! [`crate::ragged`] (with their own backward passes), other backends burn's own operations.
//!
//! The result is the same bit for bit as burn-flex's: rows are scanned in order and a
//! value replaces the running maximum only when it is larger (or NaN), so among equal
//! values (+0 and −0) the first one stays, as in flex's scan.

use burn::prelude::*;
use rayon::prelude::*;

/// Whether `x` can take the host path: on the flex CPU device, outside autodiff.
pub fn host_path(x: &Tensor<2>) -> bool {
    !x.is_autodiff() && x.device() == Device::flex()
}

/// One step of burn-flex's max scan: `v` replaces the running maximum only when it is
/// larger or NaN, so among equal values (+0 and −0) the first stays. Branch-free, so that
/// loops over rows of it vectorise.
#[inline]
pub fn flex_max(best: f32, v: f32) -> f32 {
    let replace = (v > best) | v.is_nan();
    if replace { v } else { best }
}

/// Per-run max of `x` ([rows, C], on the flex device): run s covers rows
/// `starts[s]..starts[s] + counts[s]`; an empty run gives zeros. [runs, C].
pub fn runs_max(x: Tensor<2>, starts: &[usize], counts: &[usize]) -> Tensor<2> {
    assert_eq!(starts.len(), counts.len(), "one start per run");
    let [rows, c] = x.dims();
    let device = x.device();
    let data = x.into_data();
    let data = data
        .as_slice::<f32>()
        .expect("an f32 tensor on the flex device");
    let mut out = vec![0f32; counts.len() * c];
    if c > 0 {
        out.par_chunks_mut(c)
            .zip(starts.par_iter().zip(counts))
            .for_each(|(dst, (&start, &n))| {
                assert!(start + n <= rows, "run {start}+{n} past {rows} rows");
                if n == 0 {
                    return;
                }
                dst.copy_from_slice(&data[start * c..(start + 1) * c]);
                for row in data[(start + 1) * c..(start + n) * c].chunks_exact(c) {
                    for (best, &v) in dst.iter_mut().zip(row) {
                        *best = flex_max(*best, v);
                    }
                }
            });
    }
    Tensor::from_data(TensorData::new(out, [counts.len(), c]), &device)
}

/// Max over each block of `width` consecutive rows of `x` ([blocks · width, C]) →
/// [blocks, C].
pub fn blocks_max(x: Tensor<2>, width: usize) -> Tensor<2> {
    let [rows, _] = x.dims();
    assert!(
        width > 0 && rows % width == 0,
        "{rows} rows in blocks of {width}"
    );
    let blocks = rows / width;
    let starts: Vec<usize> = (0..blocks).map(|b| b * width).collect();
    runs_max(x, &starts, &vec![width; blocks])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits(t: Tensor<2>) -> Vec<u32> {
        t.into_data()
            .try_into_vec::<f32>()
            .unwrap()
            .iter()
            .map(|v| v.to_bits())
            .collect()
    }

    /// Bit for bit what flex's max over the middle axis gives, signed zeros included,
    /// for several block widths and channel counts.
    #[test]
    fn blocks_max_matches_flex_bit_for_bit() {
        let device = Device::flex();
        for (blocks, width, c) in [(5, 1, 3), (7, 16, 32), (3, 4, 1), (64, 16, 17)] {
            let n = blocks * width * c;
            // Values with many ties, zeros of both signs and negatives.
            let values: Vec<f32> = (0..n)
                .map(|i| match (i * 7919) % 11 {
                    0 => 0.0,
                    1 => -0.0,
                    r => (r as f32 - 6.0) * 0.5,
                })
                .collect();
            let x = Tensor::<2>::from_data(TensorData::new(values, [blocks * width, c]), &device);
            assert!(host_path(&x));
            let flex = x
                .clone()
                .reshape([blocks, width, c])
                .max_dim(1)
                .reshape([blocks, c]);
            assert_eq!(bits(blocks_max(x, width)), bits(flex));
        }
    }

    #[test]
    fn runs_of_any_length_and_empty_runs() {
        let device = Device::flex();
        let x = Tensor::<2>::from_floats(
            [
                [1.0, -2.0],
                [3.0, 0.5],
                [-1.0, 4.0],
                [2.0, 2.0],
                [0.0, -5.0],
            ],
            &device,
        );
        let out = runs_max(x, &[0, 3, 2, 4], &[3, 0, 1, 1]);
        let v = out.into_data().try_into_vec::<f32>().unwrap();
        assert_eq!(v, vec![3.0, 4.0, 0.0, 0.0, -1.0, 4.0, 0.0, -5.0]);
    }

    #[test]
    fn autodiff_tensors_take_burns_path() {
        let ad = Device::flex().autodiff();
        let x = Tensor::<2>::zeros([2, 2], &ad);
        assert!(!host_path(&x));
    }
}
