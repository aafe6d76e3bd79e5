//! `calib/NNNNNN.txt`: the four camera projection matrices, the rectifying rotation
//! and the LiDAR/IMU extrinsics of one frame.

use crate::error::{FormatError, Result, parse_finite, read_text};
use std::fmt::Write as _;
use std::path::Path;

/// A 3×4 matrix, row-major.
pub type Mat34 = [[f64; 4]; 3];
/// A 3×3 matrix, row-major.
pub type Mat33 = [[f64; 3]; 3];

/// The calibration of one KITTI frame, exactly as stored (row-major matrices).
#[derive(Debug, Clone, PartialEq)]
pub struct Calib {
    /// Projection matrices of cameras 0–3 (P2 is the left colour camera).
    pub p: [Mat34; 4],
    pub r0_rect: Mat33,
    pub tr_velo_to_cam: Mat34,
    pub tr_imu_to_velo: Mat34,
}

/// Keys as written by KITTI, with the older aliases some tools write.
const KEYS: [(&str, &[&str], usize); 7] = [
    ("P0", &[], 12),
    ("P1", &[], 12),
    ("P2", &[], 12),
    ("P3", &[], 12),
    ("R0_rect", &["R_rect"], 9),
    ("Tr_velo_to_cam", &["Tr_velo_cam"], 12),
    ("Tr_imu_to_velo", &["Tr_imu_velo"], 12),
];

impl Calib {
    /// The camera model of the left colour camera (P2) with this frame's extrinsics;
    /// fails only if R0_rect · Tr_velo_to_cam is singular.
    pub fn camera_model(&self) -> std::result::Result<fusiondet_geometry::CameraModel, String> {
        fusiondet_geometry::CameraModel::new(&self.p[2], &self.r0_rect, &self.tr_velo_to_cam)
    }
}

fn to_mat34(v: &[f64]) -> Mat34 {
    let mut m = [[0.0; 4]; 3];
    for (i, x) in v.iter().enumerate() {
        m[i / 4][i % 4] = *x;
    }
    m
}

fn to_mat33(v: &[f64]) -> Mat33 {
    let mut m = [[0.0; 3]; 3];
    for (i, x) in v.iter().enumerate() {
        m[i / 3][i % 3] = *x;
    }
    m
}

/// The largest magnitude a calibration entry may have: focal lengths and principal points
/// are pixels (hundreds to a few thousand), translations metres or pixel-metres. Beyond
/// this a file is garbage, and projecting with it would overflow or lose all precision.
const MAX_ENTRY: f64 = 1e6;

/// How far the determinant of a stored rotation (R0_rect, Tr_velo_to_cam's 3×3 block) may
/// be from 1: KITTI writes them to 7 digits, so real files are within 1e-5.
const ROTATION_DET_TOLERANCE: f64 = 0.01;

