//! The frustum frame and frustum extraction from a 2D box.
//!
//! # The frustum frame
//!
//! Let C be P2's optical centre in the rectified camera frame (C = −M⁻¹t for
//! P2 = [M | t]; about 6 cm left of the rectified origin in KITTI) and d = M⁻¹(u, v, 1)
//! the direction of the ray through the 2D box centre (u, v). With
//! φ = atan2(d_x, d_z) the ray's azimuth, a rectified point p maps to
//!
//! ```text
//! x_f = cos φ · (p_x − C_x) − sin φ · (p_z − C_z)
//! y_f = p_y
//! z_f = sin φ · (p_x − C_x) + cos φ · (p_z − C_z)
//! ```
//!
//! i.e. the rectified frame moved horizontally to C and rotated about y by −φ (KITTI's
//! rotation convention, that of `geometry::corners`). The box-centre ray is then
//! exactly x_f = 0 for every depth, y stays down and unchanged, and z_f is the
//! horizontal distance from C along the ray: the frustum's depth. A point on the
//! ray at depth z_f has y_f = C_y + z_f · d_y / √(d_x² + d_z²).
//!
//! Headings follow: a KITTI `rotation_y` of ry becomes ry_f = ry − φ (wrapped to
//! (−π, π]), the same relation as the observation angle alpha = ry − atan2(x, z) with
//! the frustum ray in place of the box-centre ray.
//!
//! A frustum cut around a 3D proposal (the refinement stage) moves the frame's origin
//! along the axis: z_f is then measured from `depth_origin` (the proposal centre's
//! depth), so that every proposal sits at depth 0 and one fixed depth range tiles all
//! of them. Image frustums have `depth_origin` = 0.
//!
//! Training augmentation extends the frame by two operations applied after the
//! rotation, so that [`FrustumFrame::to_rect`] is always the exact inverse and a
//! network output decodes to the camera frame whatever was done to the sample:
//! a mirror x_f → −x_f (headings ry_f → π − ry_f) and a depth shift z_f → z_f + s.

use crate::error::SkipReason;
use crate::frame::ProjectedFrame;
use fusiondet_geometry::{CameraModel, normalize_angle};
use fusiondet_kitti::{Box2d, Box3d};
use std::f64::consts::PI;

/// The rigid map between the rectified camera frame and one frustum's frame
/// (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrustumFrame {
    /// φ: azimuth of the box-centre ray in the rectified frame, atan2(d_x, d_z).
    pub azimuth: f64,
    /// P2's optical centre C in the rectified frame. Only x and z move points; y is
    /// where the ray starts vertically.
    pub origin: [f64; 3],
    /// d_y / √(d_x² + d_z²): the ray's vertical slope per metre of frustum depth.
    pub ray_slope: f64,
    /// Mirrored about the frustum axis (training flip).
    pub mirrored: bool,
    /// Metres added to the frustum depth (training depth shift).
    pub depth_shift: f64,
    /// Depth along the ray (from C) that is z_f = 0: 0 for image frustums, the proposal
    /// centre's depth for refinement frustums. Part of the base frame, not augmentation.
    pub depth_origin: f64,
}

impl FrustumFrame {
    /// The frame whose axis is the ray through pixel (u, v).
    pub fn through_pixel(camera: &CameraModel, u: f64, v: f64) -> FrustumFrame {
        let origin = camera.image_to_rect(u, v, 0.0);
        let far = camera.image_to_rect(u, v, 1.0);
        let d = [far[0] - origin[0], far[1] - origin[1], far[2] - origin[2]];
        let horizontal = d[0].hypot(d[2]);
        FrustumFrame {
            azimuth: d[0].atan2(d[2]),
            origin,
            ray_slope: d[1] / horizontal,
            mirrored: false,
            depth_shift: 0.0,
            depth_origin: 0.0,
        }
    }

    /// The same frame with z_f = 0 at depth `depth` along the ray.
    pub fn with_depth_origin(&self, depth: f64) -> FrustumFrame {
        FrustumFrame {
            depth_origin: depth,
            ..*self
        }
    }

