//! Labels: the amodal upright box of every piece of furniture the camera sees, and its 2D
//! box — the eight projected corners' bounds clipped to the image, which is how the real
//! labels' 2D boxes relate to their 3D boxes (scene 000017's bed: its projected corners fall
//! within 13 px of the annotated box, which a person drew around the visible object).
//!
//! A piece is labelled when at least [`MIN_POINTS`] of the scene's written points lie on its
//! own parts (what stands on it does not count): with 50,000 points for a 640×480 frame that
//! is about 200 measured pixels, a 15-pixel square.

use super::layout::Placed;
use super::rgbd::RgbdCamera;
use crate::math::{Pose, V3, atan2};
use crate::scene::Scene;
use fusiondet_geometry::Box2d;
use fusiondet_sunrgbd::{Calib, Object, SunClass, UprightBox};

/// Points of its own a labelled piece needs among the scene's written points (for the
/// default 50,000; scaled with the count).
pub const MIN_POINTS: usize = 40;

/// One piece of furniture as the camera sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectView {
    /// Index into the frame's furniture.
    pub furniture: usize,
    pub class: SunClass,
    pub box3d: UprightBox,
    /// The projected box's bounds, not clipped (None when no corner is in front).
    pub projected: Option<Box2d>,
    /// The label's 2D box: `projected` clipped to the image.
    pub bbox: Option<Box2d>,
    /// Written points on its own parts, and inside its box (anything).
    pub own_points: usize,
    pub box_points: usize,
    /// Pixels (on a 2-pixel grid) where it is seen, and where it would be without occluders.
    pub visible_pixels: usize,
    pub silhouette_pixels: usize,
    pub labelled: bool,
}

impl ObjectView {
    /// Share of its silhouette hidden by nearer things.
    pub fn hidden(&self) -> f64 {
        if self.silhouette_pixels == 0 {
            return 1.0;
        }
        1.0 - (self.visible_pixels as f64 / self.silhouette_pixels as f64).min(1.0)
    }

    /// Share of the projected box's area outside the image.
    pub fn truncation(&self) -> f64 {
        match (self.projected, self.bbox) {
            (Some(p), Some(c)) => {
                let area = |b: &Box2d| (b.x2 - b.x1).max(0.0) * (b.y2 - b.y1).max(0.0);
                1.0 - area(&c) / area(&p).max(1e-9)
            }
            _ => 1.0,
        }
    }

    /// The label line's object (values rounded as the prepared files are).
    pub fn object(&self) -> Option<Object> {
        let bbox = self.bbox?;
        let r6 = |v: f64| (v * 1e6).round() / 1e6;
        let r2 = |v: f64| (v * 100.0).round() / 100.0;
        Some(Object {
            class: self.class.as_str().to_string(),
            box3d: UprightBox {
                centre: self.box3d.centre.map(r6),
                size: self.box3d.size.map(r6),
                yaw: r6(self.box3d.yaw),
            },
            bbox: Box2d {
                x1: r2(bbox.x1),
                y1: r2(bbox.y1),
                x2: r2(bbox.x2),
                y2: r2(bbox.y2),
            },
            score: None,
        })
    }
}

/// The upright box of a piece whose pose is already in the upright frame.
pub fn upright_box(p: &Placed) -> UprightBox {
    let f = p.pose.rot.cols[0];
    let c = p.pose.point(V3 {
        x: 0.0,
        y: 0.0,
        z: p.size[2] / 2.0,
    });
    UprightBox {
        centre: c.to_array(),
        size: p.size,
        yaw: atan2(f.y, f.x),
    }
}

