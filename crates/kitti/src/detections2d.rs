//! 2D detections in the F-PointNet / F-ConvNet text format:
//! `<image path> <type id: 1 Pedestrian, 2 Car, 3 Cyclist> <score> x1 y1 x2 y2`.
//! The frame id is the image file's stem.

use crate::error::{FormatError, Result, parse_finite, read_text};
use crate::label::{Box2d, ObjectClass};
use std::fmt::Write as _;
use std::path::Path;

/// One 2D detection of one image.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection2d {
    pub frame_id: String,
    pub class: ObjectClass,
    pub score: f64,
    pub bbox: Box2d,
}

/// The type ids of the format.
pub fn class_from_type_id(id: u32) -> Option<ObjectClass> {
    match id {
        1 => Some(ObjectClass::Pedestrian),
        2 => Some(ObjectClass::Car),
        3 => Some(ObjectClass::Cyclist),
        _ => None,
    }
}

pub fn type_id_of(class: ObjectClass) -> Option<u32> {
    match class {
        ObjectClass::Pedestrian => Some(1),
        ObjectClass::Car => Some(2),
        ObjectClass::Cyclist => Some(3),
        _ => None,
    }
}

pub fn parse_detections2d(text: &str, path: &Path) -> Result<Vec<Detection2d>> {
    const FIELDS: [&str; 7] = ["image path", "type id", "score", "x1", "y1", "x2", "y2"];
    let mut out = Vec::new();
    for (index, line) in text.lines().enumerate() {
        let line_no = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let cols: Vec<&str> = line.split_ascii_whitespace().collect();
        if cols.len() != 7 {
            return Err(FormatError::field(
                path,
                line_no,
                FIELDS[cols.len().min(6)],
                format!(
                    "expected 7 columns `<image path> <type id> <score> x1 y1 x2 y2`, found {}",
                    cols.len()
                ),
            ));
        }
        let frame_id = Path::new(cols[0])
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .filter(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
            .ok_or_else(|| {
                FormatError::field(
                    path,
                    line_no,
                    "image path",
                    format!("`{}` does not end in a frame id like 000042.png", cols[0]),
                )
            })?;
        let class = cols[1]
            .parse::<u32>()
            .ok()
            .and_then(class_from_type_id)
            .ok_or_else(|| {
                FormatError::field(
                    path,
                    line_no,
                    "type id",
                    format!(
                        "`{}` is not 1 (Pedestrian), 2 (Car) or 3 (Cyclist)",
                        cols[1]
                    ),
                )
            })?;
        let mut v = [0.0; 5];
        for (k, slot) in v.iter_mut().enumerate() {
            *slot = parse_finite(path, line_no, FIELDS[k + 2], cols[k + 2])?;
        }
        out.push(Detection2d {
            frame_id,
            class,
            score: v[0],
            bbox: Box2d {
                x1: v[1],
                y1: v[2],
                x2: v[3],
                y2: v[4],
            },
        });
    }
    Ok(out)
}

pub fn read_detections2d(path: &Path) -> Result<Vec<Detection2d>> {
    parse_detections2d(&read_text(path)?, path)
}

/// Formats detections; `image_prefix` is prepended to `<frame>.png` (F-PointNet files
/// use `dataset/KITTI/object/training/image_2/`). Classes without a type id are skipped.
pub fn format_detections2d(dets: &[Detection2d], image_prefix: &str) -> String {
    let mut out = String::new();
    for d in dets {
        let Some(type_id) = type_id_of(d.class) else {
            continue;
        };
        let _ = writeln!(
            out,
            "{image_prefix}{}.png {type_id} {:.6} {:.2} {:.2} {:.2} {:.2}",
            d.frame_id, d.score, d.bbox.x1, d.bbox.y1, d.bbox.x2, d.bbox.y2
        );
    }
    out
}

pub fn write_detections2d(path: &Path, dets: &[Detection2d], image_prefix: &str) -> Result<()> {
    crate::atomic::write_atomic(path, format_detections2d(dets, image_prefix).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "dataset/KITTI/object/training/image_2/000001.png 2 0.998467 389 181 424 202\n\
dataset/KITTI/object/training/image_2/000001.png 3 0.741964 677 165 689 191\n";

    #[test]
    fn parses_fpointnet_lines() {
        let d = parse_detections2d(SAMPLE, Path::new("rgb.txt")).unwrap();
        assert_eq!(d.len(), 2);
        assert_eq!(d[0].frame_id, "000001");
        assert_eq!(d[0].class, ObjectClass::Car);
        assert_eq!(d[1].class, ObjectClass::Cyclist);
        assert_eq!(d[1].bbox.y2, 191.0);
    }

    #[test]
    fn round_trips() {
        let d = parse_detections2d(SAMPLE, Path::new("rgb.txt")).unwrap();
        let text = format_detections2d(&d, "dataset/KITTI/object/training/image_2/");
        assert_eq!(parse_detections2d(&text, Path::new("rgb.txt")).unwrap(), d);
    }

    #[test]
    fn bad_type_id_and_short_lines_are_named() {
        let err = parse_detections2d("a/000001.png 7 0.5 1 2 3 4", Path::new("rgb.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("rgb.txt:1: field `type id`"), "{err}");
        let err = parse_detections2d("a/000001.png 2 0.5 1 2", Path::new("rgb.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("expected 7 columns"), "{err}");
    }
}
