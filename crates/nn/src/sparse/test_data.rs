//! Fixed inputs the sparse convolution's tests share (no generator: `nn` sits below the
//! project's seeded `dataset::rng`).

use super::sites::SparseSites;
use burn::prelude::*;
use std::sync::Arc;

/// Distinct sites in a [2 frames, z, y, x] grid from a fixed sequence.
pub fn sites(shape: [usize; 3], count: usize, seed: u64) -> Arc<SparseSites> {
    let mut state = seed;
    let mut next = |n: usize| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) % n as u64) as i32
    };
    let mut coords = Vec::new();
    while coords.len() < count {
        let c = [next(2), next(shape[0]), next(shape[1]), next(shape[2])];
        if !coords.contains(&c) {
            coords.push(c);
        }
    }
    Arc::new(SparseSites::new(coords, shape, 2).unwrap())
}

/// `n` values in [−1, 1) from a fixed sequence; `salt` gives another.
pub fn values(n: usize, salt: usize) -> Vec<f32> {
    (0..n)
        .map(|i| (((i * 7919 + salt * 104729) % 2003) as f32 / 1001.5) - 1.0)
        .collect()
}

/// An index tensor's values on the host.
pub fn ints(t: &Tensor<1, Int>) -> Vec<i64> {
    t.clone()
        .into_data()
        .convert::<i64>()
        .try_to_vec::<i64>()
        .unwrap()
}
