//! Boxes in the LiDAR frame (x forward, y left, z up), the convention the voxel family
//! computes in (OpenPCDet's): centre (x, y, z), length `dx` along the heading, width
//! `dy`, height `dz`, and `heading` measured from the LiDAR x axis towards y.
//!
//! KITTI's labels are [`Box3d`]s in the rectified camera frame (bottom centre, h/w/l,
//! ry); [`LidarBox::from_camera`] / [`LidarBox::to_camera`] convert through a frame's
//! [`CameraModel`]: heading = −(ry + π/2) and the centre lifted by h/2 along LiDAR z.
//!
//! Overlaps: the rotated bird's-eye and 3D IoU by `geometry`'s exact convex clipping, and
//! the "nearest BEV" IoU of the anchor assignment (each box snapped to the axis-aligned
//! rectangle of its nearer axis, as OpenPCDet's `boxes3d_nearest_bev_iou`).

use fusiondet_geometry::iou::convex_intersection_area;
use fusiondet_geometry::{Box3d, CameraModel};
use fusiondet_kitti::{LidarPoint, ObjectClass};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// `value − floor(value / period + offset) · period`: wraps an angle into
/// [−offset·period, (1 − offset)·period). OpenPCDet's `limit_period`, used for headings
/// (offset 0.5, period 2π → [−π, π)), the direction bins and the nearest-BEV snapping.
pub fn limit_period(value: f64, offset: f64, period: f64) -> f64 {
    value - (value / period + offset).floor() * period
}

/// Rotates (x, y) by `angle` counter-clockwise about the origin (about LiDAR z).
pub fn rotate_z(p: [f64; 2], angle: f64) -> [f64; 2] {
    let (s, c) = (libm::sin(angle), libm::cos(angle));
    [c * p[0] - s * p[1], s * p[0] + c * p[1]]
}

/// A 3D box in the LiDAR frame (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct LidarBox {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    /// Length, along the heading.
    pub dx: f64,
    /// Width.
    pub dy: f64,
    /// Height.
    pub dz: f64,
    /// Angle of the length axis from LiDAR x towards y, radians.
    pub heading: f64,
}

/// A ground-truth box and its class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GtBox {
    pub bbox: LidarBox,
    pub class: ObjectClass,
}

/// An axis-aligned bird's-eye rectangle (x1, y1) – (x2, y2) in the LiDAR frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BevRect {
    pub x1: f64,
    pub y1: f64,
    pub x2: f64,
    pub y2: f64,
}

impl BevRect {
    pub fn area(&self) -> f64 {
        (self.x2 - self.x1) * (self.y2 - self.y1)
    }

    /// Intersection over union; the union is floored at 1e-6 as OpenPCDet's
    /// `boxes_iou_normal` does, so degenerate rectangles give 0, not NaN.
    pub fn iou(&self, other: &BevRect) -> f64 {
        let w = (self.x2.min(other.x2) - self.x1.max(other.x1)).max(0.0);
        let h = (self.y2.min(other.y2) - self.y1.max(other.y1)).max(0.0);
        let inter = w * h;
        inter / (self.area() + other.area() - inter).max(1e-6)
    }
}

impl LidarBox {
    /// The LiDAR-frame box of a KITTI label box. The heading is not wrapped (so that
    /// [`LidarBox::to_camera`] returns the label's ry); see [`LidarBox::wrapped`].
    pub fn from_camera(b: &Box3d, camera: &CameraModel) -> LidarBox {
        let [x, y, z] = camera.rect_to_velo([b.x, b.y, b.z]);
        LidarBox {
            x,
            y,
            z: z + b.h / 2.0,
            dx: b.l,
            dy: b.w,
            dz: b.h,
            heading: -(b.ry + FRAC_PI_2),
        }
    }

    /// The KITTI camera-frame box (bottom centre, ry) of this box.
    pub fn to_camera(&self, camera: &CameraModel) -> Box3d {
        let [x, y, z] = camera.velo_to_rect([self.x, self.y, self.z - self.dz / 2.0]);
        Box3d {
            h: self.dz,
            w: self.dy,
            l: self.dx,
            x,
            y,
            z,
            ry: -self.heading - FRAC_PI_2,
        }
    }

