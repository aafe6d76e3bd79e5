//! The bird's-eye view: a metric top-down map in the rectified camera frame (x right,
//! z forward) with the ego camera at the bottom centre and forward up, so that left
//! and right match the camera image drawn above it.

use crate::draw::{Px, dashed_line, fill_rect, line, polygon};
use crate::style::{self, EGO, GRID, Source, TEXT};
use crate::text::{draw_text, text_size};
use fusiondet_geometry::{CameraModel, bev_polygon};
use fusiondet_kitti::{LidarPoint, Object, ObjectClass};
use image::{Rgb, RgbImage};
use imageproc::drawing::draw_polygon_mut;
use imageproc::point::Point;

/// The area shown, in metres of the rectified camera frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BevRange {
    /// Nearest and farthest distance ahead (z).
    pub forward: (f64, f64),
    /// Leftmost and rightmost offset (x, right positive).
    pub lateral: (f64, f64),
}

impl Default for BevRange {
    /// 0–70 m ahead × ±40 m: KITTI labels objects up to about 70 m, and ±40 m keeps
    /// the aspect close to that of a detection paper's figure.
    fn default() -> Self {
        BevRange {
            forward: (0.0, 70.0),
            lateral: (-40.0, 40.0),
        }
    }
}

/// Where metres land in a BEV picture of a given width (isotropic scale, so rotated
/// boxes keep their shape).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BevMap {
    pub range: BevRange,
    pub px_per_m: f64,
    pub width: u32,
    pub height: u32,
}

impl BevMap {
    /// A map `width` pixels wide; the height follows from the range's aspect.
    pub fn new(range: BevRange, width: u32) -> BevMap {
        let px_per_m = width as f64 / (range.lateral.1 - range.lateral.0);
        let height = ((range.forward.1 - range.forward.0) * px_per_m)
            .round()
            .max(1.0) as u32;
        BevMap {
            range,
            px_per_m,
            width,
            height,
        }
    }

    /// Continuous pixel coordinates (pixel centres at integers) of ground point (x, z).
    pub fn to_pixel(&self, x: f64, z: f64) -> Px {
        (
            (x - self.range.lateral.0) * self.px_per_m - 0.5,
            (self.range.forward.1 - z) * self.px_per_m - 0.5,
        )
    }

    /// The pixel containing ground point (x, z), or `None` outside the map.
    pub fn pixel_of(&self, x: f64, z: f64) -> Option<(u32, u32)> {
        let (c, r) = self.to_pixel(x, z);
        let (c, r) = (c.round(), r.round());
        (c >= 0.0 && r >= 0.0 && c < self.width as f64 && r < self.height as f64)
            .then_some((c as u32, r as u32))
    }
}

/// Grid lines every `step` metres with distance labels: ahead along the left edge,
/// sideways along the bottom edge (outside the camera's view, so usually empty).
pub fn draw_grid(img: &mut RgbImage, map: &BevMap, step: f64, text_scale: u32) {
    let r = map.range;
    let ticks = |lo: f64, hi: f64| {
        let first = (lo / step).ceil() as i64;
        let last = (hi / step).floor() as i64;
        (first..=last).map(move |k| k as f64 * step)
    };
    for x in ticks(r.lateral.0, r.lateral.1) {
        line(
            img,
            map.to_pixel(x, r.forward.0),
            map.to_pixel(x, r.forward.1),
            GRID,
            1,
        );
    }
    for z in ticks(r.forward.0, r.forward.1) {
        line(
            img,
            map.to_pixel(r.lateral.0, z),
            map.to_pixel(r.lateral.1, z),
            GRID,
            1,
        );
    }
    let pad = 2 * text_scale as i32;
    let (_, th) = text_size("0", text_scale);
    for z in ticks(r.forward.0, r.forward.1).filter(|&z| z > r.forward.0) {
        let (_, row) = map.to_pixel(r.lateral.0, z);
        draw_text(
            img,
            pad,
            row as i32 - th as i32 - pad,
            &format!("{z:.0} m"),
            TEXT,
            text_scale,
        );
    }
    let labels: Vec<(f64, String)> = ticks(r.lateral.0, r.lateral.1)
        .filter(|&x| x != 0.0 && x > r.lateral.0 && x < r.lateral.1)
        .map(|x| (x, format!("{x:+.0} m")))
        .collect();
    let widest = labels
        .iter()
        .map(|(_, t)| text_size(t, text_scale).0)
        .max()
        .unwrap_or(0);
    let (space, _) = text_size(" ", text_scale);
    let every = label_stride(step * map.px_per_m, widest + space);
    for (x, text) in labels {
        if (x / step).round() as i64 % every != 0 {
            continue;
        }
        let (col, _) = map.to_pixel(x, r.forward.0);
        draw_text(
            img,
            col as i32 + pad,
            map.height as i32 - th as i32 - pad,
            &text,
            TEXT,
            text_scale,
        );
    }
}

