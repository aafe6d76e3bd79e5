//! Ablation studies: several detector configurations evaluated on the same frames,
//! printed like the ablation tables of detection papers (one row per configuration) so
//! that a component's effect reads across a row pair, with the occlusion / distance /
//! LiDAR-point breakdown side by side (where claims about occluded and far objects are
//! checked) and a JSON form of everything.
//!
//! Nothing is evaluated here: every number comes from an [`EvalReport`] and, where
//! given, the rows of [`evaluate_breakdown`](crate::evaluate_breakdown).

use crate::breakdown::{BreakdownAxis, BreakdownRow, JsonBreakdownRow};
use crate::error::EvalError;
use crate::protocol::{Difficulty, Metric};
use crate::report::{EvalReport, JsonRow};
use fusiondet_kitti::ObjectClass;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// One configuration of an ablation: its evaluation and what it costs.
#[derive(Debug, Clone, PartialEq)]
pub struct AblationRow {
    /// The configuration's name as the table shows it, e.g. `saf+lfa`.
    pub name: String,
    pub report: EvalReport,
    /// Rows of [`evaluate_breakdown`](crate::evaluate_breakdown), if it was run.
    pub breakdown: Option<Vec<BreakdownRow>>,
    /// Trainable parameters of the network (both stages' for a refinement model).
    pub params: Option<usize>,
    /// Multiply-adds of one frame's inference on a typical scene, where the family
    /// counts them.
    pub multiply_adds: Option<u64>,
    /// Inference speed, frames per second.
    pub frames_per_second: Option<f64>,
}

impl AblationRow {
    /// A row with a report only (no breakdown, size or speed).
    pub fn new(name: impl Into<String>, report: EvalReport) -> Self {
        AblationRow {
            name: name.into(),
            report,
            breakdown: None,
            params: None,
            multiply_adds: None,
            frames_per_second: None,
        }
    }
}

/// What a numeric cell holds; kept apart from its text so the best value per column
/// can be marked.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Cell {
    Ap(f64),
    /// The result exists but has no ground truth to measure against.
    NoGt,
    /// The configuration has no such result (not evaluated / no breakdown run).
    Missing,
}

/// Formats cells column by column, bolding (Markdown `**`) the best AP of each column
/// as papers do, so the winning configuration stands out. Ties at the printed
/// precision are all bold; a column with fewer than two values marks nothing.
fn format_columns(rows: &[Vec<Cell>]) -> Vec<Vec<String>> {
    let shown = |v: f64| (v * 100.0).round() as i64;
    let n_cols = rows.first().map_or(0, Vec::len);
    let best: Vec<Option<i64>> = (0..n_cols)
        .map(|c| {
            let values: Vec<i64> = rows
                .iter()
                .filter_map(|r| match r[c] {
                    Cell::Ap(v) => Some(shown(v)),
                    _ => None,
                })
                .collect();
            (values.len() >= 2).then(|| *values.iter().max().expect("two values"))
        })
        .collect();
    rows.iter()
        .map(|r| {
            r.iter()
                .zip(&best)
                .map(|(cell, best)| match *cell {
                    Cell::Ap(v) if Some(shown(v)) == *best => format!("**{v:.2}**"),
                    Cell::Ap(v) => format!("{v:.2}"),
                    Cell::NoGt => "-".to_string(),
                    Cell::Missing => "n/a".to_string(),
                })
                .collect()
        })
        .collect()
}

/// A Markdown table with padded columns, so it also reads well as plain text. The first
/// column is left-aligned, the others right-aligned (numbers).
pub(crate) fn markdown_table(header: &[String], rows: &[Vec<String>]) -> String {
    let widths: Vec<usize> = (0..header.len())
        .map(|c| {
            rows.iter()
                .map(|r| r[c].chars().count())
                .chain([header[c].chars().count(), 3])
                .max()
                .unwrap_or(3)
        })
        .collect();
    let line = |cells: &[String]| {
        let mut s = String::from("|");
        for (c, (cell, w)) in cells.iter().zip(&widths).enumerate() {
            if c == 0 {
                let _ = write!(s, " {cell:<w$} |");
            } else {
                let _ = write!(s, " {cell:>w$} |");
            }
        }
        s.push('\n');
        s
    };
    let mut out = line(header);
    out.push('|');
    for (c, w) in widths.iter().enumerate() {
        let dashes = "-".repeat(*w);
        if c == 0 {
            let _ = write!(out, " {dashes} |");
        } else {
            let _ = write!(out, " {}: |", &dashes[1..]);
        }
    }
    out.push('\n');
    for r in rows {
        out.push_str(&line(r));
    }
    out
}

