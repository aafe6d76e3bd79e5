//! KITTI labels from the rendered frame.
//!
//! * Box: the actor's box in the rectified camera frame (location = bottom centre,
//!   rotation_y from its heading), 2D box = projection of the 3D box clipped to the
//!   image, alpha from rotation_y and the location.
//! * Truncation: the fraction of the projected 3D box's area outside the image.
//! * Occlusion: from the id image. The object's own silhouette is rendered alone
//!   (rays against its parts only) inside its 2D box; the hidden fraction is the
//!   share of those pixels where the full render shows something else. Levels:
//!   hidden < [`OCC_PARTLY`] → 0 (fully visible), < [`OCC_LARGELY`] → 1 (partly
//!   occluded), < [`OCC_UNKNOWN`] → 2 (largely occluded), else 3.
//! * Objects annotators could not see (fewer than [`MIN_VISIBLE_PX`] visible pixels)
//!   are left out, as in KITTI. Objects farther than [`MAX_LABEL_DEPTH`] or whose 2D
//!   box is lower than [`MIN_LABEL_HEIGHT_PX`] become DontCare regions (their
//!   visible pixel box), like KITTI's far, tiny objects, if at least
//!   [`MIN_DONTCARE_PX`] of them show and they are within [`MAX_DONTCARE_DEPTH`].

use crate::camera::{PixelRays, Render};
use crate::math::{V3, atan2};
use crate::scene::{Actor, Scene};
use fusiondet_geometry::{CameraModel, clip_to_image, normalize_angle};
use fusiondet_kitti::{Box2d, Box3d, Object, ObjectClass};
use rayon::prelude::*;

pub const OCC_PARTLY: f64 = 0.10;
pub const OCC_LARGELY: f64 = 0.60;
pub const OCC_UNKNOWN: f64 = 0.90;
pub const MIN_VISIBLE_PX: f64 = 30.0;
pub const MAX_LABEL_DEPTH: f64 = 80.0;
pub const MIN_LABEL_HEIGHT_PX: f64 = 18.0;
/// DontCare regions need a little more to see, and nothing beyond this is annotated.
pub const MIN_DONTCARE_PX: f64 = 60.0;
pub const MAX_DONTCARE_DEPTH: f64 = 110.0;

/// How one actor appears in the image, labelled or not.
#[derive(Debug, Clone, PartialEq)]
pub struct ActorView {
    pub actor: usize,
    pub class: ObjectClass,
    /// The label line written for this actor, if any (a real class or DontCare).
    pub label: Option<Object>,
    /// The 3D box in the rectified camera frame.
    pub box3d: Box3d,
    /// The 2D box (clipped projection), if the box projects into the image.
    pub bbox: Option<Box2d>,
    pub truncation: f64,
    /// The box of the object's visible pixels.
    pub visible_bbox: Option<Box2d>,
    /// Fraction of the in-image silhouette hidden by nearer surfaces.
    pub hidden: f64,
    /// Visible / own silhouette pixel counts (full-resolution equivalents).
    pub visible_px: f64,
    pub own_px: f64,
    /// LiDAR points inside the 3D box (filled in by the frame assembly).
    pub points_in_box: usize,
}

impl ActorView {
    pub fn is_labelled(&self) -> bool {
        self.label
            .as_ref()
            .is_some_and(|o| o.class != ObjectClass::DontCare)
    }
    pub fn is_dontcare(&self) -> bool {
        self.label
            .as_ref()
            .is_some_and(|o| o.class == ObjectClass::DontCare)
    }
}

/// The occlusion level of a hidden fraction.
pub fn occlusion_level(hidden: f64) -> i32 {
    if hidden < OCC_PARTLY {
        0
    } else if hidden < OCC_LARGELY {
        1
    } else if hidden < OCC_UNKNOWN {
        2
    } else {
        3
    }
}

/// The actor's KITTI box in the rectified camera frame.
pub fn actor_box3d(a: &Actor, cam: &CameraModel) -> Box3d {
    let loc = cam.velo_to_rect(a.bottom_center.to_array());
    let o = cam.velo_to_rect([0.0; 3]);
    let tip = cam.velo_to_rect(a.heading.to_array());
    let d = V3::from_array(tip) - V3::from_array(o);
    // corners(): the length axis is (cos ry, 0, −sin ry) in (x, y, z).
    let ry = atan2(-d.z, d.x);
    Box3d {
        h: a.h,
        w: a.w,
        l: a.l,
        x: loc[0],
        y: loc[1],
        z: loc[2],
        ry,
    }
}

fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// Computes views (and labels) for every actor that shows in the image.
pub fn label_frame(scene: &Scene, cam: &CameraModel, render: &Render) -> Vec<ActorView> {
    let (w, h) = (render.width as f64, render.height as f64);
    let rays = PixelRays::new(cam);
    // Objects are independent: view them in parallel (collected in actor order).
    (0..scene.actors.len())
        .into_par_iter()
        .filter_map(|index| {
            let actor = &scene.actors[index];
            let box3d = actor_box3d(actor, cam);
            if box3d.z < 0.3 {
                // Centre behind (or at) the camera: KITTI labels only what is in front.
                return None;
            }
            let full = fusiondet_geometry::projected_bounds(&box3d, cam)?;
            let clipped = clip_to_image(&full, w, h)?;
            let area = |b: &Box2d| (b.x2 - b.x1).max(0.0) * (b.y2 - b.y1).max(0.0);
            let truncation = if area(&full) > 0.0 {
                (1.0 - area(&clipped) / area(&full)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            // Silhouette alone vs what the full render shows, on a grid whose stride keeps
            // the ray count bounded for big near objects.
            let (x0, y0) = (clipped.x1.floor() as u32, clipped.y1.floor() as u32);
            let (x1, y1) = (
                (clipped.x2.ceil() as u32).min(render.width - 1),
                (clipped.y2.ceil() as u32).min(render.height - 1),
            );
            let box_px = ((x1 - x0 + 1) * (y1 - y0 + 1)) as f64;
            let stride = if box_px > 40_000.0 {
                3
            } else if box_px > 10_000.0 {
                2
            } else {
                1
            };
            let (mut own, mut vis) = (0usize, 0usize);
            let (mut vx1, mut vy1, mut vx2, mut vy2) = (u32::MAX, u32::MAX, 0u32, 0u32);
            let mut v = y0;
            while v <= y1 {
                let mut u = x0;
                while u <= x1 {
                    let d = rays.dir(u as f64, v as f64);
                    if scene.hits_actor(index, rays.origin, d, 400.0) {
                        own += 1;
                        let seen = render.prim_at(u, v);
                        if seen != crate::camera::SKY && scene.owner(seen) == Some(index) {
                            vis += 1;
                            vx1 = vx1.min(u);
                            vy1 = vy1.min(v);
                            vx2 = vx2.max(u);
                            vy2 = vy2.max(v);
                        }
                    }
                    u += stride;
                }
                v += stride;
            }
            let scale = (stride * stride) as f64;
            let (own_px, visible_px) = (own as f64 * scale, vis as f64 * scale);
            if own == 0 {
                return None;
            }
            let hidden = 1.0 - vis as f64 / own as f64;
            let s = stride.saturating_sub(1) as f64;
            let visible_bbox = (vis > 0).then(|| Box2d {
                x1: vx1 as f64,
                y1: vy1 as f64,
                x2: (vx2 as f64 + s).min(w - 1.0),
                y2: (vy2 as f64 + s).min(h - 1.0),
            });
            let mut view = ActorView {
                actor: index,
                class: actor.class,
                label: None,
                box3d,
                bbox: Some(clipped),
                visible_bbox,
                truncation,
                hidden,
                visible_px,
                own_px,
                points_in_box: 0,
            };
            if visible_px >= MIN_VISIBLE_PX {
                let too_small = clipped.y2 - clipped.y1 < MIN_LABEL_HEIGHT_PX;
                if box3d.z > MAX_LABEL_DEPTH || too_small {
                    if visible_px >= MIN_DONTCARE_PX && box3d.z <= MAX_DONTCARE_DEPTH {
                        view.label = visible_bbox.map(dontcare);
                    }
                } else {
                    view.label = Some(Object {
                        class: actor.class,
                        truncation: round2(truncation),
                        occlusion: occlusion_level(hidden),
                        alpha: normalize_angle(box3d.ry - atan2(box3d.x, box3d.z)),
                        bbox: clipped,
                        box3d,
                        score: None,
                    });
                }
            }
            Some(view)
        })
        .collect()
}

/// A DontCare line covering `bbox`.
pub fn dontcare(bbox: Box2d) -> Object {
    Object {
        class: ObjectClass::DontCare,
        truncation: -1.0,
        occlusion: -1,
        alpha: -10.0,
        bbox,
        box3d: Box3d {
            h: -1.0,
            w: -1.0,
            l: -1.0,
            x: -1000.0,
            y: -1000.0,
            z: -1000.0,
            ry: -10.0,
        },
        score: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occlusion_levels_follow_the_thresholds() {
        assert_eq!(occlusion_level(0.0), 0);
        assert_eq!(occlusion_level(0.09), 0);
        assert_eq!(occlusion_level(0.1), 1);
        assert_eq!(occlusion_level(0.5), 1);
        assert_eq!(occlusion_level(0.7), 2);
        assert_eq!(occlusion_level(0.95), 3);
    }

    #[test]
    fn alpha_matches_the_geometry_crate() {
        let a = normalize_angle(-1.55 - atan2(4.59, 45.84));
        assert!((a - fusiondet_geometry::alpha_from_ry(-1.55, 4.59, 45.84)).abs() < 1e-12);
    }

    #[test]
    fn actor_box_matches_kitti_conventions() {
        use crate::math::{V3, v3};
        use fusiondet_kitti::Calib;
        // Identity-like extrinsics: LiDAR x → camera z, LiDAR y → −camera x, z → −y.
        let calib = Calib {
            p: [[
                [700.0, 0.0, 600.0, 0.0],
                [0.0, 700.0, 180.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ]; 4],
            r0_rect: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            tr_velo_to_cam: [
                [0.0, -1.0, 0.0, 0.0],
                [0.0, 0.0, -1.0, 0.0],
                [1.0, 0.0, 0.0, 0.0],
            ],
            tr_imu_to_velo: [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
        };
        let cam = calib.camera_model().unwrap();
        let actor = Actor {
            class: ObjectClass::Car,
            bottom_center: v3(20.0, 2.0, -1.73),
            heading: V3::X,
            up: V3::Z,
            l: 4.0,
            w: 1.6,
            h: 1.5,
            prims: 0..0,
            parked: false,
        };
        let b = actor_box3d(&actor, &cam);
        assert!(
            (b.x + 2.0).abs() < 1e-12 && (b.y - 1.73).abs() < 1e-12 && (b.z - 20.0).abs() < 1e-12
        );
        // Driving away from the camera (along its z axis): ry = −π/2 in KITTI.
        assert!(
            (b.ry + std::f64::consts::FRAC_PI_2).abs() < 1e-12,
            "{}",
            b.ry
        );
        // Facing left (LiDAR +y = camera −x): ry = π.
        let left = Actor {
            heading: V3::Y,
            ..actor
        };
        let b = actor_box3d(&left, &cam);
        assert!(
            (b.ry.abs() - std::f64::consts::PI).abs() < 1e-12,
            "{}",
            b.ry
        );
    }
}
