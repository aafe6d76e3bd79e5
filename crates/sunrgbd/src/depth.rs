//! Raw SUN RGB-D depth maps and the points they make.
//!
//! A raw depth map is a 16-bit grey PNG (640×480 for the Kinect v1 frames) whose value is the
//! depth in millimetres rotated right by 3 bits, `(d >> 3) | (d << 13)`: the sensor's
//! 13-bit millimetres sit in the high bits of the stored value. 0 means no measurement.
//!
//! Back-projection follows the SUN RGB-D toolbox, whose camera matrices K were made for it:
//! a pixel at column c, row r (counted from 0) has image coordinates u = c + 1, v = r + 1
//! (MATLAB's 1-based pixels; [`PixelOrigin`]), depths beyond 8 m are set to 8 m, and with
//! d the depth in metres the camera-frame point (x right, y down, z forward) is
//! ((u − cx)·d/fx, (v − cy)·d/fy, d). Upright depth before the tilt is the same point with
//! the axes renamed, x right, y forward, z up: (x_cam, z_cam, −y_cam); the tilt then makes it
//! gravity-aligned, p = Rtilt · p_depth.

use crate::calib::{Mat33, apply};
use crate::io::{MAX_BINARY_BYTES, read_regular};
use crate::points::Point;
use fusiondet_kitti::{FormatError, Result};
use std::path::Path;

/// A raw depth map, the stored rotation undone.
#[derive(Debug, Clone, PartialEq)]
pub struct RawDepth {
    pub width: usize,
    pub height: usize,
    /// `height` rows of `width` depths in millimetres (0 = no measurement).
    pub millimetres: Vec<u16>,
}

impl RawDepth {
    pub fn get(&self, col: usize, row: usize) -> u16 {
        self.millimetres[row * self.width + col]
    }
}

/// A stored PNG value → millimetres.
pub fn stored_to_millimetres(stored: u16) -> u16 {
    stored.rotate_right(3)
}

/// Millimetres → the value SUN RGB-D stores.
pub fn millimetres_to_stored(mm: u16) -> u16 {
    mm.rotate_left(3)
}

/// Reads a raw depth PNG; anything but a 16-bit single-channel PNG is an error naming the file.
pub fn read_depth_png(path: &Path) -> Result<RawDepth> {
    let bytes = read_regular(path, MAX_BINARY_BYTES)?;
    let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| FormatError::file(path, format!("cannot decode the PNG: {e}")))?;
    let image::DynamicImage::ImageLuma16(gray) = decoded else {
        return Err(FormatError::file(
            path,
            format!(
                "a SUN RGB-D depth map is a 16-bit grey PNG, this one is {:?}",
                decoded.color()
            ),
        ));
    };
    let (w, h) = gray.dimensions();
    Ok(RawDepth {
        width: w as usize,
        height: h as usize,
        millimetres: gray
            .into_raw()
            .into_iter()
            .map(stored_to_millimetres)
            .collect(),
    })
}

/// Writes a raw depth PNG (atomically) the way SUN RGB-D stores it.
pub fn write_depth_png(path: &Path, depth: &RawDepth) -> Result<()> {
    let values: Vec<u16> = depth
        .millimetres
        .iter()
        .map(|&mm| millimetres_to_stored(mm))
        .collect();
    let image: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
        image::ImageBuffer::from_raw(depth.width as u32, depth.height as u32, values)
            .ok_or_else(|| FormatError::file(path, "the depth map has not one value per pixel"))?;
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| FormatError::file(path, format!("cannot encode the PNG: {e}")))?;
    fusiondet_kitti::write_atomic(path, &bytes)
}

/// Where pixel coordinates start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelOrigin {
    /// The first pixel is at (1, 1): the SUN RGB-D toolbox's (MATLAB) convention, the one its
    /// camera matrices and the prepared points were made with.
    OneBased,
    /// The first pixel is at (0, 0).
    ZeroBased,
}

/// How a depth map becomes points (module docs). The default is the SUN RGB-D toolbox's.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthToPoints {
    pub pixel_origin: PixelOrigin,
    /// Depths beyond this many metres are set to it (the toolbox: 8); `None` keeps them.
    pub max_depth_m: Option<f64>,
    /// Upright = Rtilt · depth frame; the identity for a level camera.
    pub rtilt: Mat33,
}

