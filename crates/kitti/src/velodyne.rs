//! `velodyne/NNNNNN.bin`: little-endian float32 quadruples (x, y, z, reflectance)
//! in the LiDAR frame (x forward, y left, z up).

use crate::error::{FormatError, Result};
use std::path::Path;

/// One LiDAR return: x, y, z in metres (LiDAR frame) and reflectance in [0, 1].
pub type LidarPoint = [f32; 4];

/// Decodes a point cloud; the length must be a multiple of 16 bytes and every value finite.
pub fn parse_velodyne(bytes: &[u8], path: &Path) -> Result<Vec<LidarPoint>> {
    if !bytes.len().is_multiple_of(16) {
        return Err(FormatError::file(
            path,
            format!(
                "size {} bytes is not a multiple of 16 (4 float32 per point); the file is truncated or not a KITTI velodyne scan",
                bytes.len()
            ),
        ));
    }
    let mut points = Vec::with_capacity(bytes.len() / 16);
    for (index, chunk) in bytes.chunks_exact(16).enumerate() {
        let mut p = [0.0f32; 4];
        for (k, value) in p.iter_mut().enumerate() {
            *value = f32::from_le_bytes([
                chunk[4 * k],
                chunk[4 * k + 1],
                chunk[4 * k + 2],
                chunk[4 * k + 3],
            ]);
            if !value.is_finite() {
                return Err(FormatError::field(
                    path,
                    index,
                    ["x", "y", "z", "reflectance"][k],
                    format!("point {index} has a non-finite value ({value})"),
                ));
            }
        }
        points.push(p);
    }
    Ok(points)
}

pub fn read_velodyne(path: &Path) -> Result<Vec<LidarPoint>> {
    let bytes = crate::error::read_regular(path, crate::error::MAX_BINARY_BYTES)?;
    parse_velodyne(&bytes, path)
}

pub fn encode_velodyne(points: &[LidarPoint]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(points.len() * 16);
    for p in points {
        for v in p {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

pub fn write_velodyne(path: &Path, points: &[LidarPoint]) -> Result<()> {
    crate::atomic::write_atomic(path, &encode_velodyne(points))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        let pts = vec![[1.0, -2.5, 0.25, 0.5], [10.0, 0.0, -1.7, 0.0]];
        let back = parse_velodyne(&encode_velodyne(&pts), Path::new("a.bin")).unwrap();
        assert_eq!(back, pts);
    }

    #[test]
    fn size_not_multiple_of_16_is_rejected() {
        let err = parse_velodyne(&[0u8; 20], Path::new("v/000001.bin"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("v/000001.bin"), "{err}");
        assert!(err.contains("not a multiple of 16"), "{err}");
    }

    #[test]
    fn nan_point_is_rejected_with_index() {
        let pts = vec![[1.0, 2.0, 3.0, 0.1], [1.0, f32::NAN, 3.0, 0.1]];
        let err = parse_velodyne(&encode_velodyne(&pts), Path::new("a.bin"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("field `y`") && err.contains("point 1"),
            "{err}"
        );
    }
}
