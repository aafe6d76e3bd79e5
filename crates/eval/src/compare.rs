//! Box-by-box comparison of two result directories of the same frames: the check that a
//! model gives the same detections on two backends (CPU and GPU), two builds or two
//! machines. AP can agree while boxes differ; this says how far the boxes themselves moved.
//!
//! Per frame and class, boxes are paired greedily by centre distance (closest pair first,
//! each box used once; pairs farther apart than [`PAIRING_GATE_M`] are not paired). Two runs
//! of one model on one input differ by float summation order only, so their boxes lie
//! centimetres apart and the closest-first pairing is the right one; an optimal assignment
//! would only matter for boxes that moved by more than their spacing, which is a failure
//! either way.

use crate::load::read_result_file;
use fusiondet_kitti::layout::list_frame_ids;
use fusiondet_kitti::{FormatError, Object};
use std::collections::BTreeSet;
use std::path::Path;

/// Boxes whose centres lie farther apart than this are never paired (they are reported as
/// unmatched in both runs).
pub const PAIRING_GATE_M: f64 = 1.0;

/// What may differ between two runs for them to count as the same detections.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    /// Largest centre offset and largest difference of any size (h, w, l), metres.
    pub metres: f64,
    /// Largest heading difference (rotation_y, wrapped to [−π, π]), radians.
    pub radians: f64,
    /// Largest score difference.
    pub score: f64,
}

impl Default for Tolerance {
    /// Parity between backends: 1 cm, 0.01 rad, 1e-3 in score.
    fn default() -> Self {
        Self {
            metres: 0.01,
            radians: 0.01,
            score: 1e-3,
        }
    }
}

/// The largest differences over all paired boxes, and what could not be paired.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Comparison {
    pub frames: usize,
    pub boxes_a: usize,
    pub boxes_b: usize,
    pub paired: usize,
    pub max_centre_m: f64,
    pub max_size_m: f64,
    pub max_heading_rad: f64,
    pub max_score: f64,
    /// (frame id, boxes of A left unpaired, boxes of B left unpaired), frames with any.
    pub unpaired: Vec<(String, usize, usize)>,
}

/// What a difference may exceed its tolerance by and still count as within it. Result files
/// hold metres and radians to two decimals, so a box one unit of the last digit away differs
/// by exactly 0.01, which the difference of the two parsed numbers puts a few 1e-16 above or
/// below 0.01; without this slack a 1 cm tolerance would pass or fail such a box by chance.
pub const READ_SLACK: f64 = 1e-9;

/// `value` within `tolerance` (up to [`READ_SLACK`]).
fn within_tolerance(value: f64, tolerance: f64) -> bool {
    value <= tolerance + READ_SLACK
}

impl Comparison {
    /// Whether every box has its partner and every difference is within `tol`.
    pub fn within(&self, tol: &Tolerance) -> bool {
        self.unpaired.is_empty()
            && within_tolerance(self.max_centre_m, tol.metres)
            && within_tolerance(self.max_size_m, tol.metres)
            && within_tolerance(self.max_heading_rad, tol.radians)
            && within_tolerance(self.max_score, tol.score)
    }

    /// The report `fusiondet compare` prints.
    pub fn summary(&self, tol: &Tolerance) -> String {
        let mark = |v: f64, t: f64| {
            if within_tolerance(v, t) {
                ""
            } else {
                "  (over)"
            }
        };
        let mut s = format!(
            "frames {}, boxes {} / {}, paired {}\n\
             largest centre offset  {:.6} m{}\n\
             largest size change    {:.6} m{}\n\
             largest heading change {:.6} rad{}\n\
             largest score change   {:.6}{}\n",
            self.frames,
            self.boxes_a,
            self.boxes_b,
            self.paired,
            self.max_centre_m,
            mark(self.max_centre_m, tol.metres),
            self.max_size_m,
            mark(self.max_size_m, tol.metres),
            self.max_heading_rad,
            mark(self.max_heading_rad, tol.radians),
            self.max_score,
            mark(self.max_score, tol.score),
        );
        for (id, a, b) in self.unpaired.iter().take(10) {
            s.push_str(&format!(
                "frame {id}: {a} box(es) of A and {b} of B unpaired\n"
            ));
        }
        if self.unpaired.len() > 10 {
            s.push_str(&format!(
                "... and {} more frames with unpaired boxes\n",
                self.unpaired.len() - 10
            ));
        }
        s
    }

