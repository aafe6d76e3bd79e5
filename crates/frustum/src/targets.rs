//! Training targets: position labels, and the box encoding the network regresses
//! (with its exact inverse, [`decode_box`], that turns network outputs into KITTI boxes).
//!
//! Encoding of a ground-truth box in a frustum frame (see [`crate::FrustumFrame`]):
//! - centre: the geometric centre (KITTI bottom y − h/2) in the frustum frame; the
//!   network predicts it as an offset from each output position's centre;
//! - heading: the frustum-frame heading ry_f = ry − φ (mirrored: π − (ry − φ)) in
//!   [`NUM_HEADING_BINS`] bins over 2π, bin k centred at k·2π/12 (bin 0 centred at 0,
//!   covering [−π/12, π/12)), residual = heading − bin centre in radians, in [−π/12, π/12);
//! - size: cluster = the class (Car 0, Pedestrian 1, Cyclist 2, each with its mean
//!   size), residual = (size − mean) / mean for (l, w, h).

use crate::frustum::FrustumFrame;
use fusiondet_geometry::normalize_angle;
use fusiondet_kitti::{Box3d, ObjectClass};
use std::f64::consts::TAU;

/// Heading bins over 2π.
pub const NUM_HEADING_BINS: usize = 12;

/// The classes with a one-hot slot and a size cluster, in slot order.
pub const CLASSES: [ObjectClass; 3] = [
    ObjectClass::Car,
    ObjectClass::Pedestrian,
    ObjectClass::Cyclist,
];

/// Mean (l, w, h) in metres of each size cluster (the classes of [`CLASSES`]):
/// F-PointNet's / F-ConvNet's KITTI means at full precision (Car 3.883/1.629/1.526,
/// Pedestrian 0.844/0.661/1.763, Cyclist 1.763/0.597/1.737 rounded), the same values
/// as `fusiondet_models::KITTI_MEAN_SIZES`.
#[allow(clippy::excessive_precision)]
pub const MEAN_SIZES: [[f64; 3]; 3] = [
    [3.88311640418, 1.62856739989, 1.52563191462],
    [0.84422524, 0.66068622, 1.76255119],
    [1.76282397, 0.59706367, 1.73698127],
];

/// A position is positive when its centre lies in the ground-truth footprint with
/// length and width scaled by this factor.
pub const POSITIVE_SHRINK: f64 = 0.5;

/// Position labels.
pub const LABEL_POSITIVE: i64 = 1;
pub const LABEL_NEGATIVE: i64 = 0;
pub const LABEL_IGNORED: i64 = -1;

/// The size cluster (and one-hot slot) of a class; `None` for classes without one.
pub fn size_cluster_of(class: ObjectClass) -> Option<usize> {
    CLASSES.iter().position(|&c| c == class)
}

/// A heading as (bin, residual): residual = heading − bin·2π/12 in [−π/12, π/12).
pub fn heading_to_bin(heading: f64) -> (usize, f64) {
    let width = TAU / NUM_HEADING_BINS as f64;
    let shifted = (heading + 0.5 * width).rem_euclid(TAU);
    let bin = ((shifted / width) as usize).min(NUM_HEADING_BINS - 1);
    (bin, shifted - (bin as f64 + 0.5) * width)
}

/// The inverse of [`heading_to_bin`], wrapped to (−π, π].
pub fn bin_to_heading(bin: usize, residual: f64) -> f64 {
    normalize_angle(bin as f64 * TAU / NUM_HEADING_BINS as f64 + residual)
}

/// What the network regresses for one ground-truth box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxEncoding {
    /// Geometric centre in the frustum frame.
    pub center: [f64; 3],
    pub heading_bin: usize,
    pub heading_residual: f64,
    pub size_cluster: usize,
    /// (l, w, h) residual over the cluster's mean size.
    pub size_residual: [f64; 3],
}

/// Encodes a KITTI camera-frame box in `frame` with size cluster `size_cluster`
/// (see [`size_cluster_of`]; panics if it is not 0, 1 or 2).
pub fn encode_box(gt: &Box3d, size_cluster: usize, frame: &FrustumFrame) -> BoxEncoding {
    let mean = MEAN_SIZES[size_cluster];
    let f = frame.box_to_frustum(gt);
    let (heading_bin, heading_residual) = heading_to_bin(f.ry);
    BoxEncoding {
        center: [f.x, f.y - 0.5 * f.h, f.z],
        heading_bin,
        heading_residual,
        size_cluster,
        size_residual: [
            (f.l - mean[0]) / mean[0],
            (f.w - mean[1]) / mean[1],
            (f.h - mean[2]) / mean[2],
        ],
    }
}

/// Turns network outputs into a KITTI camera-frame box (bottom-centre location,
/// `ry` wrapped to (−π, π]): centre = `position_center + center_offset` in the
/// frustum frame, heading from bin and residual, size = mean · (1 + residual).
/// `frustum_rotation` is the sample's frame ([`crate::FrustumSample::frame`]), which
/// also undoes any training mirror or depth shift.
pub fn decode_box(
    position_center: [f64; 3],
    center_offset: [f64; 3],
    heading_bin: usize,
    heading_residual: f64,
    size_cluster: usize,
    size_residual: [f64; 3],
    frustum_rotation: &FrustumFrame,
) -> Box3d {
    let mean = MEAN_SIZES[size_cluster];
    let [l, w, h] = [0, 1, 2].map(|k| mean[k] * (1.0 + size_residual[k]));
    let c = [0, 1, 2].map(|k| position_center[k] + center_offset[k]);
    let in_frustum = Box3d {
        h,
        w,
        l,
        x: c[0],
        y: c[1] + 0.5 * h,
        z: c[2],
        ry: bin_to_heading(heading_bin, heading_residual),
    };
    frustum_rotation.box_to_rect(&in_frustum)
}

