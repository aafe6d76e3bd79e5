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
    }
}
