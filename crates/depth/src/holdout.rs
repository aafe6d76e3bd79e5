//! Accuracy where no dense truth exists (real KITTI frames): hold out a seeded share of
//! the projected LiDAR pixels, complete from the rest, and measure on the held-out ones.

use crate::Result;
use crate::ip_basic::DepthCompleter;
use crate::metrics::{DepthErrors, depth_errors};
use fusiondet_dataset::rng::Sampler;
use fusiondet_kitti::DepthMap;

/// Splits `sparse` into (kept, held out): each measured pixel is held out with
/// probability `fraction`, drawn from `seed` (the same seed holds out the same pixels).
pub fn split_holdout(sparse: &DepthMap, fraction: f64, seed: u64) -> (DepthMap, DepthMap) {
    let mut rng = Sampler::from_path(seed, &[]);
    let mut kept = sparse.clone();
    let mut held = DepthMap::empty(sparse.width, sparse.height);
    for (i, &d) in sparse.data.iter().enumerate() {
        if d > 0.0 && rng.chance(fraction) {
            kept.data[i] = 0.0;
            held.data[i] = d;
        }
    }
    (kept, held)
}

/// Completes `sparse` without a held-out share and measures on that share.
pub fn holdout_errors(
    sparse: &DepthMap,
    fraction: f64,
    seed: u64,
    completer: &dyn DepthCompleter,
) -> Result<DepthErrors> {
    let (kept, held) = split_holdout(sparse, fraction, seed);
    depth_errors(&completer.complete(&kept), &held)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ip_basic::IpBasic;

    #[test]
    fn the_split_is_seeded_and_partitions_the_measurements() {
        let mut sparse = DepthMap::empty(50, 20);
        for i in (0..1000).step_by(3) {
            let (x, y) = (i % 50, i / 50);
            sparse.data[i] = 10.0 + 0.01 * x as f32 + 0.01 * y as f32;
        }
        let (kept, held) = split_holdout(&sparse, 0.2, 7);
        assert_eq!(
            kept.valid_count() + held.valid_count(),
            sparse.valid_count()
        );
        let share = held.valid_count() as f64 / sparse.valid_count() as f64;
        assert!((0.1..0.3).contains(&share), "{share}");
        assert_eq!(split_holdout(&sparse, 0.2, 7), (kept, held.clone()));
        assert_ne!(split_holdout(&sparse, 0.2, 8).1, held);
        // A smooth surface is predicted well at the held-out pixels.
        let e = holdout_errors(&sparse, 0.2, 7, &IpBasic::default()).unwrap();
        assert_eq!(e.pixels, held.valid_count());
        assert!(e.mae_mm < 100.0, "{e:?}");
    }
}