/// Parses calibration text; every key is required (a missing one is an error naming it),
/// each given once, and the matrices we project with must be able to project: cameras with
/// positive focal lengths, rotations that are rotations.
pub fn parse_calib(text: &str, path: &Path) -> Result<Calib> {
    let mut values: [Option<Vec<f64>>; 7] = Default::default();
    let mut lines = [0usize; 7];
    for (index, line) in text.lines().enumerate() {
        let line_no = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let Some((key, rest)) = line.split_once(':') else {
            return Err(FormatError::field(
                path,
                line_no,
                line.trim(),
                "expected `KEY: v1 v2 ...`",
            ));
        };
        let key = key.trim();
        let Some(slot) = KEYS
            .iter()
            .position(|(name, aliases, _)| *name == key || aliases.contains(&key))
        else {
            continue; // other keys (e.g. R_rect_00 in raw calibs) are not ours to judge
        };
        let (name, _, count) = KEYS[slot];
        let nums = rest
            .split_ascii_whitespace()
            .map(|t| parse_finite(path, line_no, name, t))
            .collect::<Result<Vec<f64>>>()?;
        if nums.len() != count {
            return Err(FormatError::field(
                path,
                line_no,
                name,
                format!("expected {count} numbers, found {}", nums.len()),
            ));
        }
        if let Some(v) = nums.iter().find(|v| v.abs() > MAX_ENTRY) {
            return Err(FormatError::field(
                path,
                line_no,
                name,
                format!("{v:e} is no calibration value (entries stay within ±{MAX_ENTRY:e})"),
            ));
        }
        if values[slot].is_some() {
            return Err(FormatError::field(
                path,
                line_no,
                name,
                format!(
                    "given again (first on line {}); keep one `{name}` line",
                    lines[slot]
                ),
            ));
        }
        values[slot] = Some(nums);
        lines[slot] = line_no;
    }
    for (slot, (name, _, _)) in KEYS.iter().enumerate() {
        if values[slot].is_none() {
            return Err(FormatError::file(
                path,
                format!(
                    "missing calibration key `{name}`; a KITTI calib file needs P0, P1, P2, P3, R0_rect, Tr_velo_to_cam and Tr_imu_to_velo"
                ),
            ));
        }
    }
    let v = |i: usize| values[i].as_deref().unwrap_or_default();
    let calib = Calib {
        p: [
            to_mat34(v(0)),
            to_mat34(v(1)),
            to_mat34(v(2)),
            to_mat34(v(3)),
        ],
        r0_rect: to_mat33(v(4)),
        tr_velo_to_cam: to_mat34(v(5)),
        tr_imu_to_velo: to_mat34(v(6)),
    };
    let bad =
        |slot: usize, message: String| FormatError::field(path, lines[slot], KEYS[slot].0, message);
    for (slot, p) in calib.p.iter().enumerate() {
        let (fx, fy) = (p[0][0], p[1][1]);
        if fx <= 0.0 || fy <= 0.0 || det3(p) <= 0.0 {
            return Err(bad(
                slot,
                format!(
                    "cannot project: a camera matrix needs focal lengths fx, fy > 0 (here {fx}, \
                     {fy}) and an invertible left 3x3 block"
                ),
            ));
        }
    }
    let rotations = [(4, det3(&calib.r0_rect)), (5, det3(&calib.tr_velo_to_cam))];
    for (slot, det) in rotations {
        if (det - 1.0).abs() > ROTATION_DET_TOLERANCE {
            return Err(bad(
                slot,
                format!("not a rotation: its 3x3 block has determinant {det:.6}, not 1"),
            ));
        }
    }
    Ok(calib)
}

/// The determinant of a matrix's left 3×3 block (rows of 3 or 4 entries).
fn det3<R: AsRef<[f64]>>(m: &[R; 3]) -> f64 {
    let (a, b, c) = (m[0].as_ref(), m[1].as_ref(), m[2].as_ref());
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
}

pub fn read_calib(path: &Path) -> Result<Calib> {
    parse_calib(&read_text(path)?, path)
}

/// Formats a calibration the way KITTI writes it (12 significant digits, exponent form),
/// exactly: a value with more digits is written in full.
pub fn format_calib(calib: &Calib) -> String {
    fn row(out: &mut String, key: &str, values: impl Iterator<Item = f64>) {
        out.push_str(key);
        out.push(':');
        for v in values {
            // KITTI's 12 significant digits, unless the value has more: then the shortest
            // form that reads back exactly (found by fuzzing: -387.5744590000004).
            let kitti = format!("{v:.12e}");
            if kitti.parse::<f64>() == Ok(v) {
                let _ = write!(out, " {kitti}");
            } else {
                let _ = write!(out, " {v:e}");
            }
        }
        out.push('\n');
    }
    let flat34 = |m: &Mat34| m.concat().into_iter();
    let mut out = String::new();
    for (i, p) in calib.p.iter().enumerate() {
        row(&mut out, &format!("P{i}"), flat34(p));
    }
    row(&mut out, "R0_rect", calib.r0_rect.concat().into_iter());
    row(&mut out, "Tr_velo_to_cam", flat34(&calib.tr_velo_to_cam));
    row(&mut out, "Tr_imu_to_velo", flat34(&calib.tr_imu_to_velo));
    out
}

