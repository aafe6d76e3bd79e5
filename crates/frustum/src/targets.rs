//! Training targets: which output positions are positive for a ground-truth box. What
//! the network regresses for the box itself is the [`BoxCoder`](crate::coder::BoxCoder)'s.

use fusiondet_kitti::Box3d;

/// A position is positive when its centre lies in the ground-truth footprint with
/// length and width scaled by this factor.
pub const POSITIVE_SHRINK: f64 = 0.5;

/// Position labels.
pub const LABEL_POSITIVE: i64 = 1;
pub const LABEL_NEGATIVE: i64 = 0;
pub const LABEL_IGNORED: i64 = -1;

/// Whether (x, z) lies in the bird's-eye footprint of `b` with length and width
/// scaled by `scale` (faces included).
pub fn in_footprint(b: &Box3d, x: f64, z: f64, scale: f64) -> bool {
    let (s, c) = b.ry.sin_cos();
    let (dx, dz) = (x - b.x, z - b.z);
    // The inverse of the rotation in `geometry::corners`.
    let lx = c * dx - s * dz;
    let lz = s * dx + c * dz;
    lx.abs() <= 0.5 * b.l * scale && lz.abs() <= 0.5 * b.w * scale
}

/// Labels of the output positions for one ground-truth box, both in the same
/// frustum frame (`gt` with its bottom-centre location as in KITTI).
///
/// The test is in bird's-eye view (x–z) only: positions lie on the box-centre ray,
/// whose height need not pass through the box. Positive: inside the footprint with
/// l and w scaled by [`POSITIVE_SHRINK`]; ignored: inside the full footprint only;
/// negative otherwise. If no position is positive, the one nearest to the box centre
/// in bird's-eye distance (the first on a tie) becomes positive.
pub fn position_labels(positions: &[[f64; 3]], gt: &Box3d) -> Vec<i64> {
    let mut labels: Vec<i64> = positions
        .iter()
        .map(|p| {
            if in_footprint(gt, p[0], p[2], POSITIVE_SHRINK) {
                LABEL_POSITIVE
            } else if in_footprint(gt, p[0], p[2], 1.0) {
                LABEL_IGNORED
            } else {
                LABEL_NEGATIVE
            }
        })
        .collect();
    if !labels.contains(&LABEL_POSITIVE) {
        let dist = |p: &[f64; 3]| (p[0] - gt.x).hypot(p[2] - gt.z);
        let nearest = (0..positions.len()).min_by(|&a, &b| {
            dist(&positions[a])
                .total_cmp(&dist(&positions[b]))
                .then(a.cmp(&b))
        });
        if let Some(i) = nearest {
            labels[i] = LABEL_POSITIVE;
        }
    }
    labels
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn ray(n: usize, stride: f64) -> Vec<[f64; 3]> {
        (0..n)
            .map(|k| [0.0, 1.0, (k as f64 + 0.5) * stride])
            .collect()
    }

    /// A car across the ray at 20 m, length along z (ry = π/2): footprint z ∈ [18, 22],
    /// shrunk [19, 21]; x extent ±0.8 (shrunk ±0.4) contains the ray.
    fn car_across_ray_at_20m() -> Box3d {
        Box3d {
            h: 1.5,
            w: 1.6,
            l: 4.0,
            x: 0.1,
            y: 1.7,
            z: 20.0,
            ry: PI / 2.0,
        }
    }

    /// Positions on the ray: positive inside the shrunk footprint z ∈ [19, 21], ignored in
    /// the rest of [18, 22], negative elsewhere.
    fn assert_labels_across_car_at_20m(pos: &[[f64; 3]], labels: &[i64]) {
        for (p, l) in pos.iter().zip(labels) {
            let z = p[2];
            let expect = if (19.0..=21.0).contains(&z) {
                1
            } else if (18.0..=22.0).contains(&z) {
                -1
            } else {
                0
            };
            assert_eq!(*l, expect, "z {z}");
        }
    }

    #[test]
    fn labels_on_a_synthetic_object() {
        let gt = car_across_ray_at_20m();
        let pos = ray(140, 0.5);
        let labels = position_labels(&pos, &gt);
        assert_labels_across_car_at_20m(&pos, &labels);
        assert_eq!(labels.iter().filter(|&&l| l == 1).count(), 4); // 19.25 .. 20.75
        // Every positive really is inside the shrunk box.
        for (p, l) in pos.iter().zip(&labels) {
            if *l == 1 {
                assert!(in_footprint(&gt, p[0], p[2], 0.5));
            }
        }
        // Height does not matter: the same box 3 m above the ray labels the same.
        assert_eq!(position_labels(&pos, &Box3d { y: -1.3, ..gt }), labels);
    }

    /// Depth-guided output positions: the near region's centre, then even ones.
    fn depth_guided_ray(near: f64, n: usize, range: f64) -> Vec<[f64; 3]> {
        let step = (range - near) / n as f64;
        std::iter::once([0.0, 1.0, 0.5 * near])
            .chain((1..n).map(|k| [0.0, 1.0, near + k as f64 * step]))
            .collect()
    }

    #[test]
    fn labels_with_uneven_depth_guided_positions() {
        // Near region [0, 12] (centre 6), then 119 positions 0.525 m apart from 12.525 m.
        let pos = depth_guided_ray(12.0, 120, 75.0);
        let gt = car_across_ray_at_20m();
        let labels = position_labels(&pos, &gt);
        assert_labels_across_car_at_20m(&pos, &labels);
        // 19.35, 19.875, 20.4, 20.925.
        assert_eq!(labels.iter().filter(|&&l| l == 1).count(), 4);
        // An object inside the near region: the near centre is the nearest position.
        let near_obj = Box3d {
            x: 1.5,
            z: 7.0,
            ..gt
        };
        let labels = position_labels(&pos, &near_obj);
        assert_eq!(labels[0], 1);
        assert_eq!(labels.iter().filter(|&&l| l == 1).count(), 1);
        // Between the near centre (6) and the first fine one (12.525), beside the ray:
        // the fine one at 12.525 is nearer to z = 10 than 6 is.
        let gap = Box3d {
            x: 1.5,
            z: 10.0,
            ..gt
        };
        let labels = position_labels(&pos, &gap);
        assert_eq!(labels.iter().position(|&l| l == 1), Some(1));
        assert_eq!(labels.iter().filter(|&&l| l == 1).count(), 1);
    }

    #[test]
    fn nearest_position_is_positive_when_none_is_inside() {
        // A pedestrian 1 m beside the ray: no position inside; nearest is z = 30.25.
        let gt = Box3d {
            h: 1.7,
            w: 0.6,
            l: 0.8,
            x: 1.0,
            y: 1.7,
            z: 30.3,
            ry: 0.0,
        };
        let labels = position_labels(&ray(140, 0.5), &gt);
        assert_eq!(labels.iter().filter(|&&l| l == 1).count(), 1);
        assert_eq!(labels[60], 1);
        assert!(labels.iter().all(|&l| l != -1));
        // Beyond the range: the last position.
        let far = Box3d {
            x: 0.0,
            z: 95.0,
            ..gt
        };
        assert_eq!(position_labels(&ray(140, 0.5), &far)[139], 1);
    }
}
