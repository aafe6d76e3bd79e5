//! `det_2d/<id>.txt`: a 2D detector's boxes for one scene, the input of frustum detection.
//! One detection per line, `class x1 y1 x2 y2 score` (pixels; the class spelled as in the
//! labels). KITTI's F-PointNet list puts every frame in one file; a file per scene keeps a
//! scene self-contained, like the rest of the prepared layout, and lets sharded runs write
//! their own scenes only.

use crate::io::{content_lines, parse_finite, read_text};
use fusiondet_geometry::Box2d;
use fusiondet_kitti::{FormatError, Result};
use std::fmt::Write as _;
use std::path::Path;

/// One 2D detection.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection2d {
    pub class: String,
    pub bbox: Box2d,
    pub score: f64,
}

const FIELDS: [&str; 6] = ["class", "x1", "y1", "x2", "y2", "score"];

/// Why a detection cannot be a line: the field and the message (shared by reader and
/// writer, so nothing is written that would not read back).
fn check(d: &Detection2d) -> std::result::Result<(), (&'static str, String)> {
    if d.class.is_empty()
        || d.class.chars().any(char::is_whitespace)
        || d.class.starts_with('#')
        || d.class.parse::<f64>().is_ok()
    {
        return Err((
            "class",
            format!(
                "`{}` is no class name: the first field names the class (e.g. `chair`)",
                d.class
            ),
        ));
    }
    let b = &d.bbox;
    for (field, value) in FIELDS[1..].iter().zip([b.x1, b.y1, b.x2, b.y2, d.score]) {
        if !value.is_finite() {
            return Err((field, format!("{value} is not a finite number")));
        }
    }
    if b.x2 < b.x1 {
        return Err(("x2", format!("{} is left of x1 = {}", b.x2, b.x1)));
    }
    if b.y2 < b.y1 {
        return Err(("y2", format!("{} is above y1 = {}", b.y2, b.y1)));
    }
    Ok(())
}

/// Parses a detection file; `path` names it in errors.
pub fn parse_detections_2d(text: &str, path: &Path) -> Result<Vec<Detection2d>> {
    let mut out = Vec::new();
    for (line_no, line) in content_lines(text) {
        let cols: Vec<&str> = line.split_ascii_whitespace().collect();
        if cols.len() != FIELDS.len() {
            return Err(FormatError::field(
                path,
                line_no,
                FIELDS[cols.len().min(FIELDS.len() - 1)],
                format!(
                    "expected 6 fields (class x1 y1 x2 y2 score), found {}",
                    cols.len()
                ),
            ));
        }
        let mut num = [0.0f64; 6];
        for i in 1..6 {
            num[i] = parse_finite(path, line_no, FIELDS[i], cols[i])?;
        }
        let detection = Detection2d {
            class: cols[0].to_string(),
            bbox: Box2d {
                x1: num[1],
                y1: num[2],
                x2: num[3],
                y2: num[4],
            },
            score: num[5],
        };
        check(&detection).map_err(|(field, m)| FormatError::field(path, line_no, field, m))?;
        out.push(detection);
    }
    Ok(out)
}

/// Reads `det_2d/<id>.txt`.
pub fn read_detections_2d(path: &Path) -> Result<Vec<Detection2d>> {
    parse_detections_2d(&read_text(path)?, path)
}

/// The file's text: a header comment, then one line per detection in the shortest form
/// that reads back to the same f64.
pub fn format_detections_2d(detections: &[Detection2d]) -> String {
    let mut out = String::from("# class x1 y1 x2 y2 score  (2D box in pixels)\n");
    for d in detections {
        let b = &d.bbox;
        let _ = writeln!(
            out,
            "{} {} {} {} {} {}",
            d.class, b.x1, b.y1, b.x2, b.y2, d.score
        );
    }
    out
}

/// Writes detections atomically; one the reader would refuse is refused (naming the line
/// and field it would have had) and nothing is written.
pub fn write_detections_2d(path: &Path, detections: &[Detection2d]) -> Result<()> {
    for (i, d) in detections.iter().enumerate() {
        check(d).map_err(|(field, m)| {
            FormatError::field(path, i + 2, field, format!("{m}; nothing was written"))
        })?;
    }
    fusiondet_kitti::write_atomic(path, format_detections_2d(detections).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("det_2d/000017.txt")
    }

    fn detection(class: &str, x1: f64, score: f64) -> Detection2d {
        Detection2d {
            class: class.into(),
            bbox: Box2d {
                x1,
                y1: 147.1237,
                x2: 637.0,
                y2: 521.0,
            },
            score,
        }
    }

    #[test]
    fn detections_round_trip_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000017.txt");
        let dets = vec![
            detection("bed", 176.3712, 0.987654321),
            detection("lamp", 0.1 + 0.2, 1e-9),
        ];
        write_detections_2d(&path, &dets).unwrap();
        assert_eq!(read_detections_2d(&path).unwrap(), dets);
        write_detections_2d(&path, &[]).unwrap();
        assert!(read_detections_2d(&path).unwrap().is_empty());
    }

    #[test]
    fn bad_lines_name_file_line_and_field() {
        let err = |text: &str| parse_detections_2d(text, p()).unwrap_err().to_string();
        let e = err("# head\nbed 1 2 3 4\n");
        assert!(
            e.contains("det_2d/000017.txt:2: field `score`: expected 6 fields"),
            "{e}"
        );
        let e = err("bed 1 2 3 4 0.5 7\n");
        assert!(e.contains(":1: field `score`: expected 6"), "{e}");
        let e = err("bed 1 2 x 4 0.5\n");
        assert!(e.contains(":1: field `x2`: `x` is not a number"), "{e}");
        let e = err("bed 5 2 3 4 0.5\n");
        assert!(e.contains(":1: field `x2`: 3 is left of x1 = 5"), "{e}");
        let e = err("bed 1 9 3 4 0.5\n");
        assert!(e.contains(":1: field `y2`: 4 is above y1 = 9"), "{e}");
        let e = err("0.5 1 2 3 4 0.5\n");
        assert!(e.contains(":1: field `class`"), "{e}");
        let e = err("bed 1 2 3 4 inf\n");
        assert!(
            e.contains(":1: field `score`: `inf` is not a finite"),
            "{e}"
        );
    }

    #[test]
    fn an_unreadable_detection_is_not_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000017.txt");
        let err = write_detections_2d(&path, &[detection("bed", 700.0, 0.5)])
            .unwrap_err()
            .to_string();
        assert!(err.contains(":2: field `x2`"), "{err}");
        assert!(!path.exists());
    }
}
