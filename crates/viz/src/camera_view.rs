//! 3D boxes drawn on the camera image. Every edge is cut at a near plane in front of
//! the camera before it is projected, so a box reaching behind the camera shows the
//! part that is really in view instead of corners mirrored through the image centre.

use crate::draw::{Px, dashed_rect, line};
use crate::style::{DONT_CARE, LABEL_TEXT, Source};
use crate::text::{draw_label, label_rect};
use fusiondet_geometry::{CameraModel, clip_to_image, corners, projected_bounds};
use fusiondet_kitti::{Box3d, Object, ObjectClass};
use image::RgbImage;

use fusiondet_geometry::BOX_EDGES as EDGES;
/// Edges are cut at the geometry crate's near plane, so labels sit where the drawn box is.
pub use fusiondet_geometry::NEAR_PLANE;

/// The diagonals of the front face (corners 0, 1, 5, 4 lie at +l/2 along the heading):
/// an X there shows which way the box faces.
pub const FRONT_CROSS: [(usize, usize); 2] = [(0, 5), (1, 4)];

/// Projects the segment `a`–`b` (rectified camera frame) to pixels after cutting it at
/// [`NEAR_PLANE`]; `None` if it lies wholly behind.
pub fn project_segment(cam: &CameraModel, a: [f64; 3], b: [f64; 3]) -> Option<(Px, Px)> {
    let (a, b) = match (a[2] >= NEAR_PLANE, b[2] >= NEAR_PLANE) {
        (false, false) => return None,
        (true, true) => (a, b),
        (a_in, _) => {
            let t = (NEAR_PLANE - a[2]) / (b[2] - a[2]);
            let cut = [
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                NEAR_PLANE,
            ];
            if a_in { (a, cut) } else { (cut, b) }
        }
    };
    let (ua, va, _) = cam.rect_to_image(a);
    let (ub, vb, _) = cam.rect_to_image(b);
    Some(((ua, va), (ub, vb)))
}

/// Draws the wireframe of `b` with an X on its front face.
pub fn draw_box3d(
    img: &mut RgbImage,
    cam: &CameraModel,
    b: &Box3d,
    colour: image::Rgb<u8>,
    thickness: u32,
) {
    let c = corners(b);
    for (i, j) in EDGES {
        if let Some((p, q)) = project_segment(cam, c[i], c[j]) {
            line(img, p, q, colour, thickness);
        }
    }
    let cross = thickness.saturating_sub(1).max(1);
    for (i, j) in FRONT_CROSS {
        if let Some((p, q)) = project_segment(cam, c[i], c[j]) {
            line(img, p, q, colour, cross);
        }
    }
}

/// A placed label as (x, y, width, height), so later labels can keep clear of it.
pub type LabelRect = (i32, i32, u32, u32);

/// Pixels shared by two label rectangles.
fn overlap_area(a: &LabelRect, b: &LabelRect) -> i64 {
    let w = (a.0 + a.2 as i32).min(b.0 + b.2 as i32) - a.0.max(b.0);
    let h = (a.1 + a.3 as i32).min(b.1 + b.3 as i32) - a.1.max(b.1);
    w.max(0) as i64 * h.max(0) as i64
}

/// Draws `objects` as 3D boxes in the colour of `source`. DontCare entries are
/// skipped: they have no 3D box (see [`draw_dont_care`]).
pub fn draw_boxes(img: &mut RgbImage, cam: &CameraModel, objects: &[&Object], source: Source) {
    for o in objects.iter().filter(|o| o.class != ObjectClass::DontCare) {
        draw_box3d(img, cam, &o.box3d, source.colour(), source.thickness());
    }
}

/// The most labels one picture carries. Far fewer already cover the image; and since each
/// label is placed against every earlier one, a cap keeps a result file of 100,000 boxes
/// from taking minutes (the boxes themselves are all drawn).
pub const MAX_LABELS: usize = 256;

/// Draws the labels of `objects`: ground truth above its projected box, detections
/// below, so the two rarely collide. A label that would cover one in `placed` is
/// stacked further out (up for ground truth, down for detections): the first free
/// place of a few is taken, else the least covered. Every label drawn joins `placed`,
/// until it holds [`MAX_LABELS`].
pub fn draw_labels(
    img: &mut RgbImage,
    cam: &CameraModel,
    objects: &[&Object],
    source: Source,
    scale: u32,
    placed: &mut Vec<LabelRect>,
) {
    draw_labels_with(img, cam, objects, source, scale, placed, &|s, o| s.label(o));
}

