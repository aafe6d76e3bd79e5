//! Seeded randomness. Every random choice of the crate draws from a ChaCha8 stream
//! derived from the caller's seed and the identity of the thing being drawn for
//! (epoch, sample, object, copy), never from the order in which threads ran, so the
//! results do not depend on the rayon thread count.
//!
//! The distributions are written out here (rather than taken from `rand`) so that a
//! dependency upgrade can never silently change a prepared data set.

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

/// The generator used everywhere in the crate.
pub type SampleRng = ChaCha8Rng;

fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// A generator for the stream named by `seed` and a path of identifiers
/// (e.g. `[DOMAIN, epoch, index]`); different paths give independent streams.
pub fn derive_rng(seed: u64, path: &[u64]) -> SampleRng {
    let mut state = splitmix64(seed);
    for &p in path {
        state = splitmix64(state ^ splitmix64(p));
    }
    SampleRng::seed_from_u64(state)
}

/// Uniform in [0, 1) with 53 random bits.
pub fn uniform(rng: &mut SampleRng) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Uniform in [lo, hi).
pub fn uniform_in(rng: &mut SampleRng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * uniform(rng)
}

/// Uniform integer in [0, n) by Lemire's multiply-shift (bias below 2^-40 for the
/// sizes used here). `n` must be positive.
pub fn below(rng: &mut SampleRng, n: usize) -> usize {
    debug_assert!(n > 0);
    ((rng.next_u64() as u128 * n as u128) >> 64) as usize
}

/// Standard normal by Box–Muller (two uniforms per draw).
pub fn normal(rng: &mut SampleRng) -> f64 {
    let u1 = 1.0 - uniform(rng); // (0, 1]
    let u2 = uniform(rng);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Fisher–Yates shuffle.
pub fn shuffle<T>(rng: &mut SampleRng, items: &mut [T]) {
    for i in (1..items.len()).rev() {
        let j = below(rng, i + 1);
        items.swap(i, j);
    }
}

/// Stream domains, so that e.g. the jitter of object 3 and the augmentation of
/// sample 3 never share a stream.
pub(crate) mod domain {
    pub const JITTER: u64 = 1;
    pub const SAMPLE: u64 = 2;
    pub const ORDER: u64 = 3;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<u64> = (0..4).map(|_| derive_rng(7, &[1, 2]).next_u64()).collect();
        assert!(a.windows(2).all(|w| w[0] == w[1]));
        assert_ne!(
            derive_rng(7, &[1, 2]).next_u64(),
            derive_rng(7, &[2, 1]).next_u64()
        );
        assert_ne!(
            derive_rng(7, &[1, 2]).next_u64(),
            derive_rng(8, &[1, 2]).next_u64()
        );
    }

    #[test]
    fn distributions_are_in_range_and_roughly_right() {
        let mut rng = derive_rng(1, &[]);
        let n = 20_000;
        let mut sum = 0.0;
        let mut sum_sq = 0.0;
        for _ in 0..n {
            let u = uniform(&mut rng);
            assert!((0.0..1.0).contains(&u));
            assert!(below(&mut rng, 5) < 5);
            let z = normal(&mut rng);
            sum += z;
            sum_sq += z * z;
        }
        let mean = sum / n as f64;
        let var = sum_sq / n as f64 - mean * mean;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "{mean} {var}"
        );
    }

    #[test]
    fn shuffle_is_a_permutation() {
        let mut v: Vec<usize> = (0..100).collect();
        shuffle(&mut derive_rng(3, &[]), &mut v);
        assert_ne!(v, (0..100).collect::<Vec<_>>());
        v.sort();
        assert_eq!(v, (0..100).collect::<Vec<_>>());
    }
}