impl Default for DepthToPoints {
    fn default() -> Self {
        DepthToPoints {
            pixel_origin: PixelOrigin::OneBased,
            max_depth_m: Some(8.0),
            rtilt: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        }
    }
}

/// The upright-depth point of every measured pixel, row by row, with the pixel's colour
/// from `colour` (divided by 255) or black without one. `k` is the pinhole camera matrix
/// [fx 0 cx; 0 fy cy; 0 0 1]; `colour`, when given, must be the depth map's size.
pub fn depth_to_points(
    depth: &RawDepth,
    k: &Mat33,
    options: &DepthToPoints,
    colour: Option<&image::RgbImage>,
) -> std::result::Result<Vec<Point>, String> {
    let (fx, fy, cx, cy) = (k[0][0], k[1][1], k[0][2], k[1][2]);
    let pinhole = k[0][1] == 0.0 && k[1][0] == 0.0 && k[2] == [0.0, 0.0, 1.0];
    if !(pinhole
        && fx > 0.0
        && fy > 0.0
        && cx.is_finite()
        && cy.is_finite()
        && fx.is_finite()
        && fy.is_finite())
    {
        return Err(format!(
            "{k:?} is no pinhole camera matrix [fx 0 cx; 0 fy cy; 0 0 1] with fx, fy > 0"
        ));
    }
    if depth.millimetres.len() != depth.width * depth.height {
        return Err("the depth map has not one value per pixel".into());
    }
    if let Some(img) = colour
        && (img.width() as usize, img.height() as usize) != (depth.width, depth.height)
    {
        return Err(format!(
            "the colour image is {}×{}, the depth map {}×{}",
            img.width(),
            img.height(),
            depth.width,
            depth.height
        ));
    }
    let origin = match options.pixel_origin {
        PixelOrigin::OneBased => 1.0,
        PixelOrigin::ZeroBased => 0.0,
    };
    let mut points = Vec::with_capacity(depth.millimetres.len());
    for row in 0..depth.height {
        for col in 0..depth.width {
            let mm = depth.get(col, row);
            if mm == 0 {
                continue;
            }
            let mut d = f64::from(mm) / 1000.0;
            if let Some(max) = options.max_depth_m {
                d = d.min(max);
            }
            let (u, v) = (col as f64 + origin, row as f64 + origin);
            let camera = [(u - cx) * d / fx, (v - cy) * d / fy, d];
            let [x, y, z] = apply(&options.rtilt, [camera[0], camera[2], -camera[1]]);
            let rgb = colour.map_or([0.0; 3], |img| {
                img.get_pixel(col as u32, row as u32)
                    .0
                    .map(|c| f32::from(c) / 255.0)
            });
            points.push([x as f32, y as f32, z as f32, rgb[0], rgb[1], rgb[2]]);
        }
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::Calib;

    #[test]
    fn the_stored_value_is_millimetres_rotated_right_by_three_bits() {
        // 1234 mm = 0b100_1101_0010 is stored shifted up by 3 bits.
        assert_eq!(millimetres_to_stored(1234), 1234 << 3);
        assert_eq!(stored_to_millimetres(1234 << 3), 1234);
        // The low 3 bits of a stored value are the millimetres' top bits.
        assert_eq!(stored_to_millimetres(0b101), 0b101 << 13);
        for mm in [0u16, 1, 7999, 8191, 40000, u16::MAX] {
            assert_eq!(stored_to_millimetres(millimetres_to_stored(mm)), mm);
        }
    }

    #[test]
    fn png_round_trip_and_refusals() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("depth.png");
        let depth = RawDepth {
            width: 3,
            height: 2,
            millimetres: vec![0, 1, 1500, 8000, 8191, 65535],
        };
        write_depth_png(&path, &depth).unwrap();
        assert_eq!(read_depth_png(&path).unwrap(), depth);
        // The file holds the rotated values, as SUN RGB-D's do.
        let stored = image::open(&path).unwrap().into_luma16();
        assert_eq!(stored.get_pixel(2, 0).0[0], 1500 << 3);
        let rgb = dir.path().join("rgb.png");
        image::RgbImage::new(2, 2).save(&rgb).unwrap();
        let err = read_depth_png(&rgb).unwrap_err().to_string();
        assert!(
            err.contains("rgb.png") && err.contains("16-bit grey"),
            "{err}"
        );
    }

    /// A hand-made 2×2 map: fx = 2, fy = 4, (cx, cy) = (1, 1), so with 1-based pixels the
    /// top-left pixel lies on the optical axis.
    #[test]
    fn a_two_by_two_map_back_projects_by_hand() {
        let k = [[2.0, 0.0, 1.0], [0.0, 4.0, 1.0], [0.0, 0.0, 1.0]];
        let depth = RawDepth {
            width: 2,
            height: 2,
            // (col 0, row 0) 2 m, (1, 0) none, (0, 1) 4 m, (1, 1) 9 m (clamped to 8 m).
            millimetres: vec![2000, 0, 4000, 9000],
        };
        let colour = image::RgbImage::from_fn(2, 2, |c, r| {
            image::Rgb([(c * 255) as u8, (r * 255) as u8, 51])
        });
        let points = depth_to_points(&depth, &k, &DepthToPoints::default(), Some(&colour)).unwrap();
        // (0, 0): u = v = 1 → on the axis, 2 m forward.
        // (0, 1): u = 1, v = 2 → camera y = (2 − 1)·4/4 = 1 (down) → z = −1.
        // (1, 1): u = v = 2, d = 8 → camera (4, 2, 8) → upright (4, 8, −2).
        let expected: Vec<Point> = vec![
            [0.0, 2.0, 0.0, 0.0, 0.0, 0.2],
            [0.0, 4.0, -1.0, 0.0, 1.0, 0.2],
            [4.0, 8.0, -2.0, 1.0, 1.0, 0.2],
        ];
        assert_eq!(points, expected);
        // 0-based pixels shift every ray by one pixel; no clamp keeps 9 m.
        let zero = DepthToPoints {
            pixel_origin: PixelOrigin::ZeroBased,
            max_depth_m: None,
            ..DepthToPoints::default()
        };
        let points = depth_to_points(&depth, &k, &zero, None).unwrap();
        assert_eq!(points[0], [-1.0, 2.0, 0.5, 0.0, 0.0, 0.0]);
        assert_eq!(points[2], [0.0, 9.0, 0.0, 0.0, 0.0, 0.0]);
    }

    /// Points from a tilted camera project back onto their pixels through the calibration
    /// made from the same K and Rtilt: the two conventions agree.
    #[test]
    fn points_project_back_to_their_pixels() {
        let k = [[529.5, 0.0, 365.0], [0.0, 529.5, 265.0], [0.0, 0.0, 1.0]];
        let t: f64 = -0.18;
        let rtilt = [
            [1.0, 0.0, 0.0],
            [0.0, t.cos(), -t.sin()],
            [0.0, t.sin(), t.cos()],
        ];
        let (width, height) = (7, 5);
        let depth = RawDepth {
            width,
            height,
            millimetres: (0..width * height).map(|i| 900 + 37 * i as u16).collect(),
        };
        let options = DepthToPoints {
            rtilt,
            ..DepthToPoints::default()
        };
        let points = depth_to_points(&depth, &k, &options, None).unwrap();
        let calib = Calib::from_camera(&k, &rtilt);
        for (i, p) in points.iter().enumerate() {
            let [u, v] = calib
                .project([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
                .unwrap();
            let (col, row) = ((i % width) as f64, (i / width) as f64);
            assert!(
                (u - (col + 1.0)).abs() < 1e-3 && (v - (row + 1.0)).abs() < 1e-3,
                "{i}: {u} {v}"
            );
        }
    }

    #[test]
    fn bad_inputs_are_refused() {
        let depth = RawDepth {
            width: 2,
            height: 1,
            millimetres: vec![1, 2],
        };
        let skewed = [[2.0, 0.5, 1.0], [0.0, 4.0, 1.0], [0.0, 0.0, 1.0]];
        let o = DepthToPoints::default();
        assert!(
            depth_to_points(&depth, &skewed, &o, None)
                .unwrap_err()
                .contains("pinhole")
        );
        let k = [[2.0, 0.0, 1.0], [0.0, 4.0, 1.0], [0.0, 0.0, 1.0]];
        let small = image::RgbImage::new(1, 1);
        let err = depth_to_points(&depth, &k, &o, Some(&small)).unwrap_err();
        assert!(err.contains("1×1, the depth map 2×1"), "{err}");
    }
}
