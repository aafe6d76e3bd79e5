//! SAF's Tables 4–6 (He et al., Sensors 2022): the frustum detectors of one class side by
//! side — method, stages, parameters, runtime, 3D and BEV AP easy / moderate / hard at the
//! class's official IoU (0.7 for cars, 0.5 for pedestrians and cyclists) — with the paper's
//! rows (KITTI val) under ours, so that what agrees and what does not reads down a column.
//!
//! Ours are AP_R40 on whatever val split the ablation ran on (the simulator's, in this
//! project), runtime is one over the ablation's measured frames/s; the paper's figures are
//! as printed (its runtime on its own GPU). Nothing here is evaluated: every number of ours
//! comes from an [`AblationRow`].

use crate::ablation::{AblationRow, markdown_table, min_overlap_of};
use crate::protocol::Metric;
use fusiondet_kitti::ObjectClass;
use std::fmt::Write as _;

/// One printed row of the paper's tables.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperRow {
    pub method: &'static str,
    pub stages: &'static str,
    pub params: Option<usize>,
    pub runtime_s: Option<f64>,
    /// AP in %, easy / moderate / hard.
    pub ap_3d: [f64; 3],
    pub ap_bev: [f64; 3],
}

const fn row(
    method: &'static str,
    stages: &'static str,
    params: Option<usize>,
    runtime_s: Option<f64>,
    ap_3d: [f64; 3],
    ap_bev: [f64; 3],
) -> PaperRow {
    PaperRow {
        method,
        stages,
        params,
        runtime_s,
        ap_3d,
        ap_bev,
    }
}

/// Table 4 (Cars), from the paper.
const TABLE_4: [PaperRow; 4] = [
    row(
        "F-PointNet",
        "two",
        None,
        None,
        [83.76, 70.92, 63.65],
        [88.16, 84.02, 76.44],
    ),
    row(
        "F-ConvNet + refine",
        "two",
        Some(6_633_554),
        Some(0.49),
        [88.98, 78.66, 72.23],
        [90.08, 88.84, 80.10],
    ),
    row(
        "F-ConvNet",
        "one",
        Some(3_316_777),
        Some(0.26),
        [87.95, 76.37, 68.56],
        [89.88, 87.48, 78.99],
    ),
    row(
        "SAF",
        "one",
        Some(3_724_013),
        Some(0.29),
        [89.46, 79.91, 75.53],
        [91.27, 89.63, 85.75],
    ),
];

/// Table 5 (Pedestrians), from the paper.
const TABLE_5: [PaperRow; 4] = [
    row(
        "F-PointNet",
        "two",
        None,
        None,
        [70.00, 61.32, 53.59],
        [72.38, 66.39, 59.57],
    ),
    row(
        "F-ConvNet + refine",
        "two",
        Some(6_633_554),
        Some(0.49),
        [70.88, 62.24, 53.37],
        [72.59, 67.05, 58.68],
    ),
    row(
        "F-ConvNet",
        "one",
        Some(3_316_777),
        Some(0.26),
        [68.47, 60.63, 50.80],
        [70.31, 66.14, 56.09],
    ),
    row(
        "SAF",
        "one",
        Some(3_724_013),
        Some(0.29),
        [70.61, 61.84, 53.93],
        [72.24, 66.58, 59.11],
    ),
];

/// Table 6 (Cyclists), from the paper.
const TABLE_6: [PaperRow; 4] = [
    row(
        "F-PointNet",
        "two",
        None,
        None,
        [77.15, 56.49, 53.37],
        [81.82, 60.03, 56.32],
    ),
    row(
        "F-ConvNet + refine",
        "two",
        Some(6_633_554),
        Some(0.49),
        [81.69, 69.55, 59.87],
        [83.28, 70.10, 61.79],
    ),
    row(
        "F-ConvNet",
        "one",
        Some(3_316_777),
        Some(0.26),
        [75.88, 64.63, 55.74],
        [80.37, 63.24, 57.52],
    ),
    row(
        "SAF",
        "one",
        Some(3_724_013),
        Some(0.29),
        [77.24, 65.21, 56.15],
        [80.79, 66.47, 57.86],
    ),
];

/// The paper's table number and rows for `class`; `None` for a class the paper has no
/// table of.
pub fn paper_table(class: ObjectClass) -> Option<(u32, &'static [PaperRow])> {
    match class {
        ObjectClass::Car => Some((4, &TABLE_4)),
        ObjectClass::Pedestrian => Some((5, &TABLE_5)),
        ObjectClass::Cyclist => Some((6, &TABLE_6)),
        _ => None,
    }
}

