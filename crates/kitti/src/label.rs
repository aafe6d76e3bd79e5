//! `label_2` ground truth (15 columns) and detection results (16 columns, with score).

use crate::error::{FormatError, Result, parse_finite, read_text};
pub use fusiondet_geometry::{Box2d, Box3d};
use std::fmt::Write as _;
use std::path::Path;

/// The object classes of the KITTI object benchmark, spelled as in its files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ObjectClass {
    Car,
    Van,
    Truck,
    Pedestrian,
    PersonSitting,
    Cyclist,
    Tram,
    Misc,
    DontCare,
}

impl ObjectClass {
    pub const ALL: [ObjectClass; 9] = [
        ObjectClass::Car,
        ObjectClass::Van,
        ObjectClass::Truck,
        ObjectClass::Pedestrian,
        ObjectClass::PersonSitting,
        ObjectClass::Cyclist,
        ObjectClass::Tram,
        ObjectClass::Misc,
        ObjectClass::DontCare,
    ];

    /// The three classes the benchmark evaluates.
    pub const EVALUATED: [ObjectClass; 3] = [
        ObjectClass::Car,
        ObjectClass::Pedestrian,
        ObjectClass::Cyclist,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            ObjectClass::Car => "Car",
            ObjectClass::Van => "Van",
            ObjectClass::Truck => "Truck",
            ObjectClass::Pedestrian => "Pedestrian",
            ObjectClass::PersonSitting => "Person_sitting",
            ObjectClass::Cyclist => "Cyclist",
            ObjectClass::Tram => "Tram",
            ObjectClass::Misc => "Misc",
            ObjectClass::DontCare => "DontCare",
        }
    }

    /// Parses a class name exactly as KITTI spells it.
    pub fn parse(name: &str) -> Option<ObjectClass> {
        ObjectClass::ALL.into_iter().find(|c| c.as_str() == name)
    }
}

impl std::fmt::Display for ObjectClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for ObjectClass {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        ObjectClass::parse(s).ok_or_else(|| {
            let names: Vec<_> = ObjectClass::ALL.iter().map(|c| c.as_str()).collect();
            format!("unknown class `{s}` (expected one of {})", names.join(", "))
        })
    }
}

/// One line of a `label_2` or result file.
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    pub class: ObjectClass,
    /// Fraction of the object leaving the image, in [0, 1] (-1 for DontCare).
    pub truncation: f64,
    /// 0 fully visible, 1 partly occluded, 2 largely occluded, 3 unknown (-1 for DontCare).
    pub occlusion: i32,
    /// Observation angle in [-pi, pi].
    pub alpha: f64,
    pub bbox: Box2d,
    pub box3d: Box3d,
    /// Present on detections (16th column), absent on ground truth.
    pub score: Option<f64>,
}

const FIELDS: [&str; 16] = [
    "type",
    "truncated",
    "occluded",
    "alpha",
    "bbox_left",
    "bbox_top",
    "bbox_right",
    "bbox_bottom",
    "height",
    "width",
    "length",
    "x",
    "y",
    "z",
    "rotation_y",
    "score",
];

