//! `points/<id>.bin`: little-endian float32 × 6 per point, x y z (metres, upright depth)
//! and r g b (each in [0, 1]), as the prepared SUN RGB-D scenes store them.

use crate::io::{MAX_BINARY_BYTES, read_regular};
use fusiondet_kitti::{FormatError, Result};
use std::path::Path;

/// One point: x, y, z, r, g, b.
pub type Point = [f32; 6];

const BYTES: usize = 24;
const FIELDS: [&str; 6] = ["x", "y", "z", "r", "g", "b"];

/// Why a point cannot be stored: its field and value. Colours outside [0, 1] are refused
/// because they mean another convention (0–255) that every colour feature would misread.
fn bad_field(p: &Point) -> Option<(usize, f32)> {
    p.iter().enumerate().find_map(|(k, &v)| {
        let ok = v.is_finite() && (k < 3 || (0.0..=1.0).contains(&v));
        (!ok).then_some((k, v))
    })
}

fn field_error(path: &Path, index: usize, k: usize, v: f32) -> FormatError {
    let what = if k < 3 {
        "a non-finite coordinate".to_string()
    } else {
        "a colour outside [0, 1] (0–255 colours must be divided by 255)".to_string()
    };
    // As in the KITTI scans, `line` is the point's 0-based index.
    FormatError::field(
        path,
        index,
        FIELDS[k],
        format!("point {index} has {what}: {v}"),
    )
}

/// Decodes a point file; its length must be a multiple of 24 bytes.
pub fn parse_points(bytes: &[u8], path: &Path) -> Result<Vec<Point>> {
    if !bytes.len().is_multiple_of(BYTES) {
        return Err(FormatError::file(
            path,
            format!(
                "size {} bytes is not a multiple of 24 (6 float32 per point: x y z r g b); \
                 the file is truncated or has another layout",
                bytes.len()
            ),
        ));
    }
    let mut points = Vec::with_capacity(bytes.len() / BYTES);
    for (index, chunk) in bytes.chunks_exact(BYTES).enumerate() {
        let p: Point = std::array::from_fn(|k| {
            f32::from_le_bytes(chunk[4 * k..4 * k + 4].try_into().expect("4 bytes"))
        });
        if let Some((k, v)) = bad_field(&p) {
            return Err(field_error(path, index, k, v));
        }
        points.push(p);
    }
    Ok(points)
}

pub fn read_points(path: &Path) -> Result<Vec<Point>> {
    parse_points(&read_regular(path, MAX_BINARY_BYTES)?, path)
}

pub fn encode_points(points: &[Point]) -> Vec<u8> {
    points
        .iter()
        .flat_map(|p| p.iter().flat_map(|v| v.to_le_bytes()))
        .collect()
}

/// Writes points atomically; a point the reader would refuse is not written.
pub fn write_points(path: &Path, points: &[Point]) -> Result<()> {
    for (index, p) in points.iter().enumerate() {
        if let Some((k, v)) = bad_field(p) {
            return Err(field_error(path, index, k, v));
        }
    }
    fusiondet_kitti::write_atomic(path, &encode_points(points))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000001.bin");
        let points = vec![
            [-1.5, 3.6, 0.4, 0.9, 1.0, 0.0],
            [0.0, 8.2, -1.4, 0.2, 0.3, 0.4],
        ];
        write_points(&path, &points).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), 48);
        assert_eq!(read_points(&path).unwrap(), points);
    }

    #[test]
    fn bad_files_are_refused_naming_the_point() {
        let path = Path::new("points/000017.bin");
        let err = parse_points(&[0; 25], path).unwrap_err().to_string();
        assert!(
            err.contains("points/000017.bin: size 25 bytes is not a multiple of 24"),
            "{err}"
        );
        let bad = [
            [0.0, 1.0, 0.0, 0.5, 0.5, 0.5],
            [0.0, f32::NAN, 0.0, 0.5, 0.5, 0.5],
        ];
        let err = parse_points(&encode_points(&bad), path)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(":1: field `y`: point 1 has a non-finite"),
            "{err}"
        );
        let bytes = encode_points(&[[0.0, 1.0, 0.0, 0.5, 128.0, 0.5]]);
        let err = parse_points(&bytes, path).unwrap_err().to_string();
        assert!(
            err.contains("field `g`: point 0 has a colour outside [0, 1]"),
            "{err}"
        );
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("x.bin");
        assert!(write_points(&out, &[[0.0, 1.0, 0.0, 0.5, 255.0, 0.5]]).is_err());
        assert!(!out.exists());
    }
}
