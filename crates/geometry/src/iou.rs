//! Overlap measures: axis-aligned 2D IoU, rotated bird's-eye-view IoU by exact convex
//! polygon clipping, and 3D IoU (BEV intersection × height overlap over [y − h, y]).
//!
//! Written by hand because the general polygon crates (geo's boolean ops) are far
//! slower for the 4-vertex convex case the evaluation runs millions of times, and
//! their robustness for identical footprints is not what we need to guarantee.

use crate::box3d::bev_polygon;
use crate::boxes::{Box2d, Box3d};

/// What an overlap is divided by, as in the KITTI devkit's `criterion` argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Normalization {
    /// Intersection over union.
    Union,
    /// Intersection over the first box's area/volume (used for DontCare regions).
    First,
}

fn finish(inter: f64, area_a: f64, area_b: f64, norm: Normalization) -> f64 {
    let denom = match norm {
        Normalization::Union => area_a + area_b - inter,
        Normalization::First => area_a,
    };
    if denom <= 0.0 || inter <= 0.0 {
        0.0
    } else {
        (inter / denom).clamp(0.0, 1.0)
    }
}

/// Image-box overlap (continuous coordinates, no +1 pixel, as in the devkit).
pub fn overlap_2d(a: &Box2d, b: &Box2d, norm: Normalization) -> f64 {
    let w = a.x2.min(b.x2) - a.x1.max(b.x1);
    let h = a.y2.min(b.y2) - a.y1.max(b.y1);
    if w <= 0.0 || h <= 0.0 {
        return 0.0;
    }
    finish(w * h, a.width() * a.height(), b.width() * b.height(), norm)
}

pub fn iou_2d(a: &Box2d, b: &Box2d) -> f64 {
    overlap_2d(a, b, Normalization::Union)
}

/// Signed area of a polygon (positive when counter-clockwise).
pub fn signed_area(poly: &[[f64; 2]]) -> f64 {
    let n = poly.len();
    let mut s = 0.0;
    for i in 0..n {
        let (p, q) = (poly[i], poly[(i + 1) % n]);
        s += p[0] * q[1] - q[0] * p[1];
    }
    0.5 * s
}

fn counter_clockwise(poly: &[[f64; 2]; 4]) -> [[f64; 2]; 4] {
    if signed_area(poly) < 0.0 {
        [poly[3], poly[2], poly[1], poly[0]]
    } else {
        *poly
    }
}

/// Area of the intersection of two convex polygons (any orientation), by clipping
/// the first against each edge of the second (Sutherland–Hodgman). Points on an
/// edge count as inside, so identical polygons intersect in themselves.
pub fn convex_intersection_area(a: &[[f64; 2]; 4], b: &[[f64; 2]; 4]) -> f64 {
    let a = counter_clockwise(a);
    let b = counter_clockwise(b);
    // Scale-aware tolerance for "on the edge".
    let scale = a
        .iter()
        .chain(b.iter())
        .fold(1.0f64, |m, p| m.max(p[0].abs()).max(p[1].abs()));
    let eps = 1e-12 * scale * scale;
    let mut subject: Vec<[f64; 2]> = a.to_vec();
    let mut next: Vec<[f64; 2]> = Vec::with_capacity(8);
    for i in 0..4 {
        if subject.is_empty() {
            return 0.0;
        }
        let (e0, e1) = (b[i], b[(i + 1) % 4]);
        let side =
            |p: [f64; 2]| (e1[0] - e0[0]) * (p[1] - e0[1]) - (e1[1] - e0[1]) * (p[0] - e0[0]);
        next.clear();
        let n = subject.len();
        for k in 0..n {
            let cur = subject[k];
            let prev = subject[(k + n - 1) % n];
            let (sc, sp) = (side(cur), side(prev));
            let (cur_in, prev_in) = (sc >= -eps, sp >= -eps);
            if cur_in {
                if !prev_in {
                    next.push(intersect(prev, cur, sp, sc));
                }
                next.push(cur);
            } else if prev_in {
                next.push(intersect(prev, cur, sp, sc));
            }
        }
        std::mem::swap(&mut subject, &mut next);
    }
    if subject.len() < 3 {
        return 0.0;
    }
    signed_area(&subject).max(0.0)
}