    /// The frame of a 2D box: the ray through its centre.
    pub fn for_box(camera: &CameraModel, b: &Box2d) -> FrustumFrame {
        let (u, v) = b.center();
        FrustumFrame::through_pixel(camera, u, v)
    }

    /// The same frame with the training augmentation set.
    pub fn with_augmentation(&self, mirrored: bool, depth_shift: f64) -> FrustumFrame {
        FrustumFrame {
            mirrored,
            depth_shift,
            ..*self
        }
    }

    /// The un-augmented frame.
    pub fn base(&self) -> FrustumFrame {
        self.with_augmentation(false, 0.0)
    }

    /// Rectified camera → frustum frame.
    pub fn to_frustum(&self, p: [f64; 3]) -> [f64; 3] {
        let (s, c) = self.azimuth.sin_cos();
        let (dx, dz) = (p[0] - self.origin[0], p[2] - self.origin[2]);
        self.augment([c * dx - s * dz, p[1], s * dx + c * dz - self.depth_origin])
    }

    /// Frustum frame → rectified camera frame (the inverse of [`Self::to_frustum`]).
    pub fn to_rect(&self, q: [f64; 3]) -> [f64; 3] {
        let (s, c) = self.azimuth.sin_cos();
        let q = self.unaugment(q);
        let z = q[2] + self.depth_origin;
        [
            c * q[0] + s * z + self.origin[0],
            q[1],
            -s * q[0] + c * z + self.origin[2],
        ]
    }

    /// Applies mirror and depth shift to a point of the un-augmented frustum frame.
    pub fn augment(&self, q: [f64; 3]) -> [f64; 3] {
        let x = if self.mirrored { -q[0] } else { q[0] };
        [x, q[1], q[2] + self.depth_shift]
    }

    fn unaugment(&self, q: [f64; 3]) -> [f64; 3] {
        let x = if self.mirrored { -q[0] } else { q[0] };
        [x, q[1], q[2] - self.depth_shift]
    }

    /// The row-major 3 × 4 matrix taking (augmented) frustum-frame points to homogeneous
    /// pixels: P2 · [A | t] where `to_rect(q) = A·q + t`.
    pub fn image_projection(&self, p2: &[[f64; 4]; 3]) -> [f64; 12] {
        let (s, c) = self.azimuth.sin_cos();
        let m = if self.mirrored { -1.0 } else { 1.0 };
        let a = [[c * m, 0.0, s], [0.0, 1.0, 0.0], [-s * m, 0.0, c]];
        let along = self.depth_origin - self.depth_shift;
        let t = [self.origin[0] + s * along, 0.0, self.origin[2] + c * along];
        let mut out = [0.0; 12];
        for r in 0..3 {
            for col in 0..3 {
                out[4 * r + col] = (0..3).map(|k| p2[r][k] * a[k][col]).sum();
            }
            out[4 * r + 3] = (0..3).map(|k| p2[r][k] * t[k]).sum::<f64>() + p2[r][3];
        }
        out
    }

    /// KITTI rotation_y → heading in the frustum frame, wrapped to (−π, π].
    pub fn heading_to_frustum(&self, ry: f64) -> f64 {
        let a = ry - self.azimuth;
        normalize_angle(if self.mirrored { PI - a } else { a })
    }

    /// Frustum-frame heading → KITTI rotation_y, wrapped to (−π, π].
    pub fn heading_to_rect(&self, heading: f64) -> f64 {
        let a = if self.mirrored { PI - heading } else { heading };
        normalize_angle(a + self.azimuth)
    }

    /// A KITTI box (bottom-centre location) expressed in the frustum frame: location
    /// still the bottom centre, `ry` the frustum-frame heading, sizes unchanged.
    pub fn box_to_frustum(&self, b: &Box3d) -> Box3d {
        let [x, y, z] = self.to_frustum([b.x, b.y, b.z]);
        Box3d {
            x,
            y,
            z,
            ry: self.heading_to_frustum(b.ry),
            ..*b
        }
    }