pub fn write_calib(path: &Path, calib: &Calib) -> Result<()> {
    crate::atomic::write_atomic(path, format_calib(calib).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const SAMPLE: &str = "P0: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 0.000000000000e+00 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 -3.797842000000e+02 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 4.575831000000e+01 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 -3.454157000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.981016000000e-03
P3: 7.070493000000e+02 0.000000000000e+00 6.040814000000e+02 -3.341081000000e+02 0.000000000000e+00 7.070493000000e+02 1.805066000000e+02 2.330660000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.201153000000e-03
R0_rect: 9.999128000000e-01 1.009263000000e-02 -8.511932000000e-03 -1.012729000000e-02 9.999406000000e-01 -4.037671000000e-03 8.470675000000e-03 4.123522000000e-03 9.999556000000e-01
Tr_velo_to_cam: 6.927964000000e-03 -9.999722000000e-01 -2.757829000000e-03 -2.457729000000e-02 -1.162982000000e-03 2.749836000000e-03 -9.999955000000e-01 -6.127237000000e-02 9.999753000000e-01 6.931141000000e-03 -1.143899000000e-03 -3.321029000000e-01
Tr_imu_to_velo: 9.999976000000e-01 7.553071000000e-04 -2.035826000000e-03 -8.086759000000e-01 -7.854027000000e-04 9.998898000000e-01 -1.482298000000e-02 3.195559000000e-01 2.024406000000e-03 1.482454000000e-02 9.998881000000e-01 -7.997231000000e-01
";

    fn p() -> &'static Path {
        Path::new("calib/000000.txt")
    }

    #[test]
    fn parses_all_matrices() {
        let c = parse_calib(SAMPLE, p()).unwrap();
        assert_eq!(c.p[2][0][0], 707.0493);
        assert_eq!(c.p[2][0][3], 45.75831);
        assert_eq!(c.r0_rect[2][2], 0.9999556);
        assert_eq!(c.tr_velo_to_cam[2][3], -0.3321029);
    }

    #[test]
    fn round_trips_exactly() {
        let c = parse_calib(SAMPLE, p()).unwrap();
        let back = parse_calib(&format_calib(&c), p()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn values_beyond_twelve_digits_round_trip_too() {
        let mut c = parse_calib(SAMPLE, p()).unwrap();
        c.p[1][0][3] = -387.5744590000004;
        let back = parse_calib(&format_calib(&c), p()).unwrap();
        assert_eq!(back, c);
        assert!(
            format_calib(&c).starts_with("P0: 7.070493000000e2"),
            "KITTI's form kept"
        );
    }

    #[test]
    fn missing_key_is_named() {
        let text: String = SAMPLE
            .lines()
            .filter(|l| !l.starts_with("R0_rect"))
            .map(|l| format!("{l}\n"))
            .collect();
        let err = parse_calib(&text, p()).unwrap_err().to_string();
        assert!(err.contains("missing calibration key `R0_rect`"), "{err}");
    }

    #[test]
    fn wrong_count_and_bad_numbers_are_named() {
        let err = parse_calib("P0: 1 2 3\n", p()).unwrap_err().to_string();
        assert!(err.contains(":1: field `P0`: expected 12 numbers"), "{err}");
        let text = SAMPLE.replace("4.575831000000e+01", "nan");
        let err = parse_calib(&text, p()).unwrap_err().to_string();
        assert!(err.contains(":3: field `P2`"), "{err}");
    }

    /// SAMPLE with the `key:` line replaced by `line`.
    fn with_line(key: &str, line: &str) -> String {
        SAMPLE
            .lines()
            .map(|l| {
                if l.starts_with(&format!("{key}:")) {
                    format!("{line}\n")
                } else {
                    format!("{l}\n")
                }
            })
            .collect()
    }

    #[test]
    fn calibrations_that_cannot_project_are_refused() {
        let zeros = format!("P2:{}", " 0".repeat(12));
        let err = parse_calib(&with_line("P2", &zeros), p())
            .unwrap_err()
            .to_string();
        assert!(err.contains(":3: field `P2`: cannot project"), "{err}");
        let no_fx = "P2: 0 0 604 45 0 707 180 0 0 0 1 0";
        let err = parse_calib(&with_line("P2", no_fx), p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("fx, fy > 0 (here 0, 707)"), "{err}");
        let huge = "P2: 1e308 0 604 45 0 707 180 0 0 0 1 0";
        let err = parse_calib(&with_line("P2", huge), p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(":3: field `P2`: 1e308 is no calibration value"),
            "{err}"
        );
        let squashed = "R0_rect: 1 0 0 0 1 0 0 0 0.5";
        let err = parse_calib(&with_line("R0_rect", squashed), p())
            .unwrap_err()
            .to_string();
        assert!(err.contains(":5: field `R0_rect`: not a rotation"), "{err}");
        let flat = "Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 0 0 0 0";
        let err = parse_calib(&with_line("Tr_velo_to_cam", flat), p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(":6: field `Tr_velo_to_cam`: not a rotation"),
            "{err}"
        );
    }

    #[test]
    fn a_key_given_twice_is_refused() {
        let second_p2 = SAMPLE.lines().nth(2).unwrap();
        let text = format!("{SAMPLE}{second_p2}\n");
        let err = parse_calib(&text, p()).unwrap_err().to_string();
        assert!(
            err.contains(":8: field `P2`: given again (first on line 3)"),
            "{err}"
        );
    }
}