/// Point where segment p→q crosses the clipping line, from the signed distances.
fn intersect(p: [f64; 2], q: [f64; 2], sp: f64, sq: f64) -> [f64; 2] {
    let t = sp / (sp - sq);
    [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]
}

/// Bird's-eye-view intersection area of two boxes.
pub fn bev_intersection(a: &Box3d, b: &Box3d) -> f64 {
    // Cheap rejection by bounding circles.
    let ra = 0.5 * (a.l * a.l + a.w * a.w).sqrt();
    let rb = 0.5 * (b.l * b.l + b.w * b.w).sqrt();
    let (dx, dz) = (a.x - b.x, a.z - b.z);
    if dx * dx + dz * dz > (ra + rb) * (ra + rb) {
        return 0.0;
    }
    convex_intersection_area(&bev_polygon(a), &bev_polygon(b))
}

/// Rotated bird's-eye-view overlap.
pub fn overlap_bev(a: &Box3d, b: &Box3d, norm: Normalization) -> f64 {
    let inter = bev_intersection(a, b);
    finish(inter, (a.l * a.w).abs(), (b.l * b.w).abs(), norm)
}

pub fn iou_bev(a: &Box3d, b: &Box3d) -> f64 {
    overlap_bev(a, b, Normalization::Union)
}

/// Height overlap of the two boxes' vertical extents [y − h, y].
pub fn height_overlap(a: &Box3d, b: &Box3d) -> f64 {
    (a.y.min(b.y) - (a.y - a.h).max(b.y - b.h)).max(0.0)
}

/// 3D overlap: BEV intersection × height overlap.
pub fn overlap_3d(a: &Box3d, b: &Box3d, norm: Normalization) -> f64 {
    let hov = height_overlap(a, b);
    if hov <= 0.0 {
        return 0.0;
    }
    let inter = bev_intersection(a, b) * hov;
    finish(
        inter,
        (a.l * a.w * a.h).abs(),
        (b.l * b.w * b.h).abs(),
        norm,
    )
}

