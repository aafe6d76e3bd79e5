//! `label/<id>.txt` (ground truth, 12 fields a line) and result files (13, the score last):
//! `class cx cy cz dx dy dz yaw x1 y1 x2 y2 [score]`, boxes in upright depth (crate docs).

use crate::io::{content_lines, parse_finite, read_text};
use fusiondet_geometry::Box2d;
use fusiondet_kitti::{FormatError, Result};
use std::fmt::Write as _;
use std::path::Path;

/// The ten classes SUN RGB-D's 3D detection is evaluated on, in the class-id order indoor
/// detectors use (VoteNet's `type2class`: bed = 0 … bathtub = 9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SunClass {
    Bed,
    Table,
    Sofa,
    Chair,
    Toilet,
    Desk,
    Dresser,
    NightStand,
    Bookshelf,
    Bathtub,
}

impl SunClass {
    pub const ALL: [SunClass; 10] = [
        SunClass::Bed,
        SunClass::Table,
        SunClass::Sofa,
        SunClass::Chair,
        SunClass::Toilet,
        SunClass::Desk,
        SunClass::Dresser,
        SunClass::NightStand,
        SunClass::Bookshelf,
        SunClass::Bathtub,
    ];

    /// The name as the files spell it.
    pub fn as_str(self) -> &'static str {
        match self {
            SunClass::Bed => "bed",
            SunClass::Table => "table",
            SunClass::Sofa => "sofa",
            SunClass::Chair => "chair",
            SunClass::Toilet => "toilet",
            SunClass::Desk => "desk",
            SunClass::Dresser => "dresser",
            SunClass::NightStand => "night_stand",
            SunClass::Bookshelf => "bookshelf",
            SunClass::Bathtub => "bathtub",
        }
    }

    /// The class a file's name means, if it is one of the ten (exact spelling).
    pub fn parse(name: &str) -> Option<SunClass> {
        SunClass::ALL.into_iter().find(|c| c.as_str() == name)
    }

    /// The class id (position in [`SunClass::ALL`]).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The mean box size (dx, dy, dz) of the class over SUN RGB-D's training labels, in
    /// metres, dx along the heading: VoteNet's `type_mean_size`, which indoor detectors use
    /// as size anchors (facts carried over, so the simulator and the detectors share one
    /// table).
    #[allow(clippy::excessive_precision)]
    pub fn mean_size(self) -> [f64; 3] {
        match self {
            SunClass::Bed => [2.114256, 1.620300, 0.927272],
            SunClass::Table => [0.791118, 1.279516, 0.718182],
            SunClass::Sofa => [0.923508, 1.867419, 0.845495],
            SunClass::Chair => [0.591958, 0.552978, 0.827272],
            SunClass::Toilet => [0.699104, 0.454178, 0.756250],
            SunClass::Desk => [0.695190, 1.346299, 0.736364],
            SunClass::Dresser => [0.528526, 1.002642, 1.172878],
            SunClass::NightStand => [0.500618, 0.632163, 0.683424],
            SunClass::Bookshelf => [0.404671, 1.071108, 1.688889],
            SunClass::Bathtub => [0.765840, 1.398258, 0.472728],
        }
    }
}