/// Parses the text of a label or result file. `path` is only used in error messages.
/// Ground truth lines have 15 columns, detections 16 (the score); both are accepted,
/// anything else is an error. Blank lines are skipped.
pub fn parse_objects(text: &str, path: &Path) -> Result<Vec<Object>> {
    let mut objects = Vec::new();
    for (index, line) in text.lines().enumerate() {
        let line_no = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let cols: Vec<&str> = line.split_ascii_whitespace().collect();
        if cols.len() != 15 && cols.len() != 16 {
            return Err(FormatError::field(
                path,
                line_no,
                FIELDS[cols.len().min(15)],
                format!(
                    "expected 15 columns (ground truth) or 16 (detection with score), found {}",
                    cols.len()
                ),
            ));
        }
        let class = cols[0]
            .parse::<ObjectClass>()
            .map_err(|m| FormatError::field(path, line_no, "type", m))?;
        let mut num = [0.0f64; 16];
        for (i, col) in cols.iter().enumerate().skip(1) {
            num[i] = parse_finite(path, line_no, FIELDS[i], col)?;
        }
        let occlusion = num[2];
        if occlusion.fract() != 0.0 || !(-1.0..=3.0).contains(&occlusion) {
            return Err(FormatError::field(
                path,
                line_no,
                "occluded",
                format!("`{}` is not one of -1, 0, 1, 2, 3", cols[2]),
            ));
        }
        // A box of negative size has no volume to overlap: evaluation would match it in
        // bird's-eye view but never in 3D, and a database would store it. Only DontCare
        // regions carry KITTI's -1 placeholders.
        if class != ObjectClass::DontCare
            && let Some(k) = (8..=10).find(|&k| num[k] < 0.0)
        {
            return Err(FormatError::field(
                path,
                line_no,
                FIELDS[k],
                format!(
                    "`{}` is negative; a box's height, width and length are sizes in metres (≥ 0)",
                    cols[k]
                ),
            ));
        }
        objects.push(Object {
            class,
            truncation: num[1],
            occlusion: occlusion as i32,
            alpha: num[3],
            bbox: Box2d {
                x1: num[4],
                y1: num[5],
                x2: num[6],
                y2: num[7],
            },
            box3d: Box3d {
                h: num[8],
                w: num[9],
                l: num[10],
                x: num[11],
                y: num[12],
                z: num[13],
                ry: num[14],
            },
            score: (cols.len() == 16).then_some(num[15]),
        });
    }
    Ok(objects)
}

/// Reads a `label_2` or result file.
pub fn read_objects(path: &Path) -> Result<Vec<Object>> {
    parse_objects(&read_text(path)?, path)
}