/// A parameter count the way papers print it (`1.94M`, `512.0k`).
fn format_params(n: usize) -> String {
    if n >= 1_000_000 {
        format!("{:.2}M", n as f64 / 1e6)
    } else if n >= 1_000 {
        format!("{:.1}k", n as f64 / 1e3)
    } else {
        n.to_string()
    }
}

pub(crate) fn min_overlap_of(
    rows: &[AblationRow],
    class: ObjectClass,
    setting: usize,
    m: Metric,
) -> String {
    rows.iter()
        .find_map(|r| r.report.settings.get(setting))
        .and_then(|s| s.min_overlap(class, m))
        .map_or("?".to_string(), |v| format!("{v:.2}"))
}

/// A warning when the rows were not evaluated alike, which would make the comparison
/// meaningless (different frames, ground truth or overlap setting).
fn consistency_note(rows: &[AblationRow], class: ObjectClass, setting: usize) -> Option<String> {
    let first = rows.first()?;
    let key = |r: &AblationRow| {
        (
            r.report.frames,
            r.report.n_gt(class),
            r.report.settings.get(setting).copied(),
        )
    };
    let k0 = key(first);
    rows.iter().any(|r| key(r) != k0).then(|| {
        "Warning: the configurations were not evaluated on the same frames, ground truth \
         and overlap setting; their rows are not comparable."
            .to_string()
    })
}

/// The paper-style ablation table of `class` under overlap setting `setting` (an index
/// into the reports' settings): two Markdown tables, AP_R40 (the current benchmark)
/// then AP11 (what older papers report), each with one row per configuration and
/// columns 3D easy / moderate / hard, BEV easy / moderate / hard, and parameters,
/// multiply-adds (G) and frames/s when some row gives them. The best value of each AP column is bold;
/// `n/a` marks a result the report lacks.
pub fn ablation_table(rows: &[AblationRow], class: ObjectClass, setting: usize) -> String {
    let mut out = String::new();
    let (frames, n_gt) = rows
        .first()
        .map_or((0, [0; 3]), |r| (r.report.frames, r.report.n_gt(class)));
    let with_params = rows.iter().any(|r| r.params.is_some());
    let with_macs = rows.iter().any(|r| r.multiply_adds.is_some());
    let with_fps = rows.iter().any(|r| r.frames_per_second.is_some());
    for (label, r40) in [("AP_R40", true), ("AP11", false)] {
        let _ = writeln!(
            out,
            "{class}, {label} in % (3D IoU > {}, BEV IoU > {}; {frames} frames; \
             {} / {} / {} ground-truth boxes easy / moderate / hard)\n",
            min_overlap_of(rows, class, setting, Metric::ThreeD),
            min_overlap_of(rows, class, setting, Metric::Bev),
            n_gt[0],
            n_gt[1],
            n_gt[2],
        );
        let mut header = vec!["Configuration".to_string()];
        for m in ["3D", "BEV"] {
            for d in ["Easy", "Mod.", "Hard"] {
                header.push(format!("{m} {d}"));
            }
        }
        let cells: Vec<Vec<Cell>> = rows
            .iter()
            .map(|r| {
                [Metric::ThreeD, Metric::Bev]
                    .iter()
                    .flat_map(|&m| {
                        let res = r.report.get(class, m, setting);
                        (0..3).map(move |d| {
                            res.map_or(Cell::Missing, |res| {
                                Cell::Ap(if r40 { res.ap40[d] } else { res.ap11[d] })
                            })
                        })
                    })
                    .collect()
            })
            .collect();
        let mut body = format_columns(&cells);
        for (text, r) in body.iter_mut().zip(rows) {
            text.insert(0, r.name.clone());
            if with_params {
                text.push(r.params.map_or("n/a".to_string(), format_params));
            }
            if with_macs {
                text.push(
                    r.multiply_adds
                        .map_or("n/a".to_string(), |m| format!("{:.2}", m as f64 / 1e9)),
                );
            }
            if with_fps {
                text.push(
                    r.frames_per_second
                        .map_or("n/a".to_string(), |f| format!("{f:.1}")),
                );
            }
        }
        if with_params {
            header.push("Params".to_string());
        }
        if with_macs {
            header.push("GMACs".to_string());
        }
        if with_fps {
            header.push("Frames/s".to_string());
        }
        out.push_str(&markdown_table(&header, &body));
        out.push('\n');
    }
    if let Some(note) = consistency_note(rows, class, setting) {
        let _ = writeln!(out, "{note}\n");
    }
    out
}

