//! `calib/<id>.txt`: the depth-to-image matrix of one scene. The prepared files hold this
//! one 3×3 matrix (three rows of three numbers under a `#` comment), which is SUN RGB-D's
//! camera matrix K composed with its tilt `Rtilt` and the axis change from upright depth to
//! the camera: M = K · F · Rtiltᵀ ([`Calib::from_camera`]); a pixel is
//! [u·w, v·w, w] = M · [x, y, z].

use crate::io::{content_lines, parse_finite, read_text};
use fusiondet_kitti::{FormatError, Result};
use std::fmt::Write as _;
use std::path::Path;

/// A 3×3 matrix, row-major.
pub type Mat33 = [[f64; 3]; 3];

/// The calibration of one scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Calib {
    /// Upright depth (x right, y forward, z up) → homogeneous pixel coordinates.
    pub depth_to_image: Mat33,
}

/// Upright depth (before the tilt) → camera (x right, y down, z forward): camera x = x,
/// camera y = −z, camera z = y.
pub const DEPTH_TO_CAMERA: Mat33 = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]];

pub(crate) fn mul(a: &Mat33, b: &Mat33) -> Mat33 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

pub(crate) fn transpose(a: &Mat33) -> Mat33 {
    std::array::from_fn(|i| std::array::from_fn(|j| a[j][i]))
}

pub(crate) fn apply(m: &Mat33, p: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2])
}

pub(crate) fn det(m: &Mat33) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

impl Calib {
    /// The matrix of a camera `k` ([fx 0 cx; 0 fy cy; 0 0 1]) whose frame is tilted by
    /// `rtilt` (upright = Rtilt · tilted depth; the identity for a level camera), as SUN
    /// RGB-D's raw frames give them.
    pub fn from_camera(k: &Mat33, rtilt: &Mat33) -> Calib {
        Calib {
            depth_to_image: mul(&mul(k, &DEPTH_TO_CAMERA), &transpose(rtilt)),
        }
    }

    /// The pixel (u, v) of an upright-depth point, or `None` for a point not in front of
    /// the camera (w ≤ 0).
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let [uw, vw, w] = apply(&self.depth_to_image, p);
        (w > 0.0).then(|| [uw / w, vw / w])
    }
}

/// The largest magnitude an entry may have: pixels times at most a few; beyond this a file
/// is garbage and projecting with it would lose all precision.
const MAX_ENTRY: f64 = 1e6;

/// Parses calibration text: exactly three rows of three finite numbers (comments and blank
/// lines aside), making an invertible matrix.
pub fn parse_calib(text: &str, path: &Path) -> Result<Calib> {
    let mut rows: Vec<[f64; 3]> = Vec::with_capacity(3);
    let mut last_line = 0;
    for (line_no, line) in content_lines(text) {
        let r = rows.len();
        if r == 3 {
            return Err(FormatError::field(
                path,
                line_no,
                "row 4",
                "the depth-to-image matrix has 3 rows; remove the extra line",
            ));
        }
        let cols: Vec<&str> = line.split_ascii_whitespace().collect();
        if cols.len() != 3 {
            return Err(FormatError::field(
                path,
                line_no,
                &format!("row {}", r + 1),
                format!("expected 3 numbers, found {}", cols.len()),
            ));
        }
        let mut row = [0.0; 3];
        for (c, text) in cols.iter().enumerate() {
            let field = format!("m{}{}", r + 1, c + 1);
            row[c] = parse_finite(path, line_no, &field, text)?;
            if row[c].abs() > MAX_ENTRY {
                return Err(FormatError::field(
                    path,
                    line_no,
                    &field,
                    format!(
                        "{:e} is no calibration value (entries stay within ±{MAX_ENTRY:e})",
                        row[c]
                    ),
                ));
            }
        }
        rows.push(row);
        last_line = line_no;
    }
    if rows.len() != 3 {
        return Err(FormatError::file(
            path,
            format!(
                "{} rows found; a calibration is the 3×3 depth-to-image matrix, three rows of three numbers",
                rows.len()
            ),
        ));
    }
    let m: Mat33 = [rows[0], rows[1], rows[2]];
    let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if det(&m).abs() <= 1e-12 * scale.powi(3) {
        return Err(FormatError::field(
            path,
            last_line,
            "row 3",
            "the matrix is singular: it cannot be a camera's projection",
        ));
    }
    Ok(Calib { depth_to_image: m })
}