    /// Adds one frame's boxes.
    pub fn add_frame(&mut self, id: &str, a: &[Object], b: &[Object]) {
        self.frames += 1;
        self.boxes_a += a.len();
        self.boxes_b += b.len();
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, x) in a.iter().enumerate() {
            for (j, y) in b.iter().enumerate() {
                if x.class != y.class {
                    continue;
                }
                let d = centre_distance(x, y);
                if d <= PAIRING_GATE_M {
                    pairs.push((d, i, j));
                }
            }
        }
        // Closest first; ties by position so the pairing does not depend on the sort.
        pairs.sort_by(|p, q| p.0.total_cmp(&q.0).then((p.1, p.2).cmp(&(q.1, q.2))));
        let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
        let mut paired = 0;
        for (d, i, j) in pairs {
            if used_a[i] || used_b[j] {
                continue;
            }
            used_a[i] = true;
            used_b[j] = true;
            paired += 1;
            let (p, q) = (&a[i].box3d, &b[j].box3d);
            self.max_centre_m = self.max_centre_m.max(d);
            let size = (p.h - q.h)
                .abs()
                .max((p.w - q.w).abs())
                .max((p.l - q.l).abs());
            self.max_size_m = self.max_size_m.max(size);
            self.max_heading_rad = self.max_heading_rad.max(angle_between(p.ry, q.ry));
            let score = (a[i].score.unwrap_or(0.0) - b[j].score.unwrap_or(0.0)).abs();
            self.max_score = self.max_score.max(score);
        }
        self.paired += paired;
        let (left_a, left_b) = (a.len() - paired, b.len() - paired);
        if left_a + left_b > 0 {
            self.unpaired.push((id.to_string(), left_a, left_b));
        }
    }
}

fn centre_distance(x: &Object, y: &Object) -> f64 {
    let (p, q) = (&x.box3d, &y.box3d);
    ((p.x - q.x).powi(2) + (p.y - q.y).powi(2) + (p.z - q.z).powi(2)).sqrt()
}

/// |a − b| wrapped to [0, π].
fn angle_between(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d.min(std::f64::consts::TAU - d)
}