pub(crate) fn bin_header(axis: BreakdownAxis, bin: &str) -> String {
    match axis {
        BreakdownAxis::Occlusion => format!("Occl. {bin}"),
        BreakdownAxis::Distance => bin.to_string(),
        BreakdownAxis::LidarPoints => format!("{bin} pts"),
    }
}

pub(crate) fn find_bin<'a>(
    rows: &'a [BreakdownRow],
    class: ObjectClass,
    metric: Metric,
    setting: usize,
    axis: BreakdownAxis,
    bin: &str,
) -> Option<&'a BreakdownRow> {
    rows.iter().find(|b| {
        b.class == class
            && b.metric == metric
            && b.setting == setting
            && b.axis == axis
            && b.bin == bin
    })
}

/// The breakdown of every configuration side by side: for 3D then BEV, a Markdown table
/// with one row per configuration and one column per bin (occlusion 0 / 1 / 2,
/// distance 0-20 / 20-40 / 40+ m, then LiDAR points <100 / 100-200 / >200 where
/// counted), AP_R40 in % at `difficulty`, the best of each column bold, and a last row
/// with the ground-truth boxes per bin (how much each number can be trusted).
/// `Hard` is the only difficulty at which every occlusion level has ground truth.
/// `-` marks a bin without ground truth, `n/a` a configuration without a breakdown.
pub fn ablation_breakdown_table(
    rows: &[AblationRow],
    class: ObjectClass,
    setting: usize,
    difficulty: Difficulty,
) -> String {
    let axes: Vec<BreakdownAxis> = BreakdownAxis::ALL
        .into_iter()
        .filter(|&a| {
            rows.iter()
                .filter_map(|r| r.breakdown.as_deref())
                .any(|b| b.iter().any(|b| b.axis == a && b.class == class))
        })
        .collect();
    if axes.is_empty() {
        return format!("No {class} breakdown: no configuration has one.\n");
    }
    let d = difficulty.index();
    let bins: Vec<(BreakdownAxis, &'static str)> = axes
        .iter()
        .flat_map(|&a| a.bins().map(|b| (a, b)))
        .collect();
    let mut out = String::new();
    for (metric, label) in [(Metric::ThreeD, "3D"), (Metric::Bev, "BEV")] {
        let _ = writeln!(
            out,
            "{class}, {label} AP_R40 in % by {} ({}, IoU > {})\n",
            axes.iter()
                .map(|a| a.as_str().replace('_', " "))
                .collect::<Vec<_>>()
                .join(", "),
            difficulty.as_str(),
            min_overlap_of(rows, class, setting, metric),
        );
        let mut header = vec!["Configuration".to_string()];
        header.extend(bins.iter().map(|&(a, b)| bin_header(a, b)));
        let cells: Vec<Vec<Cell>> = rows
            .iter()
            .map(|r| {
                bins.iter()
                    .map(|&(axis, bin)| {
                        let found = r
                            .breakdown
                            .as_deref()
                            .and_then(|b| find_bin(b, class, metric, setting, axis, bin));
                        match found {
                            None => Cell::Missing,
                            Some(b) => b.ap40[d].map_or(Cell::NoGt, Cell::Ap),
                        }
                    })
                    .collect()
            })
            .collect();
        let mut body = format_columns(&cells);
        for (text, r) in body.iter_mut().zip(rows) {
            text.insert(0, r.name.clone());
        }
        // Ground truth per bin from the first configuration that has the bin: the
        // frames are the same for every row (or the warning below says otherwise).
        let mut counts = vec!["*ground truth*".to_string()];
        counts.extend(bins.iter().map(|&(axis, bin)| {
            rows.iter()
                .filter_map(|r| r.breakdown.as_deref())
                .find_map(|b| find_bin(b, class, metric, setting, axis, bin))
                .map_or("n/a".to_string(), |b| b.n_gt[d].to_string())
        }));
        body.push(counts);
        out.push_str(&markdown_table(&header, &body));
        out.push('\n');
    }
    if let Some(note) = consistency_note(rows, class, setting) {
        let _ = writeln!(out, "{note}\n");
    }
    out
}

#[derive(Serialize)]
struct JsonConfiguration<'a> {
    name: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    params: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    multiply_adds: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    frames_per_second: Option<f64>,
    frames: usize,
    results: Vec<JsonRow>,
    #[serde(skip_serializing_if = "Option::is_none")]
    breakdown: Option<Vec<JsonBreakdownRow>>,
}