/// Table 4, 5 or 6 for `class`: our rows (at the ablation's first overlap setting, the
/// official one), `stages[i]` the number of stages of row i's detector, then the paper's;
/// `None` for a class the paper has no table of.
pub fn saf_table(rows: &[AblationRow], stages: &[u32], class: ObjectClass) -> Option<String> {
    assert_eq!(rows.len(), stages.len(), "one stage count per row");
    let (number, paper) = paper_table(class)?;
    let iou = min_overlap_of(rows, class, 0, Metric::ThreeD);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Table {number} of the SAF paper, {class}: ours AP_R40 in % on this ablation's val \
         frames at 3D / BEV IoU > {iou}, runtime 1 / measured frames/s on this machine; the \
         paper's rows on KITTI val as printed (runtime on its GPU)\n"
    );
    let header: Vec<String> = [
        "Method",
        "Source",
        "Stages",
        "Params",
        "Runtime (s)",
        "3D Easy",
        "3D Mod.",
        "3D Hard",
        "BEV Easy",
        "BEV Mod.",
        "BEV Hard",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let ap = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.2}"));
    let mut body = Vec::new();
    for (r, &n) in rows.iter().zip(stages) {
        let mut cells = vec![
            r.name.clone(),
            "ours".to_string(),
            if n == 1 { "one" } else { "two" }.to_string(),
            r.params
                .map_or("n/a".to_string(), |p| group_thousands(p as u64)),
            r.frames_per_second
                .filter(|f| *f > 0.0)
                .map_or("n/a".to_string(), |f| format!("{:.3}", 1.0 / f)),
        ];
        for m in [Metric::ThreeD, Metric::Bev] {
            let res = r.report.get(class, m, 0);
            for d in 0..3 {
                cells.push(ap(res.map(|res| res.ap40[d])));
            }
        }
        body.push(cells);
    }
    for p in paper {
        let mut cells = vec![
            p.method.to_string(),
            "paper".to_string(),
            p.stages.to_string(),
            p.params
                .map_or("-".to_string(), |n| group_thousands(n as u64)),
            p.runtime_s.map_or("-".to_string(), |s| format!("{s:.2}")),
        ];
        cells.extend(p.ap_3d.iter().chain(&p.ap_bev).map(|v| format!("{v:.2}")));
        body.push(cells);
    }
    out.push_str(&markdown_table(&header, &body));
    Some(out)
}

/// `6633554` as `6,633,554`, as the paper prints parameter counts.
fn group_thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{EvalConfig, evaluate, synthetic};

    #[test]
    fn thousands_are_grouped() {
        assert_eq!(group_thousands(6_633_554), "6,633,554");
        assert_eq!(group_thousands(999), "999");
        assert_eq!(group_thousands(1_000), "1,000");
    }

    #[test]
    fn the_table_puts_our_measured_rows_above_the_papers() {
        let (gt, det) = synthetic::generate(30, 3);
        let report = evaluate(&gt, &det, &EvalConfig::default()).unwrap();
        let mut row = AblationRow::new("saf-people-sim", report.clone());
        row.params = Some(3_724_013);
        row.frames_per_second = Some(4.0);
        let text = saf_table(std::slice::from_ref(&row), &[1], ObjectClass::Pedestrian)
            .expect("the paper has a pedestrian table");
        assert!(
            text.starts_with("Table 5 of the SAF paper, Pedestrian"),
            "{text}"
        );
        assert!(text.contains("IoU > 0.50"), "{text}");
        let lines: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with("| ") && !l.contains("---"))
            .collect();
        // Header, then ours, then the paper's four.
        assert_eq!(lines.len(), 6, "{text}");
        assert!(lines[1].contains("saf-people-sim") && lines[1].contains(" ours |"));
        assert!(lines[1].contains("3,724,013") && lines[1].contains("0.250"));
        let ped_3d = report
            .get(ObjectClass::Pedestrian, Metric::ThreeD, 0)
            .unwrap();
        assert!(lines[1].contains(&format!("{:.2}", ped_3d.ap40[1])));
        assert!(
            lines[5].contains("SAF") && lines[5].contains("61.84"),
            "{text}"
        );
        assert!(saf_table(&[], &[], ObjectClass::Van).is_none());
    }
}