/// Compares every `NNNNNN.txt` result file in either directory (a frame with a file in one
/// directory only compares against no boxes).
pub fn compare_dirs(a: &Path, b: &Path) -> Result<Comparison, FormatError> {
    let mut ids = BTreeSet::new();
    for dir in [a, b] {
        ids.extend(list_frame_ids(dir, "txt").map_err(|e| FormatError::io(dir, e))?);
    }
    let mut comparison = Comparison::default();
    for id in &ids {
        let file = format!("{id}.txt");
        let boxes_a = read_result_file(&a.join(&file))?.unwrap_or_default();
        let boxes_b = read_result_file(&b.join(&file))?.unwrap_or_default();
        comparison.add_frame(id, &boxes_a, &boxes_b);
    }
    Ok(comparison)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_kitti::label::parse_objects;

    fn objects(lines: &str) -> Vec<Object> {
        parse_objects(lines, Path::new("test.txt")).unwrap()
    }

    const A: &str = "Car 0 0 0 10 10 50 50 1.5 1.6 3.9 1.0 1.6 20.0 0.10 0.90\n\
                     Car 0 0 0 60 10 90 50 1.5 1.6 3.9 -4.0 1.6 30.0 3.10 0.50\n";

    #[test]
    fn identical_runs_are_within_any_tolerance() {
        let mut c = Comparison::default();
        c.add_frame("000000", &objects(A), &objects(A));
        assert_eq!(c.paired, 2);
        assert_eq!(c.max_centre_m, 0.0);
        assert!(c.within(&Tolerance {
            metres: 0.0,
            radians: 0.0,
            score: 0.0
        }));
    }

    #[test]
    fn boxes_pair_closest_first_whatever_their_order_and_headings_wrap() {
        // B lists the boxes in the other order, the first 4 mm away, the second's heading
        // across −π from A's (3.10 against −3.18: 0.0032 rad apart, not 6.28).
        let b = "Car 0 0 0 60 10 90 50 1.5 1.6 3.9 -4.0 1.6 30.0 -3.18 0.5004\n\
                 Car 0 0 0 10 10 50 50 1.5 1.6 3.9 1.004 1.6 20.0 0.10 0.90\n";
        let mut c = Comparison::default();
        c.add_frame("000000", &objects(A), &objects(b));
        assert_eq!(c.paired, 2);
        assert!((c.max_centre_m - 0.004).abs() < 1e-9, "{}", c.max_centre_m);
        let wrapped = std::f64::consts::TAU - (3.10 + 3.18);
        assert!(
            (c.max_heading_rad - wrapped).abs() < 1e-9,
            "{}",
            c.max_heading_rad
        );
        assert!((c.max_score - 4e-4).abs() < 1e-9);
        assert!(c.within(&Tolerance::default()));
    }

    #[test]
    fn a_missing_box_or_a_moved_one_fails() {
        let one = "Car 0 0 0 10 10 50 50 1.5 1.6 3.9 1.0 1.6 20.0 0.10 0.90\n";
        let mut c = Comparison::default();
        c.add_frame("000007", &objects(A), &objects(one));
        assert_eq!(c.unpaired, vec![("000007".to_string(), 1, 0)]);
        assert!(!c.within(&Tolerance::default()));

        let moved = "Car 0 0 0 10 10 50 50 1.5 1.6 3.9 1.05 1.6 20.0 0.10 0.90\n\
                     Car 0 0 0 60 10 90 50 1.5 1.6 3.9 -4.0 1.6 30.0 3.10 0.50\n";
        let mut c = Comparison::default();
        c.add_frame("000000", &objects(A), &objects(moved));
        assert!(c.unpaired.is_empty());
        assert!(!c.within(&Tolerance::default()), "5 cm is over 1 cm");
        assert!(c.summary(&Tolerance::default()).contains("(over)"));
    }

    #[test]
    fn one_unit_of_the_files_last_digit_is_within_a_tolerance_of_that_unit() {
        // Centre x, length and heading each one unit of the second decimal apart: parsed,
        // 1.01 − 1.00 and 3.91 − 3.90 land on either side of 0.01 by ~1e-16.
        let b = "Car 0 0 0 10 10 50 50 1.5 1.6 3.91 1.01 1.6 20.0 0.11 0.90\n\
                 Car 0 0 0 60 10 90 50 1.5 1.6 3.9 -4.0 1.6 30.0 3.10 0.50\n";
        let mut c = Comparison::default();
        c.add_frame("000000", &objects(A), &objects(b));
        assert!((c.max_centre_m - 0.01).abs() < 1e-12, "{}", c.max_centre_m);
        assert!(c.within(&Tolerance::default()));
        assert!(!c.summary(&Tolerance::default()).contains("(over)"));
        // Two units apart is over.
        let b2 = b.replace("1.01 1.6 20.0", "1.02 1.6 20.0");
        let mut c = Comparison::default();
        c.add_frame("000000", &objects(A), &objects(&b2));
        assert!(!c.within(&Tolerance::default()));
    }

    #[test]
    fn classes_never_pair() {
        let ped = "Pedestrian 0 0 0 10 10 50 50 1.5 1.6 3.9 1.0 1.6 20.0 0.10 0.90\n";
        let car = "Car 0 0 0 10 10 50 50 1.5 1.6 3.9 1.0 1.6 20.0 0.10 0.90\n";
        let mut c = Comparison::default();
        c.add_frame("000000", &objects(ped), &objects(car));
        assert_eq!(c.paired, 0);
        assert_eq!(c.unpaired, vec![("000000".to_string(), 1, 1)]);
    }

    #[test]
    fn directories_compare_frame_by_frame_with_missing_files_as_empty() {
        let root = std::env::temp_dir().join(format!("fd-compare-{}", std::process::id()));
        let (a, b) = (root.join("a"), root.join("b"));
        std::fs::create_dir_all(&a).unwrap();
        std::fs::create_dir_all(&b).unwrap();
        std::fs::write(a.join("000000.txt"), A).unwrap();
        std::fs::write(b.join("000000.txt"), A).unwrap();
        std::fs::write(a.join("000001.txt"), A).unwrap();
        std::fs::write(a.join("notes.md"), "not a frame").unwrap();
        let c = compare_dirs(&a, &b).unwrap();
        std::fs::remove_dir_all(&root).unwrap();
        assert_eq!(c.frames, 2);
        assert_eq!((c.boxes_a, c.boxes_b, c.paired), (4, 2, 2));
        assert_eq!(c.unpaired, vec![("000001".to_string(), 2, 0)]);
    }
}