impl std::fmt::Display for SunClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An oriented box in upright depth: centre, full sizes, yaw about +z (crate docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UprightBox {
    /// Centre (x, y, z) in metres.
    pub centre: [f64; 3],
    /// Full extents (dx, dy, dz) along the box's own axes; dz is vertical.
    pub size: [f64; 3],
    /// Counter-clockwise from +x to the `dx` side, seen from above, radians.
    pub yaw: f64,
}

impl UprightBox {
    /// The footprint's corners (x, y), counter-clockwise seen from above.
    pub fn bev_corners(&self) -> [[f64; 2]; 4] {
        let (s, c) = self.yaw.sin_cos();
        let (hx, hy) = (0.5 * self.size[0], 0.5 * self.size[1]);
        [(hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)].map(|(a, b)| {
            [
                self.centre[0] + c * a - s * b,
                self.centre[1] + s * a + c * b,
            ]
        })
    }

    /// The vertical extent (bottom, top).
    pub fn z_range(&self) -> (f64, f64) {
        let h = 0.5 * self.size[2];
        (self.centre[2] - h, self.centre[2] + h)
    }

    /// The eight corners: the footprint at the bottom, then at the top.
    pub fn corners(&self) -> [[f64; 3]; 8] {
        let bev = self.bev_corners();
        let (lo, hi) = self.z_range();
        std::array::from_fn(|i| {
            let [x, y] = bev[i % 4];
            [x, y, if i < 4 { lo } else { hi }]
        })
    }

    /// Whether `p` lies inside the box or on its boundary.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (p[0] - self.centre[0], p[1] - self.centre[1]);
        let (a, b) = (c * dx + s * dy, -s * dx + c * dy);
        a.abs() <= 0.5 * self.size[0]
            && b.abs() <= 0.5 * self.size[1]
            && (p[2] - self.centre[2]).abs() <= 0.5 * self.size[2]
    }
}

/// One line of a label or result file.
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    /// The class name as written; see [`Object::sun_class`].
    pub class: String,
    pub box3d: UprightBox,
    /// The 2D box in pixels.
    pub bbox: Box2d,
    /// Present on detections (13th field), absent on ground truth.
    pub score: Option<f64>,
}

impl Object {
    /// The evaluated class this object is, or `None` for any other name.
    pub fn sun_class(&self) -> Option<SunClass> {
        SunClass::parse(&self.class)
    }
}

/// The fields of a line, in order.
pub const FIELDS: [&str; 13] = [
    "class", "cx", "cy", "cz", "dx", "dy", "dz", "yaw", "x1", "y1", "x2", "y2", "score",
];

/// What a file holds: ground truth has 12 fields a line, results 13.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineKind {
    Label,
    Result,
}

/// Why an object cannot be a line: the field and the message. Shared by the reader and the
/// writer, so that nothing is written that would not read back.
fn check(o: &Object) -> std::result::Result<(), (&'static str, String)> {
    if o.class.is_empty() || o.class.chars().any(char::is_whitespace) {
        return Err((
            "class",
            format!("`{}` is no class name (one word, no spaces)", o.class),
        ));
    }
    if o.class.starts_with('#') || o.class.parse::<f64>().is_ok() {
        return Err((
            "class",
            format!(
                "`{}` is no class name: the first field names the class (e.g. `chair`)",
                o.class
            ),
        ));
    }
    for (field, value) in numeric_fields(o) {
        if !value.is_finite() {
            return Err((field, format!("{value} is not a finite number")));
        }
    }
    for (k, field) in ["dx", "dy", "dz"].into_iter().enumerate() {
        if o.box3d.size[k] <= 0.0 {
            return Err((
                field,
                format!(
                    "size {} is not positive: sizes are the box's full extents in metres",
                    o.box3d.size[k]
                ),
            ));
        }
    }
    if o.bbox.x2 < o.bbox.x1 {
        return Err(("x2", format!("{} is left of x1 = {}", o.bbox.x2, o.bbox.x1)));
    }
    if o.bbox.y2 < o.bbox.y1 {
        return Err(("y2", format!("{} is above y1 = {}", o.bbox.y2, o.bbox.y1)));
    }
    Ok(())
}

/// The numeric fields of `o` in file order (the score last, when present).
fn numeric_fields(o: &Object) -> impl Iterator<Item = (&'static str, f64)> {
    let (b, d) = (&o.box3d, &o.bbox);
    let values = [
        b.centre[0],
        b.centre[1],
        b.centre[2],
        b.size[0],
        b.size[1],
        b.size[2],
        b.yaw,
        d.x1,
        d.y1,
        d.x2,
        d.y2,
    ];
    (1..12)
        .map(move |i| (FIELDS[i], values[i - 1]))
        .chain(o.score.map(|s| ("score", s)))
}