    /// `[x, y, z, dx, dy, dz, heading]`, OpenPCDet's 7-vector.
    pub fn to_array(&self) -> [f64; 7] {
        [
            self.x,
            self.y,
            self.z,
            self.dx,
            self.dy,
            self.dz,
            self.heading,
        ]
    }

    pub fn from_array(a: [f64; 7]) -> LidarBox {
        LidarBox {
            x: a[0],
            y: a[1],
            z: a[2],
            dx: a[3],
            dy: a[4],
            dz: a[5],
            heading: a[6],
        }
    }

    /// The same box with its heading wrapped into [−π, π) (what OpenPCDet does to the
    /// ground truth before targets are made).
    pub fn wrapped(&self) -> LidarBox {
        LidarBox {
            heading: limit_period(self.heading, 0.5, 2.0 * PI),
            ..*self
        }
    }

    pub fn bev_area(&self) -> f64 {
        self.dx * self.dy
    }

    pub fn volume(&self) -> f64 {
        self.dx * self.dy * self.dz
    }

    /// Half the bird's-eye diagonal: no point of the footprint is farther from the centre.
    pub fn bev_radius(&self) -> f64 {
        0.5 * (self.dx * self.dx + self.dy * self.dy).sqrt()
    }

    /// The footprint's corners in OpenPCDet's order: (+dx/2, +dy/2), (+dx/2, −dy/2),
    /// (−dx/2, −dy/2), (−dx/2, +dy/2) in the box frame, rotated by the heading.
    pub fn bev_corners(&self) -> [[f64; 2]; 4] {
        let (hx, hy) = (self.dx / 2.0, self.dy / 2.0);
        let (s, c) = (libm::sin(self.heading), libm::cos(self.heading));
        [[hx, hy], [hx, -hy], [-hx, -hy], [-hx, hy]]
            .map(|[u, v]| [self.x + c * u - s * v, self.y + s * u + c * v])
    }

    /// The eight corners: 0–3 the bottom face in [`LidarBox::bev_corners`]' order, 4–7
    /// the top face above them.
    pub fn corners(&self) -> [[f64; 3]; 8] {
        let bev = self.bev_corners();
        let (lo, hi) = (self.z - self.dz / 2.0, self.z + self.dz / 2.0);
        std::array::from_fn(|k| {
            let [x, y] = bev[k % 4];
            [x, y, if k < 4 { lo } else { hi }]
        })
    }

    /// The axis-aligned rectangle the anchor assignment compares: the heading snapped to
    /// the nearer of 0 and π/2 (modulo π), i.e. (dx, dy) when |heading mod π| < π/4,
    /// else (dy, dx), around the centre.
    pub fn nearest_bev(&self) -> BevRect {
        let rot = limit_period(self.heading, 0.5, PI).abs();
        let (ex, ey) = if rot < FRAC_PI_4 {
            (self.dx, self.dy)
        } else {
            (self.dy, self.dx)
        };
        BevRect {
            x1: self.x - ex / 2.0,
            y1: self.y - ey / 2.0,
            x2: self.x + ex / 2.0,
            y2: self.y + ey / 2.0,
        }
    }

    /// A point in the box's own frame: origin at the centre, x along the heading.
    pub fn to_local(&self, p: [f64; 3]) -> [f64; 3] {
        let [u, v] = rotate_z([p[0] - self.x, p[1] - self.y], -self.heading);
        [u, v, p[2] - self.z]
    }

    /// Whether `p` lies inside the box (faces included, as `geometry::points_in_box`).
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.contains_with(p, libm::sin(self.heading), libm::cos(self.heading))
    }

    fn contains_with(&self, p: [f64; 3], s: f64, c: f64) -> bool {
        if (p[2] - self.z).abs() > self.dz / 2.0 {
            return false;
        }
        let (ex, ey) = (p[0] - self.x, p[1] - self.y);
        // Rotation by −heading.
        let u = c * ex + s * ey;
        let v = -s * ex + c * ey;
        u.abs() <= self.dx / 2.0 && v.abs() <= self.dy / 2.0
    }
}

