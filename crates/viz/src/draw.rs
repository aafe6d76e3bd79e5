//! Drawing primitives on an [`RgbImage`]: clipped thick and dashed lines, alpha
//! blending and rectangles. imageproc does the rasterising; what it lacks is done
//! here: segments are clipped to the canvas in f64 first (imageproc walks every
//! Bresenham step, so an edge projected a million pixels away would otherwise take
//! seconds), and thickness is made of parallel one-pixel lines.

use image::{Rgb, RgbImage};
use imageproc::drawing::{BresenhamLineIter, draw_filled_rect_mut, draw_line_segment_mut};
use imageproc::rect::Rect;

/// A point in continuous pixel coordinates: pixel (i, j) has its centre at (i, j).
pub type Px = (f64, f64);

/// Clips segment `a`–`b` to the rectangle [x0, x1] × [y0, y1] (Liang–Barsky), or
/// `None` if no part of it lies inside or an end is not finite.
pub fn clip_segment(a: Px, b: Px, x0: f64, y0: f64, x1: f64, y1: f64) -> Option<(Px, Px)> {
    if ![a.0, a.1, b.0, b.1].iter().all(|v| v.is_finite()) {
        return None;
    }
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let mut t0: f64 = 0.0;
    let mut t1: f64 = 1.0;
    for (p, q) in [
        (-dx, a.0 - x0),
        (dx, x1 - a.0),
        (-dy, a.1 - y0),
        (dy, y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    Some((
        (a.0 + t0 * dx, a.1 + t0 * dy),
        (a.0 + t1 * dx, a.1 + t1 * dy),
    ))
}

/// Clips to the canvas grown by `margin` pixels on every side.
fn clip_to_canvas(img: &RgbImage, a: Px, b: Px, margin: f64) -> Option<(Px, Px)> {
    let (w, h) = (img.width() as f64, img.height() as f64);
    clip_segment(a, b, -margin, -margin, w - 1.0 + margin, h - 1.0 + margin)
}

/// Draws a solid line `thickness` pixels wide (at least 1) with square caps, so that
/// the corners of a polygon drawn edge by edge close without notches.
pub fn line(img: &mut RgbImage, a: Px, b: Px, colour: Rgb<u8>, thickness: u32) {
    let t = thickness.max(1);
    let Some((a, b)) = clip_to_canvas(img, a, b, t as f64) else {
        return;
    };
    let steep = (b.1 - a.1).abs() > (b.0 - a.0).abs();
    let first = -((t as i32 - 1) / 2);
    for k in first..first + t as i32 {
        let k = k as f64;
        let (oa, ob) = if steep {
            ((a.0 + k, a.1), (b.0 + k, b.1))
        } else {
            ((a.0, a.1 + k), (b.0, b.1 + k))
        };
        draw_line_segment_mut(
            img,
            (oa.0 as f32, oa.1 as f32),
            (ob.0 as f32, ob.1 as f32),
            colour,
        );
    }
    if t > 1 {
        for p in [a, b] {
            let x = (p.0.round() as i32) + first;
            let y = (p.1.round() as i32) + first;
            fill_rect(img, x, y, t, t, colour);
        }
    }
}

/// Draws a closed polygon outline.
pub fn polygon(img: &mut RgbImage, points: &[Px], colour: Rgb<u8>, thickness: u32) {
    for (i, &a) in points.iter().enumerate() {
        line(img, a, points[(i + 1) % points.len()], colour, thickness);
    }
}

/// Draws a one-pixel dashed line (`dash` pixels on, `dash` off), blended with weight
/// `alpha`, for things that must be visible without competing with the boxes.
pub fn dashed_line(img: &mut RgbImage, a: Px, b: Px, colour: Rgb<u8>, dash: u32, alpha: f64) {
    let Some((a, b)) = clip_to_canvas(img, a, b, 0.0) else {
        return;
    };
    let dash = dash.max(1) as usize;
    let iter = BresenhamLineIter::new((a.0 as f32, a.1 as f32), (b.0 as f32, b.1 as f32));
    for (i, (x, y)) in iter.enumerate() {
        if (i / dash).is_multiple_of(2) {
            blend_pixel(img, x, y, colour, alpha);
        }
    }
}

/// Mixes `colour` into pixel (x, y) with weight `alpha` in [0, 1]; outside the
/// canvas nothing happens.
pub fn blend_pixel(img: &mut RgbImage, x: i32, y: i32, colour: Rgb<u8>, alpha: f64) {
    if x < 0 || y < 0 || x as u32 >= img.width() || y as u32 >= img.height() {
        return;
    }
    let a = alpha.clamp(0.0, 1.0);
    let p = img.get_pixel_mut(x as u32, y as u32);
    for k in 0..3 {
        p.0[k] = (p.0[k] as f64 * (1.0 - a) + colour.0[k] as f64 * a).round() as u8;
    }
}

/// Fills a `w`×`h` rectangle with top-left pixel (x, y), clipped to the canvas.
pub fn fill_rect(img: &mut RgbImage, x: i32, y: i32, w: u32, h: u32, colour: Rgb<u8>) {
    if w > 0 && h > 0 {
        draw_filled_rect_mut(img, Rect::at(x, y).of_size(w, h), colour);
    }
}

/// Fills a rectangle blended with weight `alpha` (a translucent backdrop).
pub fn fill_rect_blended(
    img: &mut RgbImage,
    x: i32,
    y: i32,
    w: u32,
    h: u32,
    colour: Rgb<u8>,
    alpha: f64,
) {
    for yy in y..y + h as i32 {
        for xx in x..x + w as i32 {
            blend_pixel(img, xx, yy, colour, alpha);
        }
    }
}

/// Dashed outline of the axis-aligned rectangle with corners `a` and `b`.
pub fn dashed_rect(img: &mut RgbImage, a: Px, b: Px, colour: Rgb<u8>, dash: u32, alpha: f64) {
    let corners = [a, (b.0, a.1), b, (a.0, b.1)];
    for i in 0..4 {
        dashed_line(img, corners[i], corners[(i + 1) % 4], colour, dash, alpha);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: Rgb<u8> = Rgb([255, 0, 0]);

    fn count(img: &RgbImage, c: Rgb<u8>) -> usize {
        img.pixels().filter(|&&p| p == c).count()
    }

    #[test]
    fn clipping_keeps_inside_and_cuts_crossing_segments() {
        let inside = clip_segment((1.0, 1.0), (5.0, 5.0), 0.0, 0.0, 9.0, 9.0).unwrap();
        assert_eq!(inside, ((1.0, 1.0), (5.0, 5.0)));
        let ((x0, y0), (x1, y1)) =
            clip_segment((-10.0, 4.0), (20.0, 4.0), 0.0, 0.0, 9.0, 9.0).unwrap();
        assert_eq!((x0, y0, x1, y1), (0.0, 4.0, 9.0, 4.0));
        assert!(clip_segment((-5.0, -5.0), (-1.0, 20.0), 0.0, 0.0, 9.0, 9.0).is_none());
        assert!(clip_segment((f64::NAN, 0.0), (3.0, 3.0), 0.0, 0.0, 9.0, 9.0).is_none());
    }

    #[test]
    fn thick_horizontal_line_covers_its_rows() {
        let mut img = RgbImage::new(20, 20);
        line(&mut img, (2.0, 10.0), (17.0, 10.0), RED, 3);
        for y in 9..=11 {
            assert_eq!(*img.get_pixel(10, y), RED, "row {y}");
        }
        assert_eq!(*img.get_pixel(10, 8), Rgb([0, 0, 0]));
        assert_eq!(*img.get_pixel(10, 12), Rgb([0, 0, 0]));
    }

    #[test]
    fn far_away_endpoints_are_clipped_not_walked() {
        let mut img = RgbImage::new(50, 50);
        let start = std::time::Instant::now();
        line(&mut img, (-1e9, 25.0), (1e9, 25.0), RED, 2);
        assert!(start.elapsed().as_millis() < 100);
        assert_eq!(count(&img, RED), 100);
    }

    #[test]
    fn dashed_line_skips_every_other_dash_and_blends() {
        let mut img = RgbImage::new(40, 3);
        dashed_line(
            &mut img,
            (0.0, 1.0),
            (39.0, 1.0),
            Rgb([200, 100, 0]),
            4,
            0.5,
        );
        assert_eq!(*img.get_pixel(0, 1), Rgb([100, 50, 0]));
        assert_eq!(*img.get_pixel(5, 1), Rgb([0, 0, 0]));
        assert_eq!(*img.get_pixel(8, 1), Rgb([100, 50, 0]));
    }
}