/// [`draw_labels`] with the label text from `text` (e.g. class names KITTI's classes
/// do not have).
pub fn draw_labels_with(
    img: &mut RgbImage,
    cam: &CameraModel,
    objects: &[&Object],
    source: Source,
    scale: u32,
    placed: &mut Vec<LabelRect>,
    text: &dyn Fn(Source, &Object) -> String,
) {
    const TRIES: i32 = 6;
    let (w, h) = (img.width() as f64, img.height() as f64);
    for o in objects.iter().filter(|o| o.class != ObjectClass::DontCare) {
        if placed.len() >= MAX_LABELS {
            return;
        }
        let Some(bounds) = projected_bounds(&o.box3d, cam).and_then(|b| clip_to_image(&b, w, h))
        else {
            continue;
        };
        let text = text(source, o);
        let (_, _, _, label_h) = label_rect(img, 0, 0, &text, scale);
        let x = bounds.x1.round() as i32;
        let (base, step) = match source {
            Source::GroundTruth => (
                bounds.y1.round() as i32 - label_h as i32,
                -(label_h as i32 + 1),
            ),
            Source::Detection => (bounds.y2.round() as i32 + 1, label_h as i32 + 1),
        };
        // The first free place, else the one covering the least label area.
        let cover = |y: i32| {
            let r = label_rect(img, x, y, &text, scale);
            placed.iter().map(|p| overlap_area(p, &r)).sum::<i64>()
        };
        let y = (0..TRIES)
            .map(|k| base + k * step)
            .min_by_key(|&y| cover(y))
            .unwrap_or(base);
        placed.push(draw_label(
            img,
            x,
            y,
            &text,
            LABEL_TEXT,
            source.colour(),
            scale,
        ));
    }
}

/// Boxes, then labels on top, of one source.
pub fn draw_objects(
    img: &mut RgbImage,
    cam: &CameraModel,
    objects: &[&Object],
    source: Source,
    label_scale: u32,
) {
    draw_boxes(img, cam, objects, source);
    draw_labels(img, cam, objects, source, label_scale, &mut Vec::new());
}