/// Which of the (x, y, z, intensity) points lie inside the box.
pub fn points_in_box(b: &LidarBox, points: &[LidarPoint]) -> Vec<bool> {
    let (s, c) = (libm::sin(b.heading), libm::cos(b.heading));
    points
        .iter()
        .map(|p| b.contains_with([p[0] as f64, p[1] as f64, p[2] as f64], s, c))
        .collect()
}

/// Whether the point lies inside any of the boxes (a bounding-circle test first, so the
/// cost is small when most points are far from every box).
pub fn in_any_box(boxes: &[LidarBox], p: [f64; 3]) -> bool {
    boxes.iter().any(|b| {
        let r = b.bev_radius();
        let (ex, ey) = (p[0] - b.x, p[1] - b.y);
        ex * ex + ey * ey <= r * r && b.contains(p)
    })
}

/// Bird's-eye intersection area of two rotated boxes (exact convex clipping).
pub fn bev_intersection(a: &LidarBox, b: &LidarBox) -> f64 {
    let (ex, ey) = (a.x - b.x, a.y - b.y);
    let r = a.bev_radius() + b.bev_radius();
    if ex * ex + ey * ey > r * r {
        return 0.0;
    }
    convex_intersection_area(&a.bev_corners(), &b.bev_corners())
}

fn ratio(inter: f64, a: f64, b: f64) -> f64 {
    let union = a + b - inter;
    if inter <= 0.0 || union <= 0.0 {
        0.0
    } else {
        (inter / union).clamp(0.0, 1.0)
    }
}

/// Rotated bird's-eye IoU.
pub fn iou_bev(a: &LidarBox, b: &LidarBox) -> f64 {
    ratio(bev_intersection(a, b), a.bev_area(), b.bev_area())
}

/// 3D IoU: bird's-eye intersection × overlap of the vertical extents.
pub fn iou_3d(a: &LidarBox, b: &LidarBox) -> f64 {
    let top = (a.z + a.dz / 2.0).min(b.z + b.dz / 2.0);
    let bottom = (a.z - a.dz / 2.0).max(b.z - b.dz / 2.0);
    if top <= bottom {
        return 0.0;
    }
    ratio(
        bev_intersection(a, b) * (top - bottom),
        a.volume(),
        b.volume(),
    )
}