#[derive(Serialize)]
struct JsonAblation<'a> {
    configurations: Vec<JsonConfiguration<'a>>,
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    against_baseline: Vec<JsonDifference<'a>>,
}

#[derive(Serialize)]
struct JsonDifference<'a> {
    name: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    seed: Option<u64>,
    #[serde(flatten)]
    result: &'a crate::PairedBootstrap,
}

/// The whole ablation as JSON: `{"configurations": [{"name", "params"?,
/// "multiply_adds"?, "frames_per_second"?, "frames", "results", "breakdown"?}, ...]}`, where `results`
/// and `breakdown` have the rows of [`to_json`](crate::to_json) (AP in percent), and, given
/// `differences`, `"against_baseline": [{"name", "seed"? (of the training), "frames",
/// "resamples", "resample_seed", "confidence", "rows"}]` with the rows of
/// [`paired_bootstrap`](crate::paired_bootstrap).
pub fn ablation_to_json(rows: &[AblationRow], differences: &[crate::RowDifference]) -> String {
    let doc = JsonAblation {
        against_baseline: differences
            .iter()
            .map(|d| JsonDifference {
                name: d.name,
                seed: d.seed,
                result: d.result,
            })
            .collect(),
        configurations: rows
            .iter()
            .map(|r| JsonConfiguration {
                name: &r.name,
                params: r.params,
                multiply_adds: r.multiply_adds,
                frames_per_second: r.frames_per_second,
                frames: r.report.frames,
                results: r.report.results.iter().map(Into::into).collect(),
                breakdown: r
                    .breakdown
                    .as_ref()
                    .map(|b| b.iter().map(Into::into).collect()),
            })
            .collect(),
    };
    let mut text = serde_json::to_string_pretty(&doc).expect("plain data serialises");
    text.push('\n');
    text
}