/// Draws KITTI's DontCare regions as faint dashed 2D rectangles: they mark image areas
/// whose objects were not labelled, so a detection there is neither right nor wrong.
pub fn draw_dont_care(img: &mut RgbImage, objects: &[Object]) {
    for o in objects.iter().filter(|o| o.class == ObjectClass::DontCare) {
        let b = &o.bbox;
        dashed_rect(img, (b.x1, b.y1), (b.x2, b.y2), DONT_CARE, 4, 0.7);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::style::{DETECTION, GT};
    use crate::testutil::{camera, count_colour};

    fn car(z: f64) -> Box3d {
        Box3d {
            h: 1.5,
            w: 1.6,
            l: 3.9,
            x: 0.0,
            y: 1.7,
            z,
            ry: 0.0,
        }
    }

    fn object(b: Box3d, score: Option<f64>) -> Object {
        Object {
            class: ObjectClass::Car,
            truncation: 0.0,
            occlusion: 0,
            alpha: 0.0,
            bbox: Default::default(),
            box3d: b,
            score,
        }
    }

    #[test]
    fn box_ahead_colours_its_projected_corners_and_nothing_far_away() {
        let cam = camera();
        let mut img = RgbImage::new(1242, 375);
        let b = car(15.0);
        draw_box3d(&mut img, &cam, &b, GT, 3);
        for p in corners(&b) {
            let (u, v, _) = cam.rect_to_image(p);
            assert_eq!(
                *img.get_pixel(u.round() as u32, v.round() as u32),
                GT,
                "corner ({u}, {v})"
            );
        }
        let bounds = projected_bounds(&b, &cam).unwrap();
        for (x, y, p) in img.enumerate_pixels() {
            if *p == GT {
                let (x, y) = (x as f64, y as f64);
                assert!(x >= bounds.x1 - 3.0 && x <= bounds.x2 + 3.0, "{x}");
                assert!(y >= bounds.y1 - 3.0 && y <= bounds.y2 + 3.0, "{y}");
            }
        }
        // The front-face X crosses the centre of the front face.
        let c = corners(&b);
        let centre = [
            (c[0][0] + c[5][0]) / 2.0,
            (c[0][1] + c[5][1]) / 2.0,
            (c[0][2] + c[5][2]) / 2.0,
        ];
        let (u, v, _) = cam.rect_to_image(centre);
        assert_eq!(*img.get_pixel(u.round() as u32, v.round() as u32), GT);
    }

    #[test]
    fn box_behind_the_camera_draws_nothing() {
        let cam = camera();
        let mut img = RgbImage::new(1242, 375);
        draw_box3d(&mut img, &cam, &car(-10.0), GT, 3);
        assert_eq!(count_colour(&img, GT), 0);
    }

    #[test]
    fn box_straddling_the_camera_is_cut_not_mirrored() {
        // A long box beside the camera from 3 m behind to 9 m ahead, on the right (x > 0).
        let cam = camera();
        let mut img = RgbImage::new(1242, 375);
        let b = Box3d {
            h: 1.5,
            w: 2.0,
            l: 12.0,
            x: 3.0,
            y: 1.7,
            z: 3.0,
            ry: std::f64::consts::FRAC_PI_2,
        };
        draw_box3d(&mut img, &cam, &b, GT, 1);
        let n = count_colour(&img, GT);
        assert!(n > 0, "the visible part is drawn");
        // Mirrored corners would land on the left half; a box wholly on the right
        // may only colour the right half (plus the principal point's column).
        let cu = cam.cu();
        for (x, _, p) in img.enumerate_pixels() {
            if *p == GT {
                assert!(x as f64 >= cu - 1.0, "pixel at x = {x} left of cu = {cu}");
            }
        }
    }

    #[test]
    fn colliding_labels_are_stacked_apart() {
        let cam = camera();
        let mut img = RgbImage::new(1242, 375);
        let a = object(car(15.0), Some(0.9));
        let b = object(
            Box3d {
                x: 0.2,
                ..car(15.0)
            },
            Some(0.8),
        );
        let mut placed = Vec::new();
        draw_labels(&mut img, &cam, &[&a, &b], Source::Detection, 1, &mut placed);
        assert_eq!(placed.len(), 2);
        assert_eq!(overlap_area(&placed[0], &placed[1]), 0, "{placed:?}");
        assert!(placed[1].1 > placed[0].1, "the second goes below the first");
    }

    #[test]
    fn a_crowd_of_boxes_gets_at_most_max_labels() {
        let cam = camera();
        let mut img = RgbImage::new(1242, 375);
        let crowd: Vec<Object> = (0..5_000)
            .map(|i| {
                let b = Box3d {
                    x: -5.0 + (i % 100) as f64 * 0.1,
                    ..car(10.0 + (i / 100) as f64 * 0.5)
                };
                object(b, Some(0.5))
            })
            .collect();
        let refs: Vec<&Object> = crowd.iter().collect();
        let mut placed = Vec::new();
        draw_labels(&mut img, &cam, &refs, Source::Detection, 1, &mut placed);
        assert_eq!(placed.len(), MAX_LABELS);
    }

    #[test]
    fn labels_name_class_and_score_in_the_source_colour() {
        let cam = camera();
        let mut img = RgbImage::new(1242, 375);
        let gt = object(car(15.0), None);
        let det = object(
            Box3d {
                x: 0.3,
                ..car(15.0)
            },
            Some(0.87),
        );
        draw_objects(&mut img, &cam, &[&gt], Source::GroundTruth, 1);
        draw_objects(&mut img, &cam, &[&det], Source::Detection, 1);
        assert!(count_colour(&img, GT) > 100);
        assert!(count_colour(&img, DETECTION) > 100);
        assert_eq!(Source::Detection.label(&det), "Car 0.87");
        let ped = Object {
            class: ObjectClass::Pedestrian,
            ..det.clone()
        };
        assert_eq!(Source::Detection.label(&ped), "Ped 0.87");
        assert_eq!(Source::GroundTruth.label(&gt), "Car");
    }
}
