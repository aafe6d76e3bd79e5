//! Results: precision/recall curves per class, metric and difficulty, the devkit's AP
//! averages, the printed table and the JSON document.

use crate::engine::Counts;
use crate::protocol::{Difficulty, Metric, N_SAMPLE_PTS, OverlapSetting};
use fusiondet_kitti::ObjectClass;
use serde::Serialize;
use std::fmt::Write as _;

/// The statistics of one class × metric × difficulty at each score threshold, as the
/// devkit computes them; enough to draw precision–recall curves.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PrCurve {
    /// Non-ignored ground-truth boxes (the recall denominator).
    pub n_gt: usize,
    /// The score thresholds chosen for the recall samples, descending (at most 41).
    pub thresholds: Vec<f64>,
    pub tp: Vec<u64>,
    pub fp: Vec<u64>,
    pub fn_: Vec<u64>,
    /// tp / (tp + fn) at each threshold.
    pub recall: Vec<f64>,
    /// tp / (tp + fp) at each threshold; for AOS rows the summed orientation similarity
    /// over (tp + fp). 0 where tp + fp = 0 (the devkit would divide 0 by 0 there).
    pub precision: Vec<f64>,
    /// The 41 values the AP averages: `precision` padded with zeros to 41 entries, then
    /// made monotone from the right (entry i = max of entries i..41).
    pub interpolated: Vec<f64>,
}

impl PrCurve {
    pub(crate) fn from_counts(c: &Counts, aos: bool) -> PrCurve {
        let n = c.thresholds.len();
        let ratio = |num: f64, den: u64| if den == 0 { 0.0 } else { num / den as f64 };
        let recall = (0..n)
            .map(|i| ratio(c.tp[i] as f64, c.tp[i] + c.fn_[i]))
            .collect();
        let precision: Vec<f64> = (0..n)
            .map(|i| {
                let num = if aos { c.similarity[i] } else { c.tp[i] as f64 };
                ratio(num, c.tp[i] + c.fp[i])
            })
            .collect();
        let mut interpolated = vec![0.0; N_SAMPLE_PTS];
        interpolated[..n].copy_from_slice(&precision);
        for i in (0..N_SAMPLE_PTS - 1).rev() {
            interpolated[i] = interpolated[i].max(interpolated[i + 1]);
        }
        PrCurve {
            n_gt: c.n_gt,
            thresholds: c.thresholds.clone(),
            tp: c.tp.clone(),
            fp: c.fp.clone(),
            fn_: c.fn_.clone(),
            recall,
            precision,
            interpolated,
        }
    }

    /// 11-point AP in percent: mean of interpolated entries 0, 4, ..., 40.
    pub fn ap11(&self) -> f64 {
        let sum: f64 = (0..N_SAMPLE_PTS)
            .step_by(4)
            .map(|i| self.interpolated[i])
            .sum();
        sum / 11.0 * 100.0
    }

    /// 40-point AP in percent: mean of interpolated entries 1..=40 (entry 0, recall 0, is left out).
    pub fn ap40(&self) -> f64 {
        let sum: f64 = (1..N_SAMPLE_PTS).map(|i| self.interpolated[i]).sum();
        sum / 40.0 * 100.0
    }
}

/// One row of the results: a class, a metric and an overlap setting, for the three
/// difficulties.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricResult {
    pub class: ObjectClass,
    pub metric: Metric,
    /// Index into [`EvalReport::settings`].
    pub setting: usize,
    /// The minimum overlap used (AOS rows: the bbox one).
    pub min_overlap: f64,
    /// AP in percent for easy, moderate, hard.
    pub ap11: [f64; 3],
    pub ap40: [f64; 3],
    /// Per difficulty (easy, moderate, hard).
    pub curves: [PrCurve; 3],
}

impl MetricResult {
    pub(crate) fn new(
        class: ObjectClass,
        metric: Metric,
        setting: usize,
        min_overlap: f64,
        curves: [PrCurve; 3],
    ) -> Self {
        MetricResult {
            class,
            metric,
            setting,
            min_overlap,
            ap11: std::array::from_fn(|d| curves[d].ap11()),
            ap40: std::array::from_fn(|d| curves[d].ap40()),
            curves,
        }
    }

    pub fn curve(&self, d: Difficulty) -> &PrCurve {
        &self.curves[d.index()]
    }
}