/// Parses a label (`LineKind::Label`, 12 fields) or result file (13 fields). `path` names
/// the file in errors. A class name not among the ten is kept, not refused.
pub fn parse_objects(text: &str, path: &Path, kind: LineKind) -> Result<Vec<Object>> {
    let expected = match kind {
        LineKind::Label => 12,
        LineKind::Result => 13,
    };
    let mut objects = Vec::new();
    for (line_no, line) in content_lines(text) {
        let cols: Vec<&str> = line.split_ascii_whitespace().collect();
        if cols.len() != expected {
            let (field, message) = match (kind, cols.len()) {
                (LineKind::Result, 12) => (
                    "score",
                    "missing: a result line has 13 fields, the last one the detection score"
                        .to_string(),
                ),
                (LineKind::Label, 13) => (
                    "score",
                    "a label line has 12 fields (class cx cy cz dx dy dz yaw x1 y1 x2 y2); \
                     a 13th, a score, belongs in result files"
                        .to_string(),
                ),
                (_, n) => (
                    FIELDS[n.min(expected - 1)],
                    format!(
                        "expected {expected} fields (class cx cy cz dx dy dz yaw x1 y1 x2 y2{}), found {n}",
                        if kind == LineKind::Result {
                            " score"
                        } else {
                            ""
                        }
                    ),
                ),
            };
            return Err(FormatError::field(path, line_no, field, message));
        }
        let mut num = [0.0f64; 13];
        for (i, col) in cols.iter().enumerate().skip(1) {
            num[i] = parse_finite(path, line_no, FIELDS[i], col)?;
        }
        let object = Object {
            class: cols[0].to_string(),
            box3d: UprightBox {
                centre: [num[1], num[2], num[3]],
                size: [num[4], num[5], num[6]],
                yaw: num[7],
            },
            bbox: Box2d {
                x1: num[8],
                y1: num[9],
                x2: num[10],
                y2: num[11],
            },
            score: (kind == LineKind::Result).then_some(num[12]),
        };
        check(&object).map_err(|(field, m)| FormatError::field(path, line_no, field, m))?;
        objects.push(object);
    }
    Ok(objects)
}

/// Reads a ground-truth file (`label/<id>.txt`).
pub fn read_labels(path: &Path) -> Result<Vec<Object>> {
    parse_objects(&read_text(path)?, path, LineKind::Label)
}

/// Reads a result file: every line needs its score.
pub fn read_results(path: &Path) -> Result<Vec<Object>> {
    parse_objects(&read_text(path)?, path, LineKind::Result)
}

/// The header comment of written files.
const HEADER: &str = "# class cx cy cz dx dy dz yaw x1 y1 x2 y2";

/// Formats objects as lines under a header comment. Numbers are written in Rust's shortest
/// form that reads back to the same f64, so a written file reads back bit for bit.
pub fn format_objects(objects: &[Object]) -> String {
    let mut out = String::from(HEADER);
    if objects.first().is_some_and(|o| o.score.is_some()) {
        out.push_str(" score");
    }
    out.push_str("  (upright depth: x right, y forward, z up, metres; yaw about +z, radians; 2D box in pixels)\n");
    for o in objects {
        out.push_str(&o.class);
        for (_, v) in numeric_fields(o) {
            let _ = write!(out, " {v}");
        }
        out.push('\n');
    }
    out
}