pub fn read_calib(path: &Path) -> Result<Calib> {
    parse_calib(&read_text(path)?, path)
}

/// The file's text: the prepared files' header comment, then the rows, each number in the
/// shortest form that reads back to the same f64.
pub fn format_calib(calib: &Calib) -> String {
    let mut out = String::from(
        "# depth2img: 3x3 matrix (row-major) projecting upright-depth coordinates (x right, y forward, z up; metres) to the image: [u*w, v*w, w] = M [x, y, z]\n",
    );
    for row in &calib.depth_to_image {
        let _ = writeln!(out, "{} {} {}", row[0], row[1], row[2]);
    }
    out
}

/// Writes a calibration atomically; one the reader would refuse is not written.
pub fn write_calib(path: &Path, calib: &Calib) -> Result<()> {
    let text = format_calib(calib);
    parse_calib(&text, path)?;
    fusiondet_kitti::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scene 000017's file as prepared.
    const REAL: &str = "# depth2img: 3x3 matrix (row-major) projecting upright-depth coordinates (x right, y forward, z up; metres) to the image: [u*w, v*w, w] = M [x, y, z]
530.5366320782341 362.0406589161139 -32.432176765054464
35.10014939727262 164.8833093419671 -567.605659916997
0.005785000044852495 0.9835000038146973 -0.18082000315189362
";

    fn p() -> &'static Path {
        Path::new("calib/000017.txt")
    }

    #[test]
    fn reads_and_round_trips_the_prepared_file() {
        let calib = parse_calib(REAL, p()).unwrap();
        assert_eq!(calib.depth_to_image[1][2], -567.605659916997);
        assert_eq!(format_calib(&calib), REAL);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.txt");
        write_calib(&path, &calib).unwrap();
        assert_eq!(read_calib(&path).unwrap(), calib);
    }

    #[test]
    fn bad_files_name_line_and_field() {
        let err = parse_calib("1 0 0\n0 1\n0 0 1\n", p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("calib/000017.txt:2: field `row 2`: expected 3 numbers, found 2"),
            "{err}"
        );
        let err = parse_calib("1 0 0\n0 1 x\n0 0 1\n", p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(":2: field `m23`: `x` is not a number"),
            "{err}"
        );
        let err = parse_calib("1 0 0\n0 1 0\n", p()).unwrap_err().to_string();
        assert!(err.contains("2 rows found"), "{err}");
        let err = parse_calib("1 0 0\n0 1 0\n0 0 1\n1 1 1\n", p())
            .unwrap_err()
            .to_string();
        assert!(err.contains(":4: field `row 4`"), "{err}");
        let err = parse_calib("1 0 0\n0 1 0\n1 0 0\n", p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(":3: field `row 3`: the matrix is singular"),
            "{err}"
        );
        let err = parse_calib("1 0 0\n0 1 0\n0 0 1e9\n", p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("field `m33`"), "{err}");
    }

    #[test]
    fn a_level_camera_projects_as_its_intrinsics_say() {
        let k = [[500.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]];
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let calib = Calib::from_camera(&k, &identity);
        // 2 m ahead, 0.5 m right, 0.25 m up: u = 320 + 500·0.25, v = 240 − 400·0.125.
        let [u, v] = calib.project([0.5, 2.0, 0.25]).unwrap();
        assert!(
            (u - 445.0).abs() < 1e-12 && (v - 190.0).abs() < 1e-12,
            "{u} {v}"
        );
        assert_eq!(calib.project([0.0, -1.0, 0.0]), None);
        // A camera pitched up by t (its forward axis Rtilt · (0, 1, 0) rises) sees a level
        // point below the image centre.
        let t: f64 = 0.1;
        let rtilt = [
            [1.0, 0.0, 0.0],
            [0.0, t.cos(), -t.sin()],
            [0.0, t.sin(), t.cos()],
        ];
        let tilted = Calib::from_camera(&k, &rtilt);
        let [_, v2] = tilted.project([0.0, 2.0, 0.0]).unwrap();
        assert!((v2 - (240.0 + 400.0 * t.tan())).abs() < 1e-9, "{v2}");
    }
}
