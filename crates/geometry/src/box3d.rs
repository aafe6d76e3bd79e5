//! 3D boxes in KITTI's camera convention: corners, bird's-eye footprints,
//! projection to the image, and the alpha ↔ rotation_y relation.

use crate::boxes::{Box2d, Box3d};
use crate::camera::CameraModel;
use std::f64::consts::PI;

/// Wraps an angle to (-pi, pi].
pub fn normalize_angle(a: f64) -> f64 {
    let mut a = a % (2.0 * PI);
    if a > PI {
        a -= 2.0 * PI;
    } else if a <= -PI {
        a += 2.0 * PI;
    }
    a
}

/// Observation angle from rotation_y and the box centre (x, z): alpha = ry − atan2(x, z).
pub fn alpha_from_ry(ry: f64, x: f64, z: f64) -> f64 {
    normalize_angle(ry - x.atan2(z))
}

/// rotation_y from the observation angle and the box centre (x, z).
pub fn ry_from_alpha(alpha: f64, x: f64, z: f64) -> f64 {
    normalize_angle(alpha + x.atan2(z))
}

/// The 12 edges of a box over [`corners`]' numbering (0–3 bottom, 4–7 top).
pub const BOX_EDGES: [(usize, usize); 12] = [
    (0, 1),
    (1, 2),
    (2, 3),
    (3, 0),
    (4, 5),
    (5, 6),
    (6, 7),
    (7, 4),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// Depth (rectified camera z, metres) at which box edges are cut before projection.
pub const NEAR_PLANE: f64 = 0.1;

/// The eight corners in the rectified camera frame. Corners 0–3 are the bottom face
/// (y = box.y), 4–7 the top face, both counter-clockwise seen from above. The rotation
/// uses `libm`'s sine and cosine (not the platform's), so corners, projected boxes and
/// everything built on them are bit-identical on every machine.
pub fn corners(b: &Box3d) -> [[f64; 3]; 8] {
    let (s, c) = (libm::sin(b.ry), libm::cos(b.ry));
    let xs = [b.l / 2.0, b.l / 2.0, -b.l / 2.0, -b.l / 2.0];
    let zs = [b.w / 2.0, -b.w / 2.0, -b.w / 2.0, b.w / 2.0];
    let mut out = [[0.0; 3]; 8];
    for k in 0..4 {
        // Rotation about y: x' = c·x + s·z, z' = −s·x + c·z.
        let x = c * xs[k] + s * zs[k] + b.x;
        let z = -s * xs[k] + c * zs[k] + b.z;
        out[k] = [x, b.y, z];
        out[k + 4] = [x, b.y - b.h, z];
    }
    out
}

/// The box's bird's-eye footprint as a polygon in the (x, z) plane.
pub fn bev_polygon(b: &Box3d) -> [[f64; 2]; 4] {
    let c = corners(b);
    [
        [c[0][0], c[0][2]],
        [c[1][0], c[1][2]],
        [c[2][0], c[2][2]],
        [c[3][0], c[3][2]],
    ]
}

/// The image extent of the box's projection, not clipped to the image, or `None` if
/// the box lies wholly behind the camera. Edges crossing the near plane (depth 0.1 m)
/// are cut there, so a box straddling the image plane still gets a proper extent.
pub fn projected_bounds(b: &Box3d, cam: &CameraModel) -> Option<Box2d> {
    const NEAR: f64 = NEAR_PLANE;
    let c = corners(b);
    let mut pts: Vec<[f64; 3]> = c.iter().copied().filter(|p| p[2] >= NEAR).collect();
    for (i, j) in BOX_EDGES {
        let (a, b) = (c[i], c[j]);
        if (a[2] - NEAR) * (b[2] - NEAR) < 0.0 {
            let t = (NEAR - a[2]) / (b[2] - a[2]);
            pts.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), NEAR]);
        }
    }
    if pts.is_empty() {
        return None;
    }
    let mut out = Box2d {
        x1: f64::MAX,
        y1: f64::MAX,
        x2: f64::MIN,
        y2: f64::MIN,
    };
    for p in pts {
        let (u, v, _) = cam.rect_to_image(p);
        out.x1 = out.x1.min(u);
        out.y1 = out.y1.min(v);
        out.x2 = out.x2.max(u);
        out.y2 = out.y2.max(v);
    }
    Some(out)
}

/// Clips a 2D box to a `width`×`height` image (pixel centres 0..width−1), or `None`
/// if nothing of it is left.
pub fn clip_to_image(b: &Box2d, width: f64, height: f64) -> Option<Box2d> {
    let clipped = Box2d {
        x1: b.x1.max(0.0),
        y1: b.y1.max(0.0),
        x2: b.x2.min(width - 1.0),
        y2: b.y2.min(height - 1.0),
    };
    (clipped.x2 > clipped.x1 && clipped.y2 > clipped.y1).then_some(clipped)
}