pub fn iou_3d(a: &Box3d, b: &Box3d) -> f64 {
    overlap_3d(a, b, Normalization::Union)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn b3(x: f64, z: f64, l: f64, w: f64, ry: f64) -> Box3d {
        Box3d {
            h: 1.5,
            w,
            l,
            x,
            y: 1.0,
            z,
            ry,
        }
    }

    #[test]
    fn identical_boxes_have_iou_one() {
        let b = b3(3.2, 17.9, 3.9, 1.6, 0.77);
        assert!((iou_bev(&b, &b) - 1.0).abs() < 1e-12);
        assert!((iou_3d(&b, &b) - 1.0).abs() < 1e-12);
        // Identical footprint, the other heading by pi: same polygon, vertices shifted.
        let flipped = Box3d {
            ry: b.ry + std::f64::consts::PI,
            ..b
        };
        assert!((iou_bev(&b, &flipped) - 1.0).abs() < 1e-9);
        // A square rotated by 90 degrees is the same footprint too.
        let sq = b3(0.0, 10.0, 2.0, 2.0, 0.0);
        let sq90 = Box3d {
            ry: std::f64::consts::FRAC_PI_2,
            ..sq
        };
        assert!((iou_bev(&sq, &sq90) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn hand_computed_cases() {
        // Two axis-aligned 2x2 squares offset by 1 in x: inter 2, union 6.
        let a = b3(0.0, 0.0, 2.0, 2.0, 0.0);
        let b = b3(1.0, 0.0, 2.0, 2.0, 0.0);
        assert!((iou_bev(&a, &b) - 2.0 / 6.0).abs() < 1e-12);
        // A square and itself rotated 45 degrees: octagon of area 8(sqrt2 - 1).
        let r = Box3d {
            ry: std::f64::consts::FRAC_PI_4,
            ..a
        };
        let inter = 8.0 * (2f64.sqrt() - 1.0);
        assert!((iou_bev(&a, &r) - inter / (8.0 - inter)).abs() < 1e-12);
        // Half height overlap halves the 3D intersection.
        let up = Box3d { y: a.y - 0.75, ..a };
        assert!((iou_3d(&a, &up) - 0.5 * 6.0 / (2.0 * 6.0 - 0.5 * 6.0)).abs() < 1e-12);
        // Over-first normalisation.
        let big = b3(0.0, 0.0, 4.0, 4.0, 0.0);
        assert!((overlap_bev(&a, &big, Normalization::First) - 1.0).abs() < 1e-12);
        assert!((overlap_bev(&big, &a, Normalization::First) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn image_boxes() {
        let a = Box2d {
            x1: 0.0,
            y1: 0.0,
            x2: 10.0,
            y2: 10.0,
        };
        let b = Box2d {
            x1: 5.0,
            y1: 0.0,
            x2: 15.0,
            y2: 10.0,
        };
        assert!((iou_2d(&a, &b) - 50.0 / 150.0).abs() < 1e-12);
        assert_eq!(
            iou_2d(
                &a,
                &Box2d {
                    x1: 10.0,
                    y1: 0.0,
                    x2: 20.0,
                    y2: 10.0
                }
            ),
            0.0
        );
        assert!((iou_2d(&a, &a) - 1.0).abs() < 1e-15);
    }

    fn arb_box() -> impl Strategy<Value = Box3d> {
        (
            -20.0..20.0f64,
            0.0..60.0f64,
            0.3..6.0f64,
            0.3..3.0f64,
            -4.0..4.0f64,
            0.5..3.0f64,
            -1.0..3.0f64,
        )
            .prop_map(|(x, z, l, w, ry, h, y)| Box3d {
                h,
                w,
                l,
                x,
                y,
                z,
                ry,
            })
    }

    fn moved(b: &Box3d, theta: f64, tx: f64, ty: f64, tz: f64) -> Box3d {
        // Rigid motion: rotation about the camera y axis (same convention as `corners`), then translation.
        let (s, c) = theta.sin_cos();
        Box3d {
            x: c * b.x + s * b.z + tx,
            z: -s * b.x + c * b.z + tz,
            y: b.y + ty,
            ry: b.ry + theta,
            ..*b
        }
    }

    proptest! {
        #[test]
        fn iou_is_symmetric_and_bounded(a in arb_box(), b in arb_box()) {
            for (ab, ba) in [(iou_bev(&a, &b), iou_bev(&b, &a)), (iou_3d(&a, &b), iou_3d(&b, &a))] {
                prop_assert!((0.0..=1.0).contains(&ab));
                prop_assert!((ab - ba).abs() < 1e-9, "{ab} vs {ba}");
            }
        }

        #[test]
        fn iou_of_a_box_with_itself_is_one(a in arb_box()) {
            prop_assert!((iou_bev(&a, &a) - 1.0).abs() < 1e-9);
            prop_assert!((iou_3d(&a, &a) - 1.0).abs() < 1e-9);
        }

        #[test]
        fn iou_is_invariant_under_rigid_motion(
            a in arb_box(), b in arb_box(), theta in -3.2..3.2f64,
            tx in -30.0..30.0f64, ty in -2.0..2.0f64, tz in -30.0..30.0f64,
        ) {
            let (a2, b2) = (moved(&a, theta, tx, ty, tz), moved(&b, theta, tx, ty, tz));
            prop_assert!((iou_bev(&a, &b) - iou_bev(&a2, &b2)).abs() < 1e-7);
            prop_assert!((iou_3d(&a, &b) - iou_3d(&a2, &b2)).abs() < 1e-7);
        }

        #[test]
        fn nearby_boxes_overlap_as_their_areas_allow(a in arb_box(), fx in -0.3..0.3f64, fz in -0.3..0.3f64) {
            // A shift under half the smaller side keeps the centre of each box inside the other.
            let r = a.l.min(a.w);
            let b = Box3d { x: a.x + fx * r, z: a.z + fz * r, ..a };
            let inter = bev_intersection(&a, &b);
            prop_assert!(inter <= a.l * a.w + 1e-9);
            prop_assert!(inter > 0.0);
        }
    }
}