/// IoU of the two boxes' [`LidarBox::nearest_bev`] rectangles.
pub fn nearest_bev_iou(a: &LidarBox, b: &LidarBox) -> f64 {
    a.nearest_bev().iou(&b.nearest_bev())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use fusiondet_geometry::corners as camera_corners;

    /// Frame 000000's P2, R0_rect and Tr_velo_to_cam (KITTI, CC BY-NC-SA 3.0).
    pub(crate) fn kitti_camera() -> CameraModel {
        CameraModel::new(
            &[
                [707.0493, 0.0, 604.0814, 45.75831],
                [0.0, 707.0493, 180.5066, -0.3454157],
                [0.0, 0.0, 1.0, 0.004981016],
            ],
            &[
                [0.9999128, 0.01009263, -0.008511932],
                [-0.01012729, 0.9999406, -0.004037671],
                [0.008470675, 0.004123522, 0.9999556],
            ],
            &[
                [0.006927964, -0.9999722, -0.002757829, -0.02457729],
                [-0.001162982, 0.002749836, -0.9999955, -0.06127237],
                [0.9999753, 0.006931141, -0.001143899, -0.3321029],
            ],
        )
        .unwrap()
    }

    /// The ideal axis permutation (rect x = −LiDAR y, rect y = −LiDAR z, rect z = LiDAR
    /// x), under which the two frames' boxes must have the same corners exactly.
    pub(crate) fn axis_camera() -> CameraModel {
        CameraModel::new(
            &[
                [700.0, 0.0, 600.0, 0.0],
                [0.0, 700.0, 180.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            &[
                [0.0, -1.0, 0.0, 0.0],
                [0.0, 0.0, -1.0, 0.0],
                [1.0, 0.0, 0.0, 0.0],
            ],
        )
        .unwrap()
    }

    pub(crate) fn lb(x: f64, y: f64, dx: f64, dy: f64, heading: f64) -> LidarBox {
        LidarBox {
            x,
            y,
            z: -1.0,
            dx,
            dy,
            dz: 1.5,
            heading,
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn camera_round_trip_is_exact() {
        let cam = kitti_camera();
        let label = Box3d {
            h: 1.67,
            w: 1.87,
            l: 3.69,
            x: -16.53,
            y: 2.39,
            z: 58.49,
            ry: 1.57,
        };
        let lidar = LidarBox::from_camera(&label, &cam);
        // LiDAR x is camera depth (to within the extrinsic's small offsets), heading
        // −(ry + π/2), dimensions renamed.
        assert!(close(lidar.x, 58.49, 0.5), "{lidar:?}");
        assert!(close(lidar.heading, -(1.57 + FRAC_PI_2), 1e-15));
        assert_eq!([lidar.dx, lidar.dy, lidar.dz], [3.69, 1.87, 1.67]);
        let back = lidar.to_camera(&cam);
        for (a, b) in [
            (back.x, label.x),
            (back.y, label.y),
            (back.z, label.z),
            (back.ry, label.ry),
        ] {
            assert!(close(a, b, 1e-12), "{back:?} vs {label:?}");
        }
        assert_eq!([back.h, back.w, back.l], [label.h, label.w, label.l]);
    }

    #[test]
    fn conversion_agrees_with_the_camera_corners() {
        // Under the ideal axis permutation, geometry's camera-frame corners mapped to
        // the LiDAR frame are this module's corners (as a set).
        let cam = axis_camera();
        for ry in [0.0, 0.4, -2.0, FRAC_PI_2] {
            let label = Box3d {
                h: 1.5,
                w: 1.6,
                l: 3.9,
                x: 2.0,
                y: 1.7,
                z: 15.0,
                ry,
            };
            let lidar = LidarBox::from_camera(&label, &cam);
            // Bottom at camera y = 1.7 (down) is LiDAR z = −1.7; centre 0.75 above.
            assert!(close(lidar.z, -1.7 + 0.75, 1e-12));
            let ours = lidar.corners();
            for c in camera_corners(&label) {
                let p = cam.rect_to_velo(c);
                let found = ours.iter().any(|q| (0..3).all(|k| close(p[k], q[k], 1e-9)));
                assert!(found, "ry {ry}: corner {p:?} not among {ours:?}");
            }
        }
    }

    #[test]
    fn ry_zero_points_along_minus_lidar_y() {
        // KITTI ry = 0 faces the camera's x axis (right), which is LiDAR −y.
        let lidar = LidarBox::from_camera(
            &Box3d {
                h: 1.0,
                w: 1.0,
                l: 4.0,
                x: 0.0,
                y: 0.0,
                z: 10.0,
                ry: 0.0,
            },
            &axis_camera(),
        );
        let [x, y] = rotate_z([1.0, 0.0], lidar.heading);
        assert!(close(x, 0.0, 1e-15) && close(y, -1.0, 1e-15));
    }

    #[test]
    fn limit_period_wraps_as_documented() {
        assert!(close(
            limit_period(3.0 * PI / 2.0, 0.5, 2.0 * PI),
            -PI / 2.0,
            1e-12
        ));
        assert!(close(limit_period(PI, 0.5, 2.0 * PI), -PI, 1e-12));
        assert!(close(limit_period(-0.1, 0.0, PI), PI - 0.1, 1e-12));
        assert!(close(limit_period(0.3, 0.5, PI), 0.3, 1e-15));
    }

    #[test]
    fn nearest_bev_snaps_to_the_nearer_axis() {
        let b = lb(10.0, 2.0, 4.0, 2.0, 0.3);
        assert_eq!(
            b.nearest_bev(),
            BevRect {
                x1: 8.0,
                y1: 1.0,
                x2: 12.0,
                y2: 3.0
            }
        );
        // 1.0 rad is past π/4: length along y. So is −π/2, and π − 0.3 is back near 0.
        for (h, along_x) in [(1.0, false), (-FRAC_PI_2, false), (PI - 0.3, true)] {
            let r = lb(0.0, 0.0, 4.0, 2.0, h).nearest_bev();
            assert_eq!(r.x2 - r.x1 == 4.0, along_x, "heading {h}: {r:?}");
        }
        // Shifted by 1 m along x: 3 × 2 overlap, union 8 + 8 − 6.
        let c = lb(11.0, 2.0, 4.0, 2.0, -0.2);
        assert!(close(nearest_bev_iou(&b, &c), 6.0 / 10.0, 1e-12));
        // Perpendicular snapped rectangles: a 2 × 2 cross-section, union 8 + 8 − 4.
        let d = lb(10.0, 2.0, 4.0, 2.0, 1.3);
        assert!(close(nearest_bev_iou(&b, &d), 4.0 / 12.0, 1e-12));
    }

    #[test]
    fn rotated_ious_by_hand() {
        let a = lb(0.0, 0.0, 2.0, 2.0, 0.0);
        let b = lb(1.0, 0.0, 2.0, 2.0, 0.0);
        assert!(close(iou_bev(&a, &b), 2.0 / 6.0, 1e-12));
        // A square and itself turned by 45°: an octagon of area 8(√2 − 1).
        let r = LidarBox {
            heading: FRAC_PI_4,
            ..a
        };
        let inter = 8.0 * (2f64.sqrt() - 1.0);
        assert!(close(iou_bev(&a, &r), inter / (8.0 - inter), 1e-12));
        // Half the height shared halves the 3D intersection: 0.5·V / (2V − 0.5·V).
        let up = LidarBox { z: a.z + 0.75, ..a };
        assert!(close(iou_3d(&a, &up), 0.5 / 1.5, 1e-12));
        // Heading by π is the same box; touching boxes and far boxes overlap by nothing.
        let flipped = LidarBox { heading: PI, ..a };
        assert!(close(iou_3d(&a, &flipped), 1.0, 1e-9));
        assert_eq!(iou_bev(&a, &lb(2.0, 0.0, 2.0, 2.0, 0.0)), 0.0);
        assert_eq!(iou_3d(&a, &LidarBox { z: 5.0, ..a }), 0.0);
        assert_eq!(iou_bev(&a, &lb(50.0, 0.0, 2.0, 2.0, 0.0)), 0.0);
    }

    #[test]
    fn points_in_box_respects_rotation_and_faces() {
        // A 4 × 2 box turned by 90°: its length runs along y.
        let b = LidarBox {
            x: 5.0,
            y: 0.0,
            z: 0.0,
            dx: 4.0,
            dy: 2.0,
            dz: 2.0,
            heading: FRAC_PI_2,
        };
        let pts: Vec<LidarPoint> = vec![
            [5.0, 1.9, 0.0, 0.0],  // inside along the length
            [5.0, 2.1, 0.0, 0.0],  // beyond the length
            [5.9, 0.0, 0.9, 0.0],  // inside across the width
            [6.1, 0.0, 0.0, 0.0],  // beyond the width
            [5.0, 0.0, -1.1, 0.0], // below
        ];
        assert_eq!(points_in_box(&b, &pts), [true, false, true, false, false]);
        assert!(in_any_box(
            &[lb(50.0, 0.0, 1.0, 1.0, 0.0), b],
            [5.0, 1.9, 0.0]
        ));
        assert!(!in_any_box(&[b], [5.0, 2.1, 0.0]));
        let local = b.to_local([5.0, 1.0, 0.5]);
        assert!(close(local[0], 1.0, 1e-12) && close(local[1], 0.0, 1e-12));
        assert!(close(local[2], 0.5, 1e-15));
    }
}