/// [`decode_box`] of an encoding (the position at the origin, the offset the centre).
pub fn decode_encoding(e: &BoxEncoding, frame: &FrustumFrame) -> Box3d {
    decode_box(
        [0.0; 3],
        e.center,
        e.heading_bin,
        e.heading_residual,
        e.size_cluster,
        e.size_residual,
        frame,
    )
}

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
    use crate::test_data::sample_camera;
    use proptest::prelude::*;
    use std::f64::consts::PI;

    #[test]
    fn heading_bins_cover_the_circle() {
        let w = TAU / 12.0;
        assert_eq!(heading_to_bin(0.0), (0, 0.0));
        let (b, r) = heading_to_bin(w);
        assert_eq!(b, 1);
        assert!(r.abs() < 1e-12);
        assert_eq!(heading_to_bin(-0.1).0, 0);
        assert_eq!(heading_to_bin(PI).0, 6);
        assert_eq!(heading_to_bin(-PI + 1e-9).0, 6);
        assert_eq!(heading_to_bin(-w).0, 11);
        for i in 0..1000 {
            let a = -PI + TAU * i as f64 / 1000.0;
            let (b, r) = heading_to_bin(a);
            assert!(
                b < 12 && (-0.5 * w..0.5 * w + 1e-12).contains(&r),
                "{a} -> {b} {r}"
            );
            assert!(normalize_angle(bin_to_heading(b, r) - a).abs() < 1e-12);
        }
    }

    fn arb_box() -> impl Strategy<Value = Box3d> {
        (
            -20.0..20.0f64,
            0.5..2.5f64,
            1.0..70.0f64,
            -PI..PI,
            0.3..5.0f64,
            0.3..2.5f64,
            0.5..2.5f64,
        )
            .prop_map(|(x, y, z, ry, l, w, h)| Box3d {
                h,
                w,
                l,
                x,
                y,
                z,
                ry,
            })
    }

    proptest! {
        #[test]
        fn encode_decode_round_trip(
            b in arb_box(), cluster in 0usize..3, u in 0.0..1242.0f64, v in 0.0..375.0f64,
            mirrored in any::<bool>(), shift in -4.0..4.0f64,
            position in (-1.0..1.0f64, -1.0..2.0f64, 0.0..70.0f64),
        ) {
            let frame = FrustumFrame::through_pixel(&sample_camera(), u, v).with_augmentation(mirrored, shift);
            let e = encode_box(&b, cluster, &frame);
            prop_assert!(e.heading_bin < NUM_HEADING_BINS);
            let check = |d: Box3d| {
                let ok = [(d.x, b.x), (d.y, b.y), (d.z, b.z), (d.l, b.l), (d.w, b.w), (d.h, b.h)]
                    .iter()
                    .all(|(p, q)| (p - q).abs() < 1e-9)
                    && normalize_angle(d.ry - b.ry).abs() < 1e-9;
                (ok, d)
            };
            let (ok, d) = check(decode_encoding(&e, &frame));
            prop_assert!(ok, "{d:?} vs {b:?}");
            // The same through a position centre and an offset from it.
            let p = [position.0, position.1, position.2];
            let off = [0, 1, 2].map(|k| e.center[k] - p[k]);
            let (ok, d) = check(decode_box(p, off, e.heading_bin, e.heading_residual, e.size_cluster, e.size_residual, &frame));
            prop_assert!(ok, "{d:?} vs {b:?}");
            // The encoded centre is the geometric centre: bottom y − h/2 in the frame.
            let bottom = frame.to_frustum([b.x, b.y, b.z]);
            prop_assert!((e.center[1] - (bottom[1] - 0.5 * b.h)).abs() < 1e-12);
        }
    }

    #[test]
    fn size_encoding_is_relative_to_the_class_mean() {
        let frame = FrustumFrame::through_pixel(&sample_camera(), 600.0, 180.0);
        let m = MEAN_SIZES[0];
        assert!(
            (m[0] - 3.883).abs() < 5e-4
                && (m[1] - 1.629).abs() < 5e-4
                && (m[2] - 1.526).abs() < 5e-4
        );
        let b = Box3d {
            h: m[2],
            w: m[1] * 1.1,
            l: m[0] * 0.5,
            x: 0.0,
            y: 1.6,
            z: 20.0,
            ry: 0.0,
        };
        let e = encode_box(&b, 0, &frame);
        assert!(
            (e.size_residual[0] + 0.5).abs() < 1e-12
                && (e.size_residual[1] - 0.1).abs() < 1e-12
                && e.size_residual[2].abs() < 1e-12
        );
        assert_eq!(size_cluster_of(ObjectClass::Cyclist), Some(2));
        assert_eq!(size_cluster_of(ObjectClass::Van), None);
    }

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