/// The real-valued fields of `o` after `occluded`, in file order (alpha, the 2D box, the
/// 3D box), with their names.
fn box_fields(o: &Object) -> [(&'static str, f64); 12] {
    let (b, d) = (&o.bbox, &o.box3d);
    let values = [
        o.alpha, b.x1, b.y1, b.x2, b.y2, d.h, d.w, d.l, d.x, d.y, d.z, d.ry,
    ];
    std::array::from_fn(|i| (FIELDS[3 + i], values[i]))
}

/// Formats objects as KITTI lines (2 decimals like the official files; score with 4).
pub fn format_objects(objects: &[Object]) -> String {
    let mut out = String::new();
    for o in objects {
        let _ = write!(out, "{} {:.2} {}", o.class, o.truncation, o.occlusion);
        for (_, v) in box_fields(o) {
            let _ = write!(out, " {v:.2}");
        }
        if let Some(score) = o.score {
            let _ = write!(out, " {score:.4}");
        }
        out.push('\n');
    }
    out
}

/// Writes objects to `path` atomically. A NaN or infinite value is refused (naming the line
/// and field it would have had): no KITTI reader, ours included, accepts it back, and an
/// evaluation of such a file would be meaningless.
pub fn write_objects(path: &Path, objects: &[Object]) -> Result<()> {
    for (i, o) in objects.iter().enumerate() {
        if let Some((field, value)) = first_non_finite_field(o) {
            return Err(FormatError::field(
                path,
                i + 1,
                field,
                format!("{value} is not a number to write; nothing was written"),
            ));
        }
    }
    crate::atomic::write_atomic(path, format_objects(objects).as_bytes())
}

/// The first numeric field of `o` (in file order) that is NaN or infinite.
fn first_non_finite_field(o: &Object) -> Option<(&'static str, f64)> {
    std::iter::once(("truncated", o.truncation))
        .chain(box_fields(o))
        .chain(o.score.map(|v| ("score", v)))
        .find(|(_, v)| !v.is_finite())
}

#[cfg(test)]
mod negative_size_tests {
    use super::*;

    #[test]
    fn negative_sizes_are_refused_except_for_dont_care() {
        let path = Path::new("r/000001.txt");
        let line = |h: &str| format!("Car 0 0 0 0 0 10 10 {h} 1.6 3.9 1 1.5 10 0 0.9\n");
        let err = parse_objects(&line("-1.5"), path).unwrap_err().to_string();
        assert!(err.contains("r/000001.txt:1: field `height`"), "{err}");
        parse_objects(&line("1.5"), path).unwrap();
        parse_objects(
            "DontCare -1 -1 -10 503 169 590 190 -1 -1 -1 -1000 -1000 -1000 -10\n",
            path,
        )
        .unwrap();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GT: &str = "Truck 0.00 0 -1.57 599.41 156.40 629.75 189.25 2.85 2.63 12.34 0.47 1.49 69.44 -1.56\n\
Cyclist 0.00 3 -1.65 676.60 163.95 688.98 193.93 1.86 0.60 2.02 4.59 1.32 45.84 -1.55\n\
DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10\n";

    fn p() -> &'static Path {
        Path::new("label_2/000001.txt")
    }

    #[test]
    fn parses_ground_truth_lines() {
        let objs = parse_objects(GT, p()).unwrap();
        assert_eq!(objs.len(), 3);
        assert_eq!(objs[0].class, ObjectClass::Truck);
        assert_eq!(objs[1].occlusion, 3);
        assert_eq!(objs[1].box3d.z, 45.84);
        assert_eq!(objs[2].class, ObjectClass::DontCare);
        assert!(objs.iter().all(|o| o.score.is_none()));
    }

    #[test]
    fn round_trips_detections_with_scores() {
        let mut objs = parse_objects(GT, p()).unwrap();
        objs[0].score = Some(0.8424);
        let text = format_objects(&objs);
        let back = parse_objects(&text, p()).unwrap();
        assert_eq!(back, objs);
    }

    #[test]
    fn short_line_names_file_line_and_field() {
        let err = parse_objects("Car 0 0 1.0 1 2 3\n", p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("label_2/000001.txt:1"), "{err}");
        assert!(err.contains("expected 15 columns"), "{err}");
    }

    #[test]
    fn non_numeric_field_is_named() {
        let line =
            "\nCar 0.00 0 -1.57 599.41 abc 629.75 189.25 2.85 2.63 12.34 0.47 1.49 69.44 -1.56\n";
        let err = parse_objects(line, p()).unwrap_err().to_string();
        assert!(err.contains(":2: field `bbox_top`"), "{err}");
    }

    #[test]
    fn nan_and_inf_are_rejected() {
        for bad in ["nan", "inf", "-inf", "NaN"] {
            let line = format!(
                "Car 0.00 0 -1.57 599.41 156.40 629.75 189.25 2.85 2.63 12.34 0.47 1.49 {bad} -1.56"
            );
            let err = parse_objects(&line, p()).unwrap_err().to_string();
            assert!(err.contains("field `z`"), "{err}");
        }
    }

    #[test]
    fn unknown_class_is_rejected() {
        let line =
            "Bus 0.00 0 -1.57 599.41 156.40 629.75 189.25 2.85 2.63 12.34 0.47 1.49 69.44 -1.56";
        let err = parse_objects(line, p()).unwrap_err().to_string();
        assert!(err.contains("unknown class `Bus`"), "{err}");
    }

    #[test]
    fn fractional_occlusion_is_rejected() {
        let line =
            "Car 0.00 1.5 -1.57 599.41 156.40 629.75 189.25 2.85 2.63 12.34 0.47 1.49 69.44 -1.56";
        let err = parse_objects(line, p()).unwrap_err().to_string();
        assert!(err.contains("field `occluded`"), "{err}");
    }

    #[test]
    fn missing_file_is_an_io_error_with_path() {
        let err = read_objects(Path::new("/no/such/label.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/no/such/label.txt"), "{err}");
    }

    #[test]
    fn non_finite_values_are_never_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000001.txt");
        let mut objects = parse_objects(GT, p()).unwrap();
        write_objects(&path, &objects).unwrap();
        let before = std::fs::read(&path).unwrap();
        objects[1].box3d.z = f64::NAN;
        let err = write_objects(&path, &objects).unwrap_err().to_string();
        assert!(err.contains("000001.txt:2: field `z`: NaN"), "{err}");
        objects[1].box3d.z = 45.84;
        objects[0].score = Some(f64::INFINITY);
        let err = write_objects(&path, &objects).unwrap_err().to_string();
        assert!(err.contains(":1: field `score`: inf"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), before);
    }
}
