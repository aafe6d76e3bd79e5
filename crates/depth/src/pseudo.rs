//! Pseudo point clouds (DASANet, Section 3.1; SFD does the same): every pixel of a
//! completed depth map back-projected into the LiDAR frame, with its colour and pixel.
//!
//! File format (`<id>.bin`): little-endian float32 × 8 per point — x, y, z (LiDAR frame,
//! metres), r, g, b (0–255, from `image_2`), u, v (the pixel, column and row index).

use crate::{DepthError, Result};
use fusiondet_geometry::CameraModel;
use fusiondet_kitti::{DepthMap, FormatError};
use image::RgbImage;
use std::path::Path;

/// One pseudo point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PseudoPoint {
    /// LiDAR frame, metres.
    pub xyz: [f32; 3],
    pub rgb: [f32; 3],
    /// Pixel column and row.
    pub uv: [f32; 2],
}

/// SFD's near-range thinning: where the point is nearer than `near_x` (LiDAR forward
/// axis) only pixels with odd u and odd v are kept (a quarter of them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thinning {
    pub near_x: f32,
}

impl Default for Thinning {
    /// SFD's 13 m.
    fn default() -> Self {
        Thinning { near_x: 13.0 }
    }
}

/// Back-projects every pixel with a depth (its centre, at the depth map's rectified z)
/// into the LiDAR frame, coloured from `image`.
pub fn pseudo_points(
    depth: &DepthMap,
    image: &RgbImage,
    camera: &CameraModel,
    thinning: Option<Thinning>,
) -> Result<Vec<PseudoPoint>> {
    if (image.width() as usize, image.height() as usize) != (depth.width, depth.height) {
        return Err(DepthError::Mismatch(format!(
            "the depth map is {}×{} but the image {}×{}",
            depth.width,
            depth.height,
            image.width(),
            image.height()
        )));
    }
    let mut points = Vec::with_capacity(depth.valid_count());
    for v in 0..depth.height {
        for u in 0..depth.width {
            let z = depth.get(u, v);
            if z <= 0.0 {
                continue;
            }
            let Some(rect) = camera.image_to_rect_at_z(u as f64 + 0.5, v as f64 + 0.5, z as f64)
            else {
                continue;
            };
            let velo = camera.rect_to_velo(rect);
            if let Some(t) = thinning
                && (velo[0] as f32) < t.near_x
                && (u % 2 == 0 || v % 2 == 0)
            {
                continue;
            }
            let c = image.get_pixel(u as u32, v as u32).0;
            points.push(PseudoPoint {
                xyz: velo.map(|x| x as f32),
                rgb: c.map(f32::from),
                uv: [u as f32, v as f32],
            });
        }
    }
    Ok(points)
}