/// The bounds of a box's projection (corners behind a near plane cut away), unclipped.
pub fn projected_bounds(calib: &Calib, b: &UprightBox) -> Option<Box2d> {
    const NEAR: f64 = 0.1;
    let m = &calib.depth_to_image;
    let row = |k: usize, p: &[f64; 3]| m[k][0] * p[0] + m[k][1] * p[1] + m[k][2] * p[2];
    let corners = b.corners();
    let w: Vec<f64> = corners.iter().map(|p| row(2, p)).collect();
    let mut pts: Vec<[f64; 3]> = corners
        .iter()
        .zip(&w)
        .filter(|(_, w)| **w >= NEAR)
        .map(|(p, _)| *p)
        .collect();
    // Edges of the box (corners i, j differ in one of: next around the footprint, or
    // bottom ↔ top) crossing the near plane.
    for i in 0..8 {
        for j in [(i + 1) % 4 + (i / 4) * 4, (i + 4) % 8] {
            if (w[i] - NEAR) * (w[j] - NEAR) < 0.0 {
                let t = (NEAR - w[i]) / (w[j] - w[i]);
                pts.push(std::array::from_fn(|k| {
                    corners[i][k] + t * (corners[j][k] - corners[i][k])
                }));
            }
        }
    }
    if pts.is_empty() {
        return None;
    }
    let (mut x1, mut y1, mut x2, mut y2) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in &pts {
        let wp = row(2, p).max(NEAR);
        let (u, v) = (row(0, p) / wp, row(1, p) / wp);
        x1 = x1.min(u);
        y1 = y1.min(v);
        x2 = x2.max(u);
        y2 = y2.max(v);
    }
    Some(Box2d { x1, y1, x2, y2 })
}

/// Clips to the image in the toolbox's 1-based pixel coordinates (pixel centres 1..=width).
pub fn clip(b: &Box2d, width: u32, height: u32) -> Option<Box2d> {
    let c = Box2d {
        x1: b.x1.max(1.0),
        y1: b.y1.max(1.0),
        x2: b.x2.min(width as f64),
        y2: b.y2.min(height as f64),
    };
    (c.x2 > c.x1 && c.y2 > c.y1).then_some(c)
}

/// The views of every piece of furniture: `furniture` in the upright frame, `owner` the
/// furniture index seen at each pixel, `points` the written points with `point_owner`.
#[allow(clippy::too_many_arguments)]
pub fn views(
    scene: &Scene,
    furniture: &[Placed],
    cam: &RgbdCamera,
    owner: &[u32],
    points: &[fusiondet_sunrgbd::Point],
    point_owner: &[u32],
    min_points: usize,
) -> Vec<ObjectView> {
    let calib = cam.calib();
    let (w, h) = (cam.width, cam.height);
    furniture
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let box3d = upright_box(p);
            let projected = projected_bounds(&calib, &box3d);
            let bbox = projected.and_then(|b| clip(&b, w, h));
            let own_points = point_owner.iter().filter(|&&o| o == i as u32).count();
            // Points inside the box, only near it (a cheap sphere test first).
            let c = box3d.centre;
            let r2 = 0.25 * box3d.size.iter().map(|v| v * v).sum::<f64>() + 0.01;
            let box_points = points
                .iter()
                .filter(|q| {
                    let d = [q[0] as f64 - c[0], q[1] as f64 - c[1], q[2] as f64 - c[2]];
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r2
                        && box3d.contains([q[0] as f64, q[1] as f64, q[2] as f64])
                })
                .count();
            let (mut visible, mut silhouette) = (0, 0);
            if let Some(b) = bbox
                && own_points >= min_points
            {
                let prims = &scene.prims[p.prims.clone()];
                // Pixel (col, row) sits at 1-based (col + 1, row + 1).
                let (c0, c1) = ((b.x1 - 1.0).max(0.0) as u32, (b.x2 - 1.0) as u32);
                let (r0, r1) = ((b.y1 - 1.0).max(0.0) as u32, (b.y2 - 1.0) as u32);
                for row in (r0..=r1.min(h - 1)).step_by(2) {
                    for col in (c0..=c1.min(w - 1)).step_by(2) {
                        let d = cam.ray(col, row);
                        if prims
                            .iter()
                            .any(|q| q.hit_interval(V3::ZERO, d, 0.0, f64::MAX).is_some())
                        {
                            silhouette += 1;
                            if owner[(row * w + col) as usize] == i as u32 {
                                visible += 1;
                            }
                        }
                    }
                }
            }
            ObjectView {
                furniture: i,
                class: p.class,
                box3d,
                projected,
                bbox,
                own_points,
                box_points,
                visible_pixels: visible,
                silhouette_pixels: silhouette,
                labelled: bbox.is_some() && own_points >= min_points,
            }
        })
        .collect()
}

/// Moves a room-frame pose into the upright camera frame.
pub fn to_upright(to_up: &Pose, p: &Placed) -> Placed {
    Placed {
        pose: Pose {
            rot: to_up.rot.mul(&p.pose.rot),
            t: to_up.point(p.pose.t),
        },
        ..p.clone()
    }
}