    /// The inverse of [`Self::box_to_frustum`].
    pub fn box_to_rect(&self, b: &Box3d) -> Box3d {
        let [x, y, z] = self.to_rect([b.x, b.y, b.z]);
        Box3d {
            x,
            y,
            z,
            ry: self.heading_to_rect(b.ry),
            ..*b
        }
    }

    /// The point of the box-centre ray at frustum depth `depth`, in the un-augmented
    /// frustum frame: (0, C_y + slope · depth, depth). Sub-frustum centres are these
    /// points, independent of the training augmentation (as in F-ConvNet, where the
    /// reference centres are not moved by the depth shift; the mirror keeps x = 0).
    pub fn ray_point(&self, depth: f64) -> [f64; 3] {
        let from_camera = depth + self.depth_origin;
        [0.0, self.origin[1] + self.ray_slope * from_camera, depth]
    }
}

/// The points of one frustum, before sampling.
#[derive(Debug, Clone)]
pub struct FrustumPoints {
    /// The 2D box clipped to the image.
    pub box2d: Box2d,
    /// The un-augmented frustum frame of the clipped box.
    pub frame: FrustumFrame,
    /// Every LiDAR point that projects into the clipped box with a frustum depth in
    /// the depth range, in the un-augmented frustum frame, in the frame's point order.
    pub points: Vec<[f64; 3]>,
}

impl FrustumPoints {
    /// The frustum, or [`SkipReason::NoPoints`] when `points` is empty.
    pub fn non_empty(
        box2d: Box2d,
        frame: FrustumFrame,
        points: Vec<[f64; 3]>,
    ) -> Result<FrustumPoints, SkipReason> {
        if points.is_empty() {
            return Err(SkipReason::NoPoints);
        }
        Ok(FrustumPoints {
            box2d,
            frame,
            points,
        })
    }
}

/// Clips a 2D box to the image `[0, width] × [0, height]`; `None` when nothing is left.
pub fn clip_box(b: &Box2d, image_size: [f64; 2]) -> Option<Box2d> {
    let c = Box2d {
        x1: b.x1.max(0.0),
        y1: b.y1.max(0.0),
        x2: b.x2.min(image_size[0]),
        y2: b.y2.min(image_size[1]),
    };
    (c.x2 > c.x1 && c.y2 > c.y1).then_some(c)
}

