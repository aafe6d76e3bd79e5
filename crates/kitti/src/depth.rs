//! The KITTI depth-completion file format: a 16-bit grey PNG whose value is the depth in
//! metres × 256 (0 = no measurement), so depths up to 255.99 m in steps of 1/256 m; and
//! the depth image it holds.

use crate::error::{FormatError, Result};
use std::path::Path;

/// A dense image of depths in metres (row-major, f32; 0 = no measurement).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: usize,
    pub height: usize,
    /// `height` rows of `width` depths.
    pub data: Vec<f32>,
}

impl DepthMap {
    /// An empty map (every pixel without measurement).
    pub fn empty(width: usize, height: usize) -> DepthMap {
        DepthMap {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, depth: f32) {
        self.data[y * self.width + x] = depth;
    }

    /// Pixels with a measurement.
    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|&&d| d > 0.0).count()
    }
}

/// Reads a depth PNG; anything but a 16-bit single-channel PNG is an error naming the file.
pub fn read_depth_png(path: &Path) -> Result<DepthMap> {
    let decoded = crate::image::image_reader(path)?
        .decode()
        .map_err(|e| FormatError::file(path, format!("cannot decode the PNG: {e}")))?;
    let image::DynamicImage::ImageLuma16(gray) = decoded else {
        return Err(FormatError::file(
            path,
            format!(
                "a depth map must be a 16-bit grey PNG (metres × 256), this one is {:?}",
                decoded.color()
            ),
        ));
    };
    let (w, h) = gray.dimensions();
    Ok(DepthMap {
        width: w as usize,
        height: h as usize,
        data: gray
            .into_raw()
            .into_iter()
            .map(|v| v as f32 / 256.0)
            .collect(),
    })
}

/// Writes a depth map as a 16-bit PNG (atomically); depths are rounded to 1/256 m and
/// clamped to the format's range, negative or non-finite ones are refused.
pub fn write_depth_png(path: &Path, map: &DepthMap) -> Result<()> {
    if let Some(i) = map.data.iter().position(|d| !(d.is_finite() && *d >= 0.0)) {
        return Err(FormatError::file(
            path,
            format!(
                "pixel ({}, {}) has depth {}, which the format cannot hold",
                i % map.width.max(1),
                i / map.width.max(1),
                map.data[i]
            ),
        ));
    }
    let values: Vec<u16> = map
        .data
        .iter()
        .map(|d| (d * 256.0).round().min(u16::MAX as f32) as u16)
        .collect();
    let image: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
        image::ImageBuffer::from_raw(map.width as u32, map.height as u32, values)
            .expect("one value per pixel");
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| FormatError::file(path, format!("cannot encode the PNG: {e}")))?;
    crate::write_atomic(path, &bytes)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_to_a_256th_of_a_metre() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        let map = DepthMap {
            width: 3,
            height: 2,
            data: vec![0.0, 1.5, 10.25, 80.0039, 255.99, 300.0],
        };
        write_depth_png(&path, &map).unwrap();
        let back = read_depth_png(&path).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(&back.data[..4], &[0.0, 1.5, 10.25, 80.0 + 1.0 / 256.0]);
        assert_eq!(back.data[5], u16::MAX as f32 / 256.0);
    }

    #[test]
    fn colour_8_bit_and_bad_values_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let rgb = dir.path().join("rgb.png");
        image::RgbImage::new(4, 4).save(&rgb).unwrap();
        let err = read_depth_png(&rgb).unwrap_err().to_string();
        assert!(err.contains("rgb.png") && err.contains("16-bit"), "{err}");
        let gray8 = dir.path().join("gray8.png");
        image::GrayImage::new(4, 4).save(&gray8).unwrap();
        let err = read_depth_png(&gray8).unwrap_err().to_string();
        assert!(err.contains("gray8.png") && err.contains("16-bit"), "{err}");
        let err = read_depth_png(&dir.path().join("none.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("none.png"), "{err}");
        let nan = DepthMap {
            width: 2,
            height: 1,
            data: vec![1.0, f32::NAN],
        };
        let err = write_depth_png(&dir.path().join("n.png"), &nan)
            .unwrap_err()
            .to_string();
        assert!(err.contains("(1, 0)") && err.contains("NaN"), "{err}");
    }
}