/// Label every how many grid lines so that labels `room` pixels wide (text and a space)
/// never touch: 1 on a street-sized map, more on a room-sized one, where a metre is
/// narrower than "-4 m". Multiples of it keep the labels symmetric about the camera.
fn label_stride(px_per_step: f64, room: u32) -> i64 {
    ((room as f64 / px_per_step).ceil() as i64).max(1)
}

/// The left and right edges of the camera's field of view, dashed, so one can see
/// which points and boxes the image can confirm.
pub fn draw_fov(img: &mut RgbImage, map: &BevMap, cam: &CameraModel, image_width: u32) {
    for u in [0.0, image_width as f64 - 1.0] {
        let near = cam.image_to_rect(u, cam.cv(), 0.5);
        let far = cam.image_to_rect(u, cam.cv(), 500.0);
        dashed_line(
            img,
            map.to_pixel(near[0], near[2]),
            map.to_pixel(far[0], far[2]),
            EGO,
            6,
            0.45,
        );
    }
}

/// LiDAR points coloured by height above the road; points outside the camera image
/// (`image_size`) are dimmed. Higher points are drawn last so that objects stand out
/// from the road beneath them. Returns how many drawn points were dimmed, so the
/// legend explains dimming only when there is some.
pub fn draw_points(
    img: &mut RgbImage,
    map: &BevMap,
    cam: &CameraModel,
    image_size: (u32, u32),
    points: &[LidarPoint],
    point_size: u32,
) -> usize {
    let (w, h) = (image_size.0 as f64, image_size.1 as f64);
    let mut visible: Vec<(f64, u32, u32, bool)> = Vec::with_capacity(points.len());
    for p in points {
        let r = cam.velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64]);
        let Some((col, row)) = map.pixel_of(r[0], r[2]) else {
            continue;
        };
        let (u, v, d) = cam.rect_to_image(r);
        let in_view = d > 0.0 && u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5;
        visible.push((p[2] as f64 + style::LIDAR_MOUNT_HEIGHT, col, row, in_view));
    }
    visible.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut dimmed = 0;
    for (height, col, row, in_view) in visible {
        let c = style::height_colour(height);
        dimmed += usize::from(!in_view);
        let c = if in_view {
            c
        } else {
            style::dim(c, OUT_OF_VIEW)
        };
        if point_size <= 1 {
            img.put_pixel(col, row, c);
        } else {
            let half = (point_size / 2) as i32;
            fill_rect(
                img,
                col as i32 - half,
                row as i32 - half,
                point_size,
                point_size,
                c,
            );
        }
    }
    dimmed
}

/// Points in colours of their own (`colours[i]` for `points[i]`, e.g. an RGB-D camera's),
/// the lowest first so that tops of furniture stand out over the floor beneath them.
pub fn draw_coloured_points(
    img: &mut RgbImage,
    map: &BevMap,
    cam: &CameraModel,
    points: &[LidarPoint],
    colours: &[Rgb<u8>],
    point_size: u32,
) {
    let mut shown: Vec<(f32, u32, u32, Rgb<u8>)> = points
        .iter()
        .zip(colours)
        .filter_map(|(p, &c)| {
            let r = cam.velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64]);
            let (col, row) = map.pixel_of(r[0], r[2])?;
            // Camera y points down: the highest point has the smallest y.
            Some((-r[1] as f32, col, row, c))
        })
        .collect();
    shown.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = (point_size / 2) as i32;
    for (_, col, row, c) in shown {
        if point_size <= 1 {
            img.put_pixel(col, row, c);
        } else {
            fill_rect(
                img,
                col as i32 - half,
                row as i32 - half,
                point_size,
                point_size,
                c,
            );
        }
    }
}

/// Pseudo points (LiDAR frame, metres) in their own colour, one pixel each: drawn under
/// the LiDAR points, which they densify.
pub fn draw_pseudo_points(
    img: &mut RgbImage,
    map: &BevMap,
    cam: &CameraModel,
    points: &[[f32; 3]],
) {
    for p in points {
        let r = cam.velo_to_rect(p.map(f64::from));
        if let Some((col, row)) = map.pixel_of(r[0], r[2]) {
            img.put_pixel(col, row, style::PSEUDO);
        }
    }
}

/// Brightness kept by points outside the camera's view.
pub const OUT_OF_VIEW: f64 = 0.45;

/// Box footprints in the colour of `source`, each with a tick from its centre to the
/// middle of its front edge (corners 0 and 1 face the heading). DontCare is skipped.
pub fn draw_footprints(img: &mut RgbImage, map: &BevMap, objects: &[&Object], source: Source) {
    for o in objects.iter().filter(|o| o.class != ObjectClass::DontCare) {
        let b = &o.box3d;
        let poly = bev_polygon(b).map(|[x, z]| map.to_pixel(x, z));
        polygon(img, &poly, source.colour(), source.thickness());
        let front = ((poly[0].0 + poly[1].0) / 2.0, (poly[0].1 + poly[1].1) / 2.0);
        line(
            img,
            map.to_pixel(b.x, b.z),
            front,
            source.colour(),
            source.thickness(),
        );
    }
}