/// Extracts the frustum of a 2D box: clipped to the image (wholly outside →
/// [`SkipReason::OutsideImage`]), at least `min_height` pixels tall after clipping
/// (else [`SkipReason::TooSmall`]), and the points with u ∈ [x1, x2), v ∈ [y1, y2) and
/// frustum depth in `depth_range` (none → [`SkipReason::NoPoints`]).
pub fn extract_frustum(
    frame: &ProjectedFrame,
    box2d: &Box2d,
    depth_range: [f64; 2],
    min_height: f64,
) -> Result<FrustumPoints, SkipReason> {
    let b = clip_box(box2d, frame.image_size).ok_or(SkipReason::OutsideImage)?;
    if b.height() < min_height {
        return Err(SkipReason::TooSmall);
    }
    let ff = FrustumFrame::for_box(&frame.camera, &b);
    let mut points = Vec::new();
    for (r, uv) in frame.cloud.rect.iter().zip(&frame.cloud.uv) {
        if uv[0] >= b.x1 && uv[0] < b.x2 && uv[1] >= b.y1 && uv[1] < b.y2 {
            let q = ff.to_frustum(*r);
            if q[2] >= depth_range[0] && q[2] <= depth_range[1] {
                points.push(q);
            }
        }
    }
    FrustumPoints::non_empty(b, ff, points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_data::{sample_camera, sample_frame};
    use fusiondet_geometry::{alpha_from_ry, corners};
    use proptest::prelude::*;

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
    }

    #[test]
    fn image_projection_equals_to_rect_then_p2() {
        let cam = sample_camera();
        let ray = FrustumFrame::through_pixel(&cam, 300.0, 200.0);
        let cases = [(false, 0.0), (true, 0.0), (false, 1.3), (true, -0.7)];
        for (base, (mirrored, shift)) in [ray, ray.with_depth_origin(14.5)]
            .into_iter()
            .flat_map(|b| cases.map(|c| (b, c)))
        {
            let f = base.with_augmentation(mirrored, shift);
            let m = f.image_projection(&cam.p2_rows());
            for q in [[0.3, 0.8, 12.0], [-2.0, -1.0, 30.5], [1.0, 1.5, 4.0]] {
                let r = f.to_rect(q);
                let (u, v, depth) = cam.rect_to_image(r);
                assert!(depth > 0.0);
                let want = (u, v);
                let h: Vec<f64> = (0..3)
                    .map(|row| (0..3).map(|k| m[4 * row + k] * q[k]).sum::<f64>() + m[4 * row + 3])
                    .collect();
                let got = (h[0] / h[2], h[1] / h[2]);
                assert!(
                    (got.0 - want.0).abs() < 1e-9 && (got.1 - want.1).abs() < 1e-9,
                    "{got:?} vs {want:?} (mirrored {mirrored}, shift {shift})"
                );
            }
        }
    }

    #[test]
    fn box_centre_ray_is_the_depth_axis() {
        let cam = sample_camera();
        for (u, v) in [(100.0, 50.0), (620.0, 190.0), (1200.0, 360.0), (5.0, 370.0)] {
            let f = FrustumFrame::through_pixel(&cam, u, v);
            for depth in [0.5, 5.0, 40.0, 70.0] {
                // The rectified point that projects to (u, v) at this P2 depth.
                let p = cam.image_to_rect(u, v, depth);
                let q = f.to_frustum(p);
                assert!(q[0].abs() < 1e-9, "x {} at ({u},{v}) depth {depth}", q[0]);
                assert!(q[2] > 0.0);
                assert!(
                    close(f.ray_point(q[2]), q, 1e-9),
                    "{q:?} vs {:?}",
                    f.ray_point(q[2])
                );
                let (pu, pv, _) = cam.rect_to_image(f.to_rect(f.ray_point(depth)));
                assert!((pu - u).abs() < 1e-6 && (pv - v).abs() < 1e-6);
                // Moving the origin along the axis shifts depths and keeps the ray.
                let g = f.with_depth_origin(12.5);
                let r = g.to_frustum(p);
                assert!(close(r, [q[0], q[1], q[2] - 12.5], 1e-9), "{r:?} vs {q:?}");
                assert!(close(g.ray_point(r[2]), r, 1e-9));
                assert!(close(g.to_rect(r), p, 1e-9));
            }
        }
        // A box to the right of the image centre looks right: positive azimuth.
        assert!(FrustumFrame::through_pixel(&cam, 1000.0, 180.0).azimuth > 0.3);
    }

    #[test]
    fn heading_matches_alpha_for_a_box_on_the_ray() {
        // Put a box centre on the ray of a pixel: its frustum heading is the observation
        // angle, up to the 6 cm offset of P2's optical centre (negligible at 20 m).
        let cam = sample_camera();
        let f = FrustumFrame::through_pixel(&cam, 1000.0, 200.0);
        let c = cam.image_to_rect(1000.0, 200.0, 20.0);
        for ry in [-3.0, -1.2, 0.0, 0.7, 2.9] {
            let alpha = alpha_from_ry(ry, c[0], c[2]);
            let h = f.heading_to_frustum(ry);
            assert!(
                normalize_angle(h - alpha).abs() < 5e-3,
                "ry {ry}: {h} vs alpha {alpha}"
            );
        }
    }

    fn arb_frame() -> impl Strategy<Value = FrustumFrame> {
        (
            0.0..1242.0f64,
            0.0..375.0f64,
            any::<bool>(),
            -3.0..3.0f64,
            prop_oneof![Just(0.0), 0.0..40.0f64],
        )
            .prop_map(|(u, v, m, s, o)| {
                FrustumFrame::through_pixel(&sample_camera(), u, v)
                    .with_depth_origin(o)
                    .with_augmentation(m, s)
            })
    }

    fn arb_box() -> impl Strategy<Value = Box3d> {
        (
            -20.0..20.0f64,
            0.5..2.5f64,
            1.0..70.0f64,
            -4.0..4.0f64,
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
        fn frame_round_trips(f in arb_frame(), p in (-30.0..30.0f64, -3.0..3.0f64, 0.0..80.0f64)) {
            let p = [p.0, p.1, p.2];
            prop_assert!(close(f.to_rect(f.to_frustum(p)), p, 1e-9));
            let h = f.heading_to_frustum(0.3);
            prop_assert!(normalize_angle(f.heading_to_rect(h) - 0.3).abs() < 1e-12);
        }

        /// The heading convention is right iff transforming the corners point by point
        /// gives the corners of the transformed box (as a set: a mirror reverses their order).
        #[test]
        fn box_transform_moves_the_corners(f in arb_frame(), b in arb_box()) {
            let moved: Vec<[f64; 3]> = corners(&b).iter().map(|&c| f.to_frustum(c)).collect();
            let of_box = corners(&f.box_to_frustum(&b));
            for c in &moved {
                prop_assert!(of_box.iter().any(|d| close(*c, *d, 1e-9)), "{c:?} not in {of_box:?}");
            }
            if !f.mirrored {
                for k in 0..8 {
                    prop_assert!(close(moved[k], of_box[k], 1e-9));
                }
            }
            let back = f.box_to_rect(&f.box_to_frustum(&b));
            prop_assert!(close([back.x, back.y, back.z], [b.x, b.y, b.z], 1e-9));
            prop_assert!(normalize_angle(back.ry - b.ry).abs() < 1e-9);
        }
    }

    #[test]
    fn extraction_clips_and_skips() {
        let frame = sample_frame("000003");
        let range = [0.0, 70.0];
        let car = frame.objects[0].bbox;
        let fp = extract_frustum(&frame, &car, range, 25.0).unwrap();
        assert!(fp.points.len() > 300, "{}", fp.points.len());
        for (i, q) in fp.points.iter().enumerate() {
            assert!((0.0..=70.0).contains(&q[2]));
            let (u, v, _) = frame.camera.rect_to_image(fp.frame.to_rect(*q));
            assert!(
                u >= car.x1 - 1e-6 && u < car.x2 + 1e-6 && v >= car.y1 - 1e-6 && v < car.y2 + 1e-6,
                "{i}"
            );
        }
        // Every in-box point of the frame is there.
        let expected = frame
            .cloud
            .uv
            .iter()
            .zip(&frame.cloud.rect)
            .filter(|(uv, r)| {
                uv[0] >= car.x1
                    && uv[0] < car.x2
                    && uv[1] >= car.y1
                    && uv[1] < car.y2
                    && fp.frame.to_frustum(**r)[2] <= 70.0
            })
            .count();
        assert_eq!(fp.points.len(), expected);

        let partly = Box2d {
            x1: -50.0,
            y1: 150.0,
            x2: 60.0,
            y2: 300.0,
        };
        let clipped = extract_frustum(&frame, &partly, range, 0.0).map(|f| f.box2d);
        assert_eq!(clipped.map(|b| b.x1), Ok(0.0));
        let outside = Box2d {
            x1: -80.0,
            y1: 100.0,
            x2: -10.0,
            y2: 200.0,
        };
        assert_eq!(
            extract_frustum(&frame, &outside, range, 0.0).err(),
            Some(SkipReason::OutsideImage)
        );
        let low = Box2d {
            x1: 600.0,
            y1: 370.0,
            x2: 700.0,
            y2: 420.0,
        };
        assert_eq!(
            extract_frustum(&frame, &low, range, 25.0).err(),
            Some(SkipReason::TooSmall)
        );
        // The sky above the scan has no points.
        let sky = Box2d {
            x1: 600.0,
            y1: 0.0,
            x2: 640.0,
            y2: 40.0,
        };
        assert_eq!(
            extract_frustum(&frame, &sky, range, 5.0).err(),
            Some(SkipReason::NoPoints)
        );
    }
}
