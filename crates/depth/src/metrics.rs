//! The KITTI depth-completion errors against a ground truth: MAE and RMSE in mm, iMAE and
//! iRMSE in 1/km, over the pixels the ground truth measures.

use crate::{DepthError, Result};
use fusiondet_kitti::DepthMap;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthErrors {
    /// Ground-truth pixels compared.
    pub pixels: usize,
    /// Of those, pixels the prediction left empty (they count with depth 0 in MAE and
    /// RMSE and are left out of the inverse errors).
    pub missing: usize,
    pub mae_mm: f64,
    pub rmse_mm: f64,
    pub imae_per_km: f64,
    pub irmse_per_km: f64,
}

impl DepthErrors {
    /// The errors over all the pixels of several maps (each map weighted by its pixels;
    /// the inverse errors likewise, as each map reports them).
    pub fn pool<'a>(parts: impl IntoIterator<Item = &'a DepthErrors>) -> DepthErrors {
        let (mut n, mut missing, mut ae, mut se, mut iae, mut ise) = (0, 0, 0.0, 0.0, 0.0, 0.0);
        for e in parts {
            let m = e.pixels as f64;
            n += e.pixels;
            missing += e.missing;
            ae += e.mae_mm * m;
            se += e.rmse_mm * e.rmse_mm * m;
            iae += e.imae_per_km * m;
            ise += e.irmse_per_km * e.irmse_per_km * m;
        }
        let m = n.max(1) as f64;
        DepthErrors {
            pixels: n,
            missing,
            mae_mm: ae / m,
            rmse_mm: (se / m).sqrt(),
            imae_per_km: iae / m,
            irmse_per_km: (ise / m).sqrt(),
        }
    }
}

/// Leaves in a dense `truth` only what a LiDAR-based truth (KITTI's) covers: depths up to
/// `max_depth`, at or below the topmost measured pixel of each column of `sparse`.
pub fn restrict_to_scan_coverage(truth: &mut DepthMap, sparse: &DepthMap, max_depth: f32) {
    for x in 0..truth.width.min(sparse.width) {
        let top = (0..sparse.height)
            .find(|&y| sparse.get(x, y) > 0.0)
            .unwrap_or(sparse.height);
        for y in 0..truth.height {
            if y < top || truth.get(x, y) > max_depth {
                truth.set(x, y, 0.0);
            }
        }
    }
}

/// Errors of `prediction` on the pixels where `truth` has a depth.
pub fn depth_errors(prediction: &DepthMap, truth: &DepthMap) -> Result<DepthErrors> {
    if (prediction.width, prediction.height) != (truth.width, truth.height) {
        return Err(DepthError::Mismatch(format!(
            "the prediction is {}×{} but the ground truth {}×{}",
            prediction.width, prediction.height, truth.width, truth.height
        )));
    }
    let (mut n, mut missing, mut ae, mut se, mut iae, mut ise, mut ni) =
        (0, 0, 0.0, 0.0, 0.0, 0.0, 0);
    for (&p, &t) in prediction.data.iter().zip(&truth.data) {
        if t <= 0.0 {
            continue;
        }
        n += 1;
        let e = (p as f64 - t as f64) * 1000.0;
        ae += e.abs();
        se += e * e;
        if p > 0.0 {
            let ie = (1.0 / p as f64 - 1.0 / t as f64) * 1000.0;
            iae += ie.abs();
            ise += ie * ie;
            ni += 1;
        } else {
            missing += 1;
        }
    }
    let mean = |s: f64, k: usize| if k == 0 { 0.0 } else { s / k as f64 };
    Ok(DepthErrors {
        pixels: n,
        missing,
        mae_mm: mean(ae, n),
        rmse_mm: mean(se, n).sqrt(),
        imae_per_km: mean(iae, ni),
        irmse_per_km: mean(ise, ni).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_by_hand() {
        let truth = DepthMap {
            width: 3,
            height: 1,
            data: vec![10.0, 20.0, 0.0],
        };
        let pred = DepthMap {
            width: 3,
            height: 1,
            data: vec![10.5, 18.0, 7.0],
        };
        let e = depth_errors(&pred, &truth).unwrap();
        assert_eq!((e.pixels, e.missing), (2, 0));
        assert!((e.mae_mm - 1250.0).abs() < 1e-6);
        assert!((e.rmse_mm - ((500.0f64.powi(2) + 2000.0f64.powi(2)) / 2.0).sqrt()).abs() < 1e-6);
        let i1 = (1.0 / 10.5 - 0.1f64) * 1000.0;
        let i2 = (1.0 / 18.0 - 0.05f64) * 1000.0;
        assert!((e.imae_per_km - (i1.abs() + i2.abs()) / 2.0).abs() < 1e-6);
        let small = DepthMap::empty(2, 1);
        assert!(depth_errors(&small, &truth).is_err());
        // Pooling one map gives it back; two equal maps too.
        assert_eq!(DepthErrors::pool([&e]), e);
        let twice = DepthErrors::pool([&e, &e]);
        assert_eq!(twice.pixels, 4);
        assert!((twice.rmse_mm - e.rmse_mm).abs() < 1e-9 && (twice.mae_mm - e.mae_mm).abs() < 1e-9);
    }

    #[test]
    fn coverage_keeps_what_the_scan_sees_up_to_the_range() {
        let mut sparse = DepthMap::empty(2, 4);
        sparse.set(0, 1, 5.0); // column 0 scanned from row 1 down; column 1 not at all
        let mut truth = DepthMap {
            width: 2,
            height: 4,
            data: vec![9.0, 9.0, 9.0, 9.0, 90.0, 9.0, 9.0, 9.0],
        };
        restrict_to_scan_coverage(&mut truth, &sparse, 80.0);
        assert_eq!(truth.data, vec![0.0, 0.0, 9.0, 0.0, 0.0, 0.0, 9.0, 0.0]);
    }
}