/// The ego camera: a filled triangle pointing forward at the origin, 2.4 m long on
/// KITTI's 70 m view and shrinking with shorter ranges (a room's 8 m).
pub fn draw_ego(img: &mut RgbImage, map: &BevMap) {
    let forward = map.range.forward.1 - map.range.forward.0;
    let k = (forward / 70.0).clamp(0.1, 1.0);
    let pts = [(0.0, 2.2), (-1.0, -0.2), (1.0, -0.2)].map(|(x, z)| {
        let (x, z) = (x * k, z * k);
        let (c, r) = map.to_pixel(x, z);
        Point::new(c.round() as i32, r.round() as i32)
    });
    if pts[0] != pts[1] && pts[1] != pts[2] {
        draw_polygon_mut(img, &pts, EGO);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::style::{BACKGROUND, GT};
    use crate::testutil::{camera, count_colour};
    use fusiondet_kitti::Box3d;

    fn map() -> BevMap {
        BevMap::new(BevRange::default(), 800)
    }

    #[test]
    fn crowded_side_labels_are_thinned_to_fit() {
        // A room-sized map: a metre is 73 px, "-4 m" and a space 80 px at scale 2.
        assert_eq!(label_stride(73.0, 80), 2);
        // A street-sized map: every grid line keeps its label.
        assert_eq!(label_stride(114.0, 80), 1);
        assert_eq!(label_stride(80.0, 80), 1);
        assert_eq!(label_stride(20.0, 80), 4);
    }

    #[test]
    fn scale_is_isotropic_and_height_follows_the_range() {
        let m = map();
        assert_eq!(m.px_per_m, 10.0);
        assert_eq!(m.height, 700);
    }

    #[test]
    fn a_point_ten_metres_ahead_lands_ten_metres_above_the_bottom() {
        let m = map();
        // 10 m ahead of the ego: 60 m below the top row at 10 px/m.
        assert_eq!(m.pixel_of(0.0, 10.0), Some((400, 600)));
        // Right in the camera frame is right in the picture.
        assert_eq!(m.pixel_of(5.0, 10.0), Some((450, 600)));
        assert_eq!(m.pixel_of(0.0, -1.0), None);
        assert_eq!(m.pixel_of(41.0, 10.0), None);
    }

    #[test]
    fn lidar_point_is_drawn_where_its_camera_position_maps() {
        let cam = camera();
        let m = map();
        let mut img = RgbImage::from_pixel(m.width, m.height, BACKGROUND);
        // A point 20 m ahead on the road (LiDAR x forward, z up).
        draw_points(
            &mut img,
            &m,
            &cam,
            (1242, 375),
            &[[20.0, 0.0, -1.73, 0.5]],
            1,
        );
        let r = cam.velo_to_rect([20.0, 0.0, -1.73]);
        let (c, row) = m.pixel_of(r[0], r[2]).unwrap();
        assert_eq!(*img.get_pixel(c, row), style::height_colour(0.0));
        assert_eq!(img.pixels().filter(|&&p| p != BACKGROUND).count(), 1);
        // The same point behind the camera is outside the map.
        let mut img2 = RgbImage::from_pixel(m.width, m.height, BACKGROUND);
        draw_points(
            &mut img2,
            &m,
            &cam,
            (1242, 375),
            &[[-20.0, 0.0, -1.73, 0.5]],
            1,
        );
        assert!(img2.pixels().all(|&p| p == BACKGROUND));
    }

    #[test]
    fn footprint_outlines_the_box_and_ticks_towards_its_heading() {
        let m = map();
        let mut img = RgbImage::from_pixel(m.width, m.height, BACKGROUND);
        // ry = 0: length along +x, so the front edge is on the right.
        let b = Box3d {
            h: 1.5,
            w: 2.0,
            l: 4.0,
            x: 0.0,
            y: 1.7,
            z: 20.0,
            ry: 0.0,
        };
        let o = Object {
            class: ObjectClass::Car,
            truncation: 0.0,
            occlusion: 0,
            alpha: 0.0,
            bbox: Default::default(),
            box3d: b,
            score: None,
        };
        draw_footprints(&mut img, &m, &[&o], Source::GroundTruth);
        let (cx, cy) = m.pixel_of(0.0, 20.0).unwrap();
        // Tick from the centre towards +x (right) only.
        assert_eq!(*img.get_pixel(cx + 10, cy), GT);
        assert_eq!(*img.get_pixel(cx - 10, cy), BACKGROUND);
        // Left and right edges at x = ∓2 m, top edge at z = 21 m.
        assert_eq!(*img.get_pixel(cx - 20, cy), GT);
        assert_eq!(*img.get_pixel(cx + 20, cy), GT);
        assert_eq!(*img.get_pixel(cx, cy - 10), GT);
        assert!(count_colour(&img, GT) < 2 * 3 * (40 + 20) + 3 * 20 + 40);
    }
}