/// The outcome of an evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalReport {
    pub frames: usize,
    pub classes: Vec<ObjectClass>,
    pub settings: Vec<OverlapSetting>,
    /// False when some detection has alpha = −10 (the devkit's "no orientation"
    /// marker); there are no AOS rows then.
    pub aos_computed: bool,
    /// Per class, per setting: bbox, bev, 3d, aos rows (aos only if computed).
    pub results: Vec<MetricResult>,
}

impl EvalReport {
    /// The row for a class, metric and overlap setting (index into `settings`).
    pub fn get(&self, class: ObjectClass, metric: Metric, setting: usize) -> Option<&MetricResult> {
        self.results
            .iter()
            .find(|r| r.class == class && r.metric == metric && r.setting == setting)
    }

    /// Non-ignored ground-truth boxes of a class at each difficulty.
    pub fn n_gt(&self, class: ObjectClass) -> [usize; 3] {
        self.results
            .iter()
            .find(|r| r.class == class)
            .map(|r| std::array::from_fn(|d| r.curves[d].n_gt))
            .unwrap_or_default()
    }

    /// The printed table, laid out like the devkit/OpenPCDet one.
    pub fn table(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "KITTI object evaluation, {} frames (devkit protocol, 41 recall points; AP in %, easy, moderate, hard)",
            self.frames
        );
        if !self.aos_computed {
            let _ = writeln!(
                out,
                "(no AOS: some detection has alpha = -10, the devkit's \"no orientation\" marker)"
            );
        }
        for &class in &self.classes {
            let n = self.n_gt(class);
            let _ = write!(
                out,
                "{class}: {} / {} / {} ground-truth boxes",
                n[0], n[1], n[2]
            );
            if n.contains(&0) {
                let _ = write!(out, " (AP is 0 where there is none)");
            }
            out.push('\n');
            for (s, setting) in self.settings.iter().enumerate() {
                let mins =
                    Metric::OVERLAPS.map(|m| setting.min_overlap(class, m).unwrap_or(f64::NAN));
                for (label, r40) in [("AP", false), ("AP_R40", true)] {
                    let _ = writeln!(
                        out,
                        "{class} {label}@{:.2}, {:.2}, {:.2}:",
                        mins[0], mins[1], mins[2]
                    );
                    for metric in Metric::ALL {
                        if let Some(r) = self.get(class, metric, s) {
                            let ap = if r40 { r.ap40 } else { r.ap11 };
                            let _ = writeln!(
                                out,
                                "{:<4} AP:{:.4}, {:.4}, {:.4}",
                                metric.as_str(),
                                ap[0],
                                ap[1],
                                ap[2]
                            );
                        }
                    }
                }
            }
        }
        out
    }
}

#[derive(Serialize)]
pub(crate) struct JsonRow {
    class: &'static str,
    metric: &'static str,
    min_overlap: f64,
    ap11: [f64; 3],
    ap40: [f64; 3],
}

impl From<&MetricResult> for JsonRow {
    fn from(r: &MetricResult) -> Self {
        JsonRow {
            class: r.class.as_str(),
            metric: r.metric.as_str(),
            min_overlap: r.min_overlap,
            ap11: r.ap11,
            ap40: r.ap40,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counts(tp: &[u64], fp: &[u64], fn_: &[u64]) -> Counts {
        Counts {
            n_gt: (tp[0] + fn_[0]) as usize,
            thresholds: (0..tp.len()).map(|i| 1.0 - i as f64 * 0.01).collect(),
            tp: tp.to_vec(),
            fp: fp.to_vec(),
            fn_: fn_.to_vec(),
            similarity: vec![0.0; tp.len()],
        }
    }

    #[test]
    fn one_perfect_detection_gives_ap11_1_over_11_and_ap40_zero() {
        let c = PrCurve::from_counts(&counts(&[1], &[0], &[0]), false);
        assert!((c.ap11() - 100.0 / 11.0).abs() < 1e-12);
        assert_eq!(c.ap40(), 0.0);
    }

    #[test]
    fn precision_is_made_monotone_from_the_right() {
        let c = PrCurve::from_counts(&counts(&[1, 1, 2], &[0, 1, 1], &[1, 1, 0]), false);
        assert_eq!(c.precision, [1.0, 0.5, 2.0 / 3.0]);
        assert_eq!(&c.interpolated[..4], &[1.0, 2.0 / 3.0, 2.0 / 3.0, 0.0]);
        assert_eq!(c.recall, [0.5, 0.5, 1.0]);
    }
}