/// Writes [`ablation_to_json`] to `path` atomically (a reader never sees half a file).
pub fn write_ablation_json(
    path: &Path,
    rows: &[AblationRow],
    differences: &[crate::RowDifference],
) -> Result<(), EvalError> {
    let json = ablation_to_json(rows, differences);
    fusiondet_kitti::write_atomic(path, json.as_bytes()).map_err(|e| EvalError::Dir {
        path: path.to_path_buf(),
        message: format!("cannot write the ablation JSON: {e}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::{MetricResult, PrCurve};
    use crate::{EvalConfig, FrameDet, OverlapSetting, evaluate, evaluate_breakdown, synthetic};
    use fusiondet_kitti::ObjectClass::Car;

    /// A Car report whose APs encode where they belong: 3D AP_R40 = base + 1, 2, 3
    /// (easy, moderate, hard), BEV = that + 10, AP11 = AP_R40 + 0.5.
    fn report(base: f64) -> EvalReport {
        let results = [Metric::Bev, Metric::ThreeD]
            .into_iter()
            .map(|metric| {
                let off = if metric == Metric::Bev { 10.0 } else { 0.0 };
                let ap40 = [1.0, 2.0, 3.0].map(|k| base + off + k);
                let mut curves: [PrCurve; 3] = Default::default();
                for (c, n) in curves.iter_mut().zip([5, 8, 9]) {
                    c.n_gt = n;
                }
                MetricResult {
                    class: Car,
                    metric,
                    setting: 0,
                    min_overlap: 0.7,
                    ap11: ap40.map(|v| v + 0.5),
                    ap40,
                    curves,
                }
            })
            .collect();
        EvalReport {
            frames: 20,
            classes: vec![Car],
            settings: vec![OverlapSetting::STRICT],
            aos_computed: true,
            results,
        }
    }

    /// Breakdown rows whose AP_R40 encodes the cell: base + 10 × axis + bin (+ 0.25 for
    /// BEV), the same at every difficulty; occlusion 2 has no ground truth at moderate.
    fn breakdown(base: f64) -> Vec<BreakdownRow> {
        let mut out = Vec::new();
        for metric in [Metric::ThreeD, Metric::Bev] {
            for (ai, axis) in [BreakdownAxis::Distance, BreakdownAxis::Occlusion]
                .into_iter()
                .enumerate()
            {
                for (bi, bin) in axis.bins().into_iter().enumerate() {
                    let v = base
                        + 10.0 * ai as f64
                        + bi as f64
                        + if metric == Metric::Bev { 0.25 } else { 0.0 };
                    let empty = axis == BreakdownAxis::Occlusion && bin == "2";
                    out.push(BreakdownRow {
                        class: Car,
                        metric,
                        setting: 0,
                        min_overlap: 0.7,
                        axis,
                        bin,
                        n_gt: [4, if empty { 0 } else { 6 + bi }, 7 + bi],
                        ap40: [Some(v), (!empty).then_some(v), Some(v)],
                        curves: Default::default(),
                    });
                }
            }
        }
        out
    }

    /// The cells of the table row starting with `name`, bold marks removed.
    fn cells(table: &str, name: &str) -> Vec<String> {
        let line = table
            .lines()
            .find(|l| l.trim_start_matches('|').trim().starts_with(name))
            .unwrap_or_else(|| panic!("no row {name} in\n{table}"));
        line.trim_matches('|')
            .split('|')
            .map(|c| c.trim().replace("**", ""))
            .collect()
    }

    fn rows() -> Vec<AblationRow> {
        let mut a = AblationRow::new("fconvnet", report(50.0));
        a.params = Some(1_940_000);
        a.breakdown = Some(breakdown(30.0));
        let mut b = AblationRow::new("saf+lfa", report(70.0));
        b.frames_per_second = Some(12.345);
        b.breakdown = Some(breakdown(40.0));
        let c = AblationRow::new("fcam", report(60.0));
        vec![a, b, c]
    }

    #[test]
    fn ablation_values_land_in_their_cells() {
        let table = ablation_table(&rows(), Car, 0);
        let (r40, r11) = table.split_once("AP11 in %").unwrap();
        assert!(r40.contains("Car, AP_R40 in % (3D IoU > 0.70, BEV IoU > 0.70; 20 frames"));
        assert!(r40.contains("5 / 8 / 9 ground-truth boxes"));
        let header = cells(r40, "Configuration");
        assert_eq!(
            header,
            [
                "Configuration",
                "3D Easy",
                "3D Mod.",
                "3D Hard",
                "BEV Easy",
                "BEV Mod.",
                "BEV Hard",
                "Params",
                "Frames/s"
            ]
        );
        assert_eq!(
            cells(r40, "fconvnet"),
            [
                "fconvnet", "51.00", "52.00", "53.00", "61.00", "62.00", "63.00", "1.94M", "n/a"
            ]
        );
        assert_eq!(
            cells(r40, "saf+lfa"),
            [
                "saf+lfa", "71.00", "72.00", "73.00", "81.00", "82.00", "83.00", "n/a", "12.3"
            ]
        );
        assert_eq!(
            cells(r11, "fcam")[1..7],
            ["61.50", "62.50", "63.50", "71.50", "72.50", "73.50"]
        );
        // The best configuration is bold in every AP column, no other.
        let best = r40.lines().find(|l| l.contains("saf+lfa")).unwrap();
        assert_eq!(best.matches("**").count(), 12);
        assert!(!r40.lines().any(|l| l.contains("fcam") && l.contains("**")));
        assert!(!table.contains("Warning"));
    }

    #[test]
    fn missing_results_and_mismatched_reports_are_flagged() {
        let mut rows = rows();
        rows[2].report.results.retain(|r| r.metric != Metric::Bev);
        rows[2].report.frames = 19;
        let table = ablation_table(&rows, Car, 0);
        assert_eq!(cells(&table, "fcam")[4..7], ["n/a", "n/a", "n/a"]);
        assert!(table.contains("Warning: the configurations were not evaluated"));
        // No size or speed anywhere: no such columns.
        for r in &mut rows {
            r.params = None;
            r.frames_per_second = None;
        }
        assert_eq!(
            cells(&ablation_table(&rows, Car, 0), "Configuration").len(),
            7
        );
        // Nothing to compare: headings and an empty table, no panic.
        assert!(ablation_table(&[], Car, 0).contains("| Configuration |"));
    }

    #[test]
    fn breakdown_bins_are_columns_and_configurations_rows() {
        let table = ablation_breakdown_table(&rows(), Car, 0, Difficulty::Moderate);
        let (three_d, bev) = table.split_once("BEV AP_R40").unwrap();
        assert!(three_d.starts_with("Car, 3D AP_R40 in % by distance, occlusion (moderate"));
        assert_eq!(
            cells(three_d, "Configuration"),
            [
                "Configuration",
                "0-20m",
                "20-40m",
                "40m+",
                "Occl. 0",
                "Occl. 1",
                "Occl. 2"
            ]
        );
        assert_eq!(
            cells(three_d, "saf+lfa"),
            ["saf+lfa", "40.00", "41.00", "42.00", "50.00", "51.00", "-"]
        );
        assert_eq!(
            cells(bev, "fconvnet"),
            ["fconvnet", "30.25", "31.25", "32.25", "40.25", "41.25", "-"]
        );
        assert_eq!(cells(bev, "fcam")[1..], ["n/a"; 6]);
        assert_eq!(
            cells(three_d, "*ground truth*")[1..],
            ["6", "7", "8", "6", "7", "0"]
        );
        // At hard, occlusion 2 has values; saf+lfa is best there.
        let hard = ablation_breakdown_table(&rows(), Car, 0, Difficulty::Hard);
        let line = hard.lines().find(|l| l.contains("saf+lfa")).unwrap();
        assert!(line.ends_with("| **52.00** |"), "{line}");
        assert!(
            ablation_breakdown_table(&rows()[2..], Car, 0, Difficulty::Hard)
                .starts_with("No Car breakdown")
        );
    }

    #[test]
    fn synthetic_evaluations_end_to_end() {
        let (gt, det) = synthetic::generate(60, 11);
        // A weaker configuration: every third detection lost.
        let weaker: Vec<FrameDet> = det
            .iter()
            .map(|f| {
                let objects = f.objects.iter().step_by(3).cloned().collect();
                FrameDet::new(f.id.clone(), objects)
            })
            .collect();
        let cfg = EvalConfig::default();
        let rows: Vec<AblationRow> = [("full", &det), ("weaker", &weaker)]
            .into_iter()
            .map(|(name, d)| {
                let mut row = AblationRow::new(name, evaluate(&gt, d, &cfg).unwrap());
                row.breakdown = Some(evaluate_breakdown(&gt, d, &cfg, None).unwrap());
                row.params = Some(123);
                row
            })
            .collect();
        let table = ablation_table(&rows, Car, 1);
        let want = rows[1].report.get(Car, Metric::ThreeD, 1).unwrap().ap40[1];
        assert_eq!(cells(&table, "weaker")[2], format!("{want:.2}"));
        assert_eq!(cells(&table, "weaker")[7], "123");
        let by_bin = ablation_breakdown_table(&rows, Car, 1, Difficulty::Hard);
        let far = rows[0]
            .breakdown
            .as_ref()
            .unwrap()
            .iter()
            .find(|b| {
                b.class == Car && b.metric == Metric::ThreeD && b.setting == 1 && b.bin == "40m+"
            })
            .unwrap();
        let shown = far.ap40[2].map_or("-".to_string(), |v| format!("{v:.2}"));
        assert_eq!(cells(&by_bin, "full")[3], shown);

        let json: serde_json::Value = serde_json::from_str(&ablation_to_json(&rows, &[])).unwrap();
        let configs = json["configurations"].as_array().unwrap();
        assert_eq!(configs.len(), 2);
        assert_eq!(configs[1]["name"], "weaker");
        assert_eq!(configs[1]["params"], 123);
        assert!(configs[1].get("frames_per_second").is_none());
        assert_eq!(configs[0]["frames"], 60);
        assert_eq!(
            configs[1]["results"].as_array().unwrap().len(),
            rows[1].report.results.len()
        );
        assert!(!configs[0]["breakdown"].as_array().unwrap().is_empty());

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ablation.json");
        write_ablation_json(&path, &rows, &[]).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            ablation_to_json(&rows, &[])
        );
        assert!(write_ablation_json(&dir.path().join("no/such/dir/a.json"), &rows, &[]).is_err());
    }
}
