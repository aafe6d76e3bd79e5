//! The box coder of both stages (OpenPCDet's `ResidualCoder`, 7 values) and the anchor
//! head's direction classifier.
//!
//! A box is encoded against a reference box (an anchor, or a RoI in its own frame):
//! - centre offsets x and y over the reference's bird's-eye diagonal √(dx² + dy²), z
//!   over its height: a car's and a pedestrian's offsets have similar scales;
//! - sizes as log ratios;
//! - heading as the plain difference (the direction classifier settles the π
//!   ambiguity that the loss's sin(a − b) leaves).

use crate::boxes::{LidarBox, limit_period};
use crate::config::AnchorConfig;
use std::f64::consts::TAU;

/// Values per encoded box.
pub const CODE_SIZE: usize = 7;

/// Sizes are floored here before their logarithm, as OpenPCDet does.
const MIN_SIZE: f64 = 1e-5;

/// The residual code of `gt` against `reference`:
/// [(xg − xa)/d, (yg − ya)/d, (zg − za)/dza, ln(dxg/dxa), ln(dyg/dya), ln(dzg/dza), rg − ra].
pub fn encode(gt: &LidarBox, reference: &LidarBox) -> [f64; CODE_SIZE] {
    let [dxa, dya, dza] = [reference.dx, reference.dy, reference.dz].map(|s| s.max(MIN_SIZE));
    let [dxg, dyg, dzg] = [gt.dx, gt.dy, gt.dz].map(|s| s.max(MIN_SIZE));
    let diagonal = (dxa * dxa + dya * dya).sqrt();
    [
        (gt.x - reference.x) / diagonal,
        (gt.y - reference.y) / diagonal,
        (gt.z - reference.z) / dza,
        libm::log(dxg / dxa),
        libm::log(dyg / dya),
        libm::log(dzg / dza),
        gt.heading - reference.heading,
    ]
}

/// The box a residual code stands for (the inverse of [`encode`]).
pub fn decode(code: &[f64; CODE_SIZE], reference: &LidarBox) -> LidarBox {
    let a = reference;
    let diagonal = (a.dx * a.dx + a.dy * a.dy).sqrt();
    LidarBox {
        x: code[0] * diagonal + a.x,
        y: code[1] * diagonal + a.y,
        z: code[2] * a.dz + a.z,
        dx: libm::exp(code[3]) * a.dx,
        dy: libm::exp(code[4]) * a.dy,
        dz: libm::exp(code[5]) * a.dz,
        heading: code[6] + a.heading,
    }
}

/// The direction classifier: `bins` sectors of 2π/bins each, starting at `offset`. With
/// the published 2 bins from π/4, bin 0 holds headings in [π/4, 5π/4) and bin 1 the
/// others: it tells which end of the box is the front.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectionBins {
    pub offset: f64,
    pub limit_offset: f64,
    pub bins: usize,
}

impl DirectionBins {
    pub fn from_config(config: &AnchorConfig) -> DirectionBins {
        DirectionBins {
            offset: config.dir_offset,
            limit_offset: config.dir_limit_offset,
            bins: config.num_dir_bins,
        }
    }

    /// The angle one bin covers.
    pub fn period(&self) -> f64 {
        TAU / self.bins as f64
    }

    /// The bin of a heading (the training target).
    pub fn target(&self, heading: f64) -> usize {
        let rot = limit_period(heading - self.offset, 0.0, TAU);
        ((rot / self.period()).floor().max(0.0) as usize).min(self.bins - 1)
    }

    /// A decoded heading moved into the predicted bin: wrapped into one period after
    /// the offset, then shifted by `bin` periods.
    pub fn apply(&self, heading: f64, bin: usize) -> f64 {
        let period = self.period();
        limit_period(heading - self.offset, self.limit_offset, period)
            + self.offset
            + period * bin as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

    fn anchor() -> LidarBox {
        LidarBox {
            x: 10.0,
            y: -2.0,
            z: -1.0,
            dx: 3.9,
            dy: 1.6,
            dz: 1.56,
            heading: 1.57,
        }
    }

    #[test]
    fn encoding_by_hand() {
        let a = anchor();
        let d = (3.9f64 * 3.9 + 1.6 * 1.6).sqrt(); // √17.77
        let gt = LidarBox {
            x: a.x + d,
            y: a.y - d / 2.0,
            z: a.z + 0.78,
            dx: 3.9 * std::f64::consts::E,
            dy: 1.6,
            dz: 1.56 / 2.0,
            heading: 1.87,
        };
        let code = encode(&gt, &a);
        let want = [1.0, -0.5, 0.5, 1.0, 0.0, -(2f64.ln()), 0.3];
        for k in 0..CODE_SIZE {
            assert!((code[k] - want[k]).abs() < 1e-12, "{k}: {code:?}");
        }
    }

    #[test]
    fn decode_inverts_encode() {
        let a = anchor();
        for gt in [
            anchor(),
            LidarBox {
                x: 13.2,
                y: -0.4,
                z: -0.6,
                dx: 4.4,
                dy: 1.8,
                dz: 1.5,
                heading: -2.9,
            },
            LidarBox {
                x: 9.0,
                y: -3.5,
                z: -1.3,
                dx: 0.8,
                dy: 0.6,
                dz: 1.73,
                heading: 0.1,
            },
        ] {
            let back = decode(&encode(&gt, &a), &a);
            let (p, q) = (back.to_array(), gt.to_array());
            for k in 0..7 {
                assert!((p[k] - q[k]).abs() < 1e-12, "{back:?} vs {gt:?}");
            }
        }
    }

    #[test]
    fn direction_bins_by_hand() {
        let dir = DirectionBins {
            offset: FRAC_PI_4,
            limit_offset: 0.0,
            bins: 2,
        };
        assert_eq!(dir.target(FRAC_PI_2), 0);
        assert_eq!(dir.target(PI), 0);
        assert_eq!(dir.target(0.0), 1);
        assert_eq!(dir.target(-FRAC_PI_2), 1);
        assert_eq!(dir.target(FRAC_PI_4), 0); // a bin's start belongs to it
        // A prediction 0.1 off the axis with bin 0 means the box faces π + 0.1.
        assert!((dir.apply(0.1, 0) - (PI + 0.1)).abs() < 1e-12);
        assert!((dir.apply(0.1, 1) - (TAU + 0.1)).abs() < 1e-12);
        // Moving any heading into its own bin gives the heading back (modulo 2π), even
        // when the regressed value is off by π.
        for k in 0..64 {
            let h = -PI + k as f64 * TAU / 64.0 + 0.01;
            for guess in [h, h + PI, h - PI] {
                let back = dir.apply(guess, dir.target(h));
                assert!(limit_period(back - h, 0.5, TAU).abs() < 1e-9, "{h} {guess}");
            }
        }
        let published = DirectionBins::from_config(&AnchorConfig::default());
        assert_eq!((published.bins, published.offset), (2, FRAC_PI_4));
    }
}