/// Writes pseudo points (atomically) in the format above.
pub fn write_pseudo_points(path: &Path, points: &[PseudoPoint]) -> Result<()> {
    let mut bytes = Vec::with_capacity(points.len() * 32);
    for p in points {
        for v in p.xyz.iter().chain(&p.rgb).chain(&p.uv) {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    fusiondet_kitti::write_atomic(path, &bytes)?;
    Ok(())
}

/// Reads a pseudo-point file; a size that is not a whole number of points, or a value
/// that is not finite, is an error naming the file and the point.
pub fn read_pseudo_points(path: &Path) -> Result<Vec<PseudoPoint>> {
    let bytes =
        fusiondet_kitti::error::read_regular(path, fusiondet_kitti::error::MAX_BINARY_BYTES)?;
    if bytes.len() % 32 != 0 {
        return Err(FormatError::file(
            path,
            format!(
                "{} bytes is not a whole number of pseudo points (8 float32 each, 32 bytes)",
                bytes.len()
            ),
        )
        .into());
    }
    bytes
        .chunks_exact(32)
        .enumerate()
        .map(|(i, chunk)| {
            let f: [f32; 8] = std::array::from_fn(|k| {
                f32::from_le_bytes(chunk[4 * k..4 * k + 4].try_into().expect("4 bytes"))
            });
            if let Some(k) = f.iter().position(|v| !v.is_finite()) {
                return Err(FormatError::file(
                    path,
                    format!("point {i}: value {k} is {}, not a finite number", f[k]),
                )
                .into());
            }
            Ok(PseudoPoint {
                xyz: [f[0], f[1], f[2]],
                rgb: [f[3], f[4], f[5]],
                uv: [f[6], f[7]],
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_kitti::FrameDir;

    fn camera() -> CameraModel {
        let dir = FrameDir::new(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training"),
        );
        fusiondet_kitti::read_calib(&dir.calib("000001"))
            .unwrap()
            .camera_model()
            .unwrap()
    }

    #[test]
    fn a_pixel_goes_back_to_the_point_it_came_from() {
        let cam = camera();
        // A LiDAR point, projected to its pixel centre's ray at its own depth.
        let velo = [15.0, 2.0, -0.5];
        let rect = cam.velo_to_rect(velo);
        let (u, v, _) = cam.rect_to_image(rect);
        let (pu, pv) = (u as usize, v as usize);
        let mut depth = DepthMap::empty(1242, 375);
        depth.set(pu, pv, rect[2] as f32);
        let mut image = RgbImage::new(1242, 375);
        image.put_pixel(pu as u32, pv as u32, image::Rgb([10, 20, 30]));
        let points = pseudo_points(&depth, &image, &cam, None).unwrap();
        assert_eq!(points.len(), 1);
        let p = points[0];
        assert_eq!((p.rgb, p.uv), ([10.0, 20.0, 30.0], [pu as f32, pv as f32]));
        // Within half a pixel at 15 m (the pixel centre, not the exact projection).
        let off: f64 = (0..3)
            .map(|k| (p.xyz[k] as f64 - velo[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(off < 0.02, "{off} m");
        // The exact projection goes back exactly.
        let back = cam.rect_to_velo(cam.image_to_rect_at_z(u, v, rect[2]).unwrap());
        assert!((0..3).all(|k| (back[k] - velo[k]).abs() < 1e-9));
    }

    #[test]
    fn thinning_keeps_a_quarter_near_and_everything_far() {
        let cam = camera();
        let (mut near, mut far) = (DepthMap::empty(40, 40), DepthMap::empty(40, 40));
        near.data.fill(8.0);
        far.data.fill(30.0);
        let image = RgbImage::new(40, 40);
        let thin = Some(Thinning::default());
        assert_eq!(pseudo_points(&near, &image, &cam, thin).unwrap().len(), 400);
        assert_eq!(pseudo_points(&far, &image, &cam, thin).unwrap().len(), 1600);
        assert_eq!(
            pseudo_points(&near, &image, &cam, None).unwrap().len(),
            1600
        );
        let err = pseudo_points(&near, &RgbImage::new(41, 40), &cam, None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("40×40") && err.contains("41×40"), "{err}");
    }

    #[test]
    fn files_round_trip_and_bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000001.bin");
        let points = vec![
            PseudoPoint {
                xyz: [1.0, -2.0, 0.5],
                rgb: [255.0, 0.0, 7.0],
                uv: [3.0, 4.0],
            };
            3
        ];
        write_pseudo_points(&path, &points).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), 96);
        assert_eq!(read_pseudo_points(&path).unwrap(), points);
        std::fs::write(&path, [0u8; 33]).unwrap();
        let err = read_pseudo_points(&path).unwrap_err().to_string();
        assert!(
            err.contains("000001.bin") && err.contains("33 bytes"),
            "{err}"
        );
        let mut nan = vec![0u8; 32];
        nan[8..12].copy_from_slice(&f32::NAN.to_le_bytes());
        std::fs::write(&path, nan).unwrap();
        let err = read_pseudo_points(&path).unwrap_err().to_string();
        assert!(err.contains("point 0: value 2"), "{err}");
    }
}