/// The 2D box of the projected 3D box clipped to the image, as in KITTI's labels.
pub fn project_to_image(b: &Box3d, cam: &CameraModel, width: f64, height: f64) -> Option<Box2d> {
    clip_to_image(&projected_bounds(b, cam)?, width, height)
}

/// Which of `points` (rectified camera frame) lie inside the box (faces included).
pub fn points_in_box(b: &Box3d, points: &[[f64; 3]]) -> Vec<bool> {
    let (s, c) = b.ry.sin_cos();
    points
        .iter()
        .map(|p| {
            let dx = p[0] - b.x;
            let dz = p[2] - b.z;
            // Inverse rotation of `corners`.
            let lx = c * dx - s * dz;
            let lz = s * dx + c * dz;
            lx.abs() <= b.l / 2.0 && lz.abs() <= b.w / 2.0 && p[1] <= b.y && p[1] >= b.y - b.h
        })
        .collect()
}

/// Counts the points inside the box.
pub fn count_points_in_box(b: &Box3d, points: &[[f64; 3]]) -> usize {
    points_in_box(b, points).into_iter().filter(|&x| x).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::tests::sample_camera;

    fn car() -> Box3d {
        Box3d {
            h: 1.5,
            w: 1.6,
            l: 3.9,
            x: 2.0,
            y: 1.7,
            z: 15.0,
            ry: 0.3,
        }
    }

    #[test]
    fn alpha_ry_round_trip_matches_kitti_label() {
        // 000001 Cyclist: x 4.59, z 45.84, ry -1.55, alpha -1.65.
        let a = alpha_from_ry(-1.55, 4.59, 45.84);
        assert!((a - -1.65).abs() < 0.005, "{a}");
        assert!((ry_from_alpha(a, 4.59, 45.84) - -1.55).abs() < 1e-12);
    }

    #[test]
    fn corners_have_the_box_dimensions() {
        let c = corners(&car());
        let d = |i: usize, j: usize| {
            ((c[i][0] - c[j][0]).powi(2)
                + (c[i][1] - c[j][1]).powi(2)
                + (c[i][2] - c[j][2]).powi(2))
            .sqrt()
        };
        assert!((d(0, 1) - 1.6).abs() < 1e-12);
        assert!((d(1, 2) - 3.9).abs() < 1e-12);
        assert!((d(0, 4) - 1.5).abs() < 1e-12);
        // ry = 0 puts the length along the camera x axis.
        let b = Box3d { ry: 0.0, ..car() };
        let c = corners(&b);
        assert!((c[0][0] - c[3][0] - 3.9).abs() < 1e-12);
    }

    #[test]
    fn points_in_box_respects_faces_and_rotation() {
        let b = car();
        let (s, c) = b.ry.sin_cos();
        // A point 1.9 m along the length axis is inside, 2.0 m is not.
        let along = |t: f64| [b.x + c * t, b.y - 0.5, b.z - s * t];
        let inside = points_in_box(
            &b,
            &[
                along(1.9),
                along(2.0),
                [b.x, b.y + 0.01, b.z],
                [b.x, b.y - 1.4, b.z],
            ],
        );
        assert_eq!(inside, [true, false, false, true]);
    }

    #[test]
    fn projection_matches_kitti_label_box() {
        // KITTI 000001 Car: 387.63 181.54 423.81 203.12, dims 1.67 1.87 3.69, loc -16.53 2.39 58.49,
        // ry 1.57, with that frame's P2 (only P2 matters in the rectified frame).
        let mut cam = sample_camera();
        cam.p2 = nalgebra::Matrix3x4::from_row_slice(&[
            721.5377,
            0.0,
            609.5593,
            44.85728, //
            0.0,
            721.5377,
            172.854,
            0.2163791, //
            0.0,
            0.0,
            1.0,
            0.002745884,
        ]);
        let b = Box3d {
            h: 1.67,
            w: 1.87,
            l: 3.69,
            x: -16.53,
            y: 2.39,
            z: 58.49,
            ry: 1.57,
        };
        let p = project_to_image(&b, &cam, 1242.0, 375.0).unwrap();
        assert!(
            (p.x1 - 387.63).abs() < 1.0 && (p.x2 - 423.81).abs() < 1.0,
            "{p:?}"
        );
        assert!(
            (p.y1 - 181.54).abs() < 1.0 && (p.y2 - 203.12).abs() < 1.0,
            "{p:?}"
        );
    }

    #[test]
    fn box_behind_camera_projects_to_nothing() {
        let cam = sample_camera();
        let b = Box3d { z: -10.0, ..car() };
        assert!(project_to_image(&b, &cam, 1242.0, 375.0).is_none());
    }
}
