//! The printed table (papers' layout: a column per class, alphabetically as VoteNet's and
//! its successors' SUN RGB-D tables order them, a row per IoU threshold, the mean last) and
//! the JSON document.

use super::ap::IndoorReport;
use crate::error::EvalError;
use fusiondet_sunrgbd::SunClass;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// The classes in the column order of the papers' tables.
fn table_order() -> [SunClass; 10] {
    let mut classes = SunClass::ALL;
    classes.sort_by_key(|c| c.as_str());
    classes
}

/// A threshold as the table and the JSON name it: `0.25`, `0.5`.
fn threshold_name(iou: f64) -> String {
    format!("{iou}")
}

impl IndoorReport {
    /// The text table: AP in percent per class and threshold, `-` for a class without
    /// ground truth (left out of the mean), and the ground-truth counts.
    pub fn table(&self) -> String {
        let classes = table_order();
        let width = |c: SunClass| c.as_str().len().max(6);
        let mut out = String::new();
        let n_gt: usize = self
            .thresholds
            .first()
            .map(|&t| {
                self.results
                    .iter()
                    .filter(|r| r.iou == t)
                    .map(|r| r.n_gt)
                    .sum()
            })
            .unwrap_or(0);
        let _ = writeln!(
            out,
            "SUN RGB-D 3D detection: {} scenes, {n_gt} ground-truth boxes of the 10 classes \
             (VoteNet's protocol, exact rotated 3D IoU)",
            self.scenes
        );
        let _ = write!(out, "{:<8}", "");
        for &c in &classes {
            let _ = write!(out, "  {:>w$}", c.as_str(), w = width(c));
        }
        let _ = writeln!(out, "  {:>6}", "mAP");
        let cell = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.2}"));
        for &t in &self.thresholds {
            let _ = write!(out, "{:<8}", format!("AP@{}", threshold_name(t)));
            for &c in &classes {
                let ap = self.get(c, t).and_then(|r| r.ap);
                let _ = write!(out, "  {:>w$}", cell(ap), w = width(c));
            }
            let _ = writeln!(out, "  {:>6}", cell(self.map(t)));
        }
        if let Some(&t) = self.thresholds.first() {
            let _ = write!(out, "{:<8}", "GT");
            for &c in &classes {
                let n = self.get(c, t).map_or(0, |r| r.n_gt);
                let _ = write!(out, "  {:>w$}", n, w = width(c));
            }
            out.push('\n');
        }
        out
    }
}

#[derive(Serialize)]
struct JsonRow {
    class: &'static str,
    iou: f64,
    ap: Option<f64>,
}

#[derive(Serialize)]
struct JsonDoc {
    results: Vec<JsonRow>,
    map: BTreeMap<String, Option<f64>>,
}

/// `{"results": [{"class", "iou", "ap"}, ...], "map": {"0.25": m, "0.5": m}}`: AP in percent,
/// one row per class and threshold (threshold by threshold, classes in id order), `null`
/// for a class without ground truth and for a mean over no class.
pub fn indoor_json(report: &IndoorReport) -> String {
    let doc = JsonDoc {
        results: report
            .results
            .iter()
            .map(|r| JsonRow {
                class: r.class.as_str(),
                iou: r.iou,
                ap: r.ap,
            })
            .collect(),
        map: report
            .thresholds
            .iter()
            .map(|&t| (threshold_name(t), report.map(t)))
            .collect(),
    };
    let mut text = serde_json::to_string_pretty(&doc).expect("plain data serialises");
    text.push('\n');
    text
}

/// Writes [`indoor_json`] to `path` atomically.
pub fn write_indoor_json(path: &Path, report: &IndoorReport) -> Result<(), EvalError> {
    fusiondet_kitti::write_atomic(path, indoor_json(report).as_bytes()).map_err(|e| {
        EvalError::Dir {
            path: path.to_path_buf(),
            message: format!("cannot write the JSON output: {e}"),
        }
    })
}