/// Writes labels (objects without scores) or results (every object with one) atomically.
/// An object the readers would refuse, or a file mixing lines with and without scores, is
/// refused (naming the line and field it would have had) and nothing is written.
pub fn write_objects(path: &Path, objects: &[Object]) -> Result<()> {
    let with_score = objects.first().is_some_and(|o| o.score.is_some());
    for (i, o) in objects.iter().enumerate() {
        if o.score.is_some() != with_score {
            return Err(FormatError::field(
                path,
                i + 2,
                "score",
                "a file holds labels (no score) or results (a score on every line), not both; \
                 nothing was written",
            ));
        }
        check(o).map_err(|(field, m)| {
            FormatError::field(path, i + 2, field, format!("{m}; nothing was written"))
        })?;
    }
    fusiondet_kitti::write_atomic(path, format_objects(objects).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The real ground truth of scene 000017 (the fixture's), header included.
    const GT: &str = "# class cx cy cz dx dy dz yaw x1 y1 x2 y2  (3D box centre and full sizes in upright-depth coordinates, yaw about z in radians; 2D box in pixels)
night_stand -1.507576 3.3 -0.901539 0.350458 0.6383 0.703078 -1.1186423617081755 54.94983 233.0936 187.00673 360.719
bed -0.013872 2.993747 -0.561364 2.292754 1.5798 1.277272 -1.1051997599457748 176.3712 147.1237 637.0 521.0
";

    fn p() -> &'static Path {
        Path::new("label/000017.txt")
    }

    fn label_err(text: &str) -> String {
        parse_objects(text, p(), LineKind::Label)
            .unwrap_err()
            .to_string()
    }

    fn result_err(text: &str) -> String {
        parse_objects(text, p(), LineKind::Result)
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn reads_the_prepared_ground_truth() {
        let objects = parse_objects(GT, p(), LineKind::Label).unwrap();
        assert_eq!(objects.len(), 2);
        assert_eq!(objects[0].sun_class(), Some(SunClass::NightStand));
        assert_eq!(objects[1].class, "bed");
        assert_eq!(objects[1].box3d.centre, [-0.013872, 2.993747, -0.561364]);
        assert_eq!(objects[1].box3d.size, [2.292754, 1.5798, 1.277272]);
        assert_eq!(objects[1].box3d.yaw, -1.1051997599457748);
        assert_eq!(objects[1].bbox.x2, 637.0);
        assert!(objects.iter().all(|o| o.score.is_none()));
    }

    /// A byte-order mark (some editors write one) is not part of the first class name:
    /// the first box is read, not dropped.
    #[test]
    fn a_byte_order_mark_does_not_drop_the_first_box() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000001.txt");
        let first = GT.lines().find(|l| !l.starts_with('#')).unwrap();
        std::fs::write(&path, format!("\u{feff}{first}\n")).unwrap();
        let objects = read_labels(&path).unwrap();
        assert_eq!(objects.len(), 1);
        assert_eq!(objects[0].sun_class(), Some(SunClass::NightStand));
    }

    #[test]
    fn labels_and_results_round_trip_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let labels = parse_objects(GT, p(), LineKind::Label).unwrap();
        let path = dir.path().join("000017.txt");
        write_objects(&path, &labels).unwrap();
        assert_eq!(read_labels(&path).unwrap(), labels);
        let mut results = labels.clone();
        results[0].score = Some(0.123456789);
        results[1].score = Some(1e-7);
        results[1].box3d.yaw = std::f64::consts::PI;
        write_objects(&path, &results).unwrap();
        assert_eq!(read_results(&path).unwrap(), results);
        // A result file is no label file and the reverse.
        let err = read_labels(&path).unwrap_err().to_string();
        assert!(err.contains("000017.txt:2: field `score`"), "{err}");
    }

    #[test]
    fn a_class_outside_the_ten_is_kept() {
        let line = "lamp 0 1 0 0.3 0.3 0.5 0 0 0 10 10\n";
        let objects = parse_objects(line, p(), LineKind::Label).unwrap();
        assert_eq!(objects[0].class, "lamp");
        assert_eq!(objects[0].sun_class(), None);
    }

    #[test]
    fn bad_lines_name_file_line_and_field() {
        let err = label_err("# header\nbed 0 1 0 2 1.5 1 0 0 0 10\n");
        assert!(
            err.contains("label/000017.txt:2: field `y2`: expected 12 fields"),
            "{err}"
        );
        let err = label_err("bed 0 1 0 2 1.5 1 0 0 0 10 10 0.9 7\n");
        assert!(err.contains(":1: field `y2`: expected 12 fields"), "{err}");
        let err = label_err("bed 0 1 0 2 x 1 0 0 0 10 10\n");
        assert!(err.contains(":1: field `dy`: `x` is not a number"), "{err}");
        let err = label_err("bed 0 1 0 2 1.5 -1 0 0 0 10 10\n");
        assert!(
            err.contains(":1: field `dz`: size -1 is not positive"),
            "{err}"
        );
        let err = label_err("bed 0 1 0 0 1.5 1 0 0 0 10 10\n");
        assert!(err.contains("field `dx`: size 0 is not positive"), "{err}");
        let err = label_err("bed 0 1 0 2 1.5 1 nan 0 0 10 10\n");
        assert!(err.contains("field `yaw`: `nan` is not a finite"), "{err}");
        let err = label_err("bed 0 1 0 2 1.5 1 0 10 0 5 10\n");
        assert!(err.contains("field `x2`: 5 is left of x1 = 10"), "{err}");
        // A line without its class is short by one; one with a number there is refused.
        let err = label_err("1.5 0 1 0 2 1.5 1 0 0 0 10 10\n");
        assert!(err.contains("field `class`"), "{err}");
    }

    #[test]
    fn a_result_line_without_a_score_is_an_error() {
        let err =
            result_err("bed 0 1 0 2 1.5 1 0 0 0 10 10 0.9\n\nchair 0 1 0 1 1 1 0 0 0 10 10\n");
        assert!(
            err.contains("label/000017.txt:3: field `score`: missing"),
            "{err}"
        );
        let err = result_err("bed 0 1 0 2 1.5 1 0 0 0 10 10 inf\n");
        assert!(err.contains(":1: field `score`"), "{err}");
    }

    #[test]
    fn nothing_unreadable_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000001.txt");
        let mut objects = parse_objects(GT, p(), LineKind::Label).unwrap();
        objects[1].box3d.size[1] = -1.0;
        let err = write_objects(&path, &objects).unwrap_err().to_string();
        assert!(err.contains("000001.txt:3: field `dy`"), "{err}");
        objects[1].box3d.size[1] = 1.0;
        objects[1].score = Some(0.5);
        let err = write_objects(&path, &objects).unwrap_err().to_string();
        assert!(
            err.contains(":3: field `score`: a file holds labels"),
            "{err}"
        );
        objects[1].score = None;
        objects[0].class = "night stand".into();
        let err = write_objects(&path, &objects).unwrap_err().to_string();
        assert!(err.contains(":2: field `class`"), "{err}");
        assert!(!path.exists());
    }

    #[test]
    fn box_geometry() {
        let b = UprightBox {
            centre: [1.0, 2.0, 0.5],
            size: [4.0, 2.0, 1.0],
            yaw: std::f64::consts::FRAC_PI_2,
        };
        // The dx side runs along +y after a quarter turn.
        let c = b.bev_corners();
        let near = |a: [f64; 2], e: [f64; 2]| (a[0] - e[0]).abs() + (a[1] - e[1]).abs() < 1e-12;
        assert!(near(c[0], [0.0, 4.0]), "{c:?}");
        assert!(near(c[2], [2.0, 0.0]), "{c:?}");
        assert_eq!(b.z_range(), (0.0, 1.0));
        assert!(b.contains([1.0, 3.9, 0.9]) && !b.contains([2.1, 2.0, 0.5]));
        assert_eq!(b.corners()[5][2], 1.0);
        let area = fusiondet_geometry::iou::signed_area(&c);
        assert!((area - 8.0).abs() < 1e-12, "counter-clockwise: {area}");
    }
}
