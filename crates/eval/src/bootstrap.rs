//! Paired bootstrap over frames: how far the AP difference between two detectors on the same
//! frames could move if the frames had been drawn again.
//!
//! A difference of a point of AP_R40 on a few hundred frames can come from a handful of
//! boxes (one confident near miss, IoU 0.68 where 0.7 is needed, outranks a hundred true
//! positives). To say whether model A is ahead of model B beyond that, the frames are
//! resampled with replacement, both result sets are evaluated on each resample with the
//! devkit's own matching (a frame drawn twice counts twice), and the spread of A − B over
//! the resamples gives a percentile interval and the share of resamples in which A leads.
//! Pairing (the same resample for both) removes what the frames share: a hard frame is hard
//! for both models.
//!
//! The resample indices come from the project's seeded generator, one stream per resample,
//! so the result depends on the seed and the number of resamples only, not on thread count.

use crate::engine::{self, Task};
use crate::error::EvalError;
use crate::evaluate::{EvalConfig, RowTask, tasks_for, validate};
use crate::frames::{FrameDet, FrameGt};
use crate::protocol::{Difficulty, Metric};
use crate::report::PrCurve;
use fusiondet_dataset::rng::Sampler;
use fusiondet_kitti::ObjectClass;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;

/// Stream domain of the resample draws ("BOOT").
const RESAMPLE_DOMAIN: u64 = 0x424F_4F54;

/// How the frames are resampled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resampling {
    /// Number of resamples (each as many frames as the set, drawn with replacement).
    pub resamples: usize,
    /// Seed of the draws.
    pub seed: u64,
    /// Coverage of the reported interval, in (0, 1) (0.95: the 2.5th to 97.5th percentile).
    pub confidence: f64,
}

/// One (class, overlap measure, overlap setting) row: both AP_R40s and their difference.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DifferenceRow {
    #[serde(serialize_with = "as_name")]
    pub class: ObjectClass,
    #[serde(serialize_with = "as_name")]
    pub metric: Metric,
    /// Index into the configuration's overlap settings.
    #[serde(skip)]
    pub setting: usize,
    pub min_overlap: f64,
    /// AP_R40 in percent of the results and of the baseline on the frames as given (easy,
    /// moderate, hard).
    pub ap40: [f64; 3],
    pub baseline_ap40: [f64; 3],
    /// `ap40 − baseline_ap40`.
    pub difference: [f64; 3],
    /// Percentile interval of the difference over the resamples.
    pub interval_low: [f64; 3],
    pub interval_high: [f64; 3],
    /// Share of resamples in which the results' AP is above the baseline's.
    pub ahead: [f64; 3],
}

fn as_name<T: std::fmt::Display, S: serde::Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(v)
}

/// The outcome: the rows and how they were resampled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairedBootstrap {
    pub frames: usize,
    pub resamples: usize,
    #[serde(rename = "resample_seed")]
    pub seed: u64,
    pub confidence: f64,
    pub rows: Vec<DifferenceRow>,
}

/// AP_R40 of every row at every difficulty for the frames `order` names.
fn ap40_rows(
    prep: &engine::Prepared,
    order: &[usize],
    tasks: &[Task],
    rows: &[RowTask],
) -> Vec<[f64; 3]> {
    let counts = engine::run_frames(prep, order, tasks, None, false);
    rows.iter()
        .map(|r| std::array::from_fn(|d| PrCurve::from_counts(&counts[r.task][d], false).ap40()))
        .collect()
}

/// The `q`-quantile of sorted values, interpolated linearly between order statistics.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Evaluates `det` and `baseline` (both for the frames of `gt`, in its order) on `gt` and on
/// `resampling.resamples` resamples of its frames, and reports AP_R40 of the bbox, bev and
/// 3d rows of `cfg` with the difference's interval (a row both overlap settings share, such
/// as Car bbox at 0.7, once).
pub fn paired_bootstrap(
    gt: &[FrameGt],
    det: &[FrameDet],
    baseline: &[FrameDet],
    cfg: &EvalConfig,
    resampling: Resampling,
) -> Result<PairedBootstrap, EvalError> {
    validate(gt, det, cfg)?;
    validate(gt, baseline, cfg)?;
    if gt.is_empty() {
        return Err(EvalError::Class("no frames to resample".into()));
    }
    if resampling.resamples < 2 {
        return Err(EvalError::Class(format!(
            "{} resamples: an interval needs at least 2 (1,000 or more is usual)",
            resampling.resamples
        )));
    }
    if !(resampling.confidence > 0.0 && resampling.confidence < 1.0) {
        return Err(EvalError::Class(format!(
            "confidence {}: must lie strictly between 0 and 1 (e.g. 0.95)",
            resampling.confidence
        )));
    }
    let (tasks, mut rows) = tasks_for(cfg, &Metric::OVERLAPS);
    // A row both settings share (Car bbox at 0.7) is reported once.
    let mut seen = Vec::new();
    rows.retain(|r| {
        let first = !seen.contains(&r.task);
        seen.push(r.task);
        first
    });
    let prep_a = engine::prepare(gt, det, &cfg.classes)?;
    let prep_b = engine::prepare(gt, baseline, &cfg.classes)?;
    let n = gt.len();
    let every_frame: Vec<usize> = (0..n).collect();
    let full_a = ap40_rows(&prep_a, &every_frame, &tasks, &rows);
    let full_b = ap40_rows(&prep_b, &every_frame, &tasks, &rows);

    // Per resample, per row: the difference at each difficulty.
    let differences: Vec<Vec<[f64; 3]>> = (0..resampling.resamples)
        .into_par_iter()
        .map(|r| {
            let mut sampler = Sampler::from_path(resampling.seed, &[RESAMPLE_DOMAIN, r as u64]);
            let order: Vec<usize> = (0..n).map(|_| sampler.below(n)).collect();
            let a = ap40_rows(&prep_a, &order, &tasks, &rows);
            let b = ap40_rows(&prep_b, &order, &tasks, &rows);
            a.iter()
                .zip(&b)
                .map(|(a, b)| std::array::from_fn(|d| a[d] - b[d]))
                .collect()
        })
        .collect();

    let tail = (1.0 - resampling.confidence) / 2.0;
    let rows = rows
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let class = cfg.classes[r.class_idx];
            let per_difficulty = |d: usize| {
                let mut v: Vec<f64> = differences.iter().map(|row| row[i][d]).collect();
                v.sort_by(f64::total_cmp);
                let ahead = v.iter().filter(|&&x| x > 0.0).count() as f64 / v.len() as f64;
                (quantile(&v, tail), quantile(&v, 1.0 - tail), ahead)
            };
            let stats: [(f64, f64, f64); 3] = std::array::from_fn(per_difficulty);
            DifferenceRow {
                class,
                metric: r.metric,
                setting: r.setting,
                min_overlap: cfg.settings[r.setting]
                    .min_overlap(class, r.metric)
                    .expect("validated class"),
                ap40: full_a[i],
                baseline_ap40: full_b[i],
                difference: std::array::from_fn(|d| full_a[i][d] - full_b[i][d]),
                interval_low: stats.map(|s| s.0),
                interval_high: stats.map(|s| s.1),
                ahead: stats.map(|s| s.2),
            }
        })
        .collect();
    Ok(PairedBootstrap {
        frames: n,
        resamples: resampling.resamples,
        seed: resampling.seed,
        confidence: resampling.confidence,
        rows,
    })
}

impl PairedBootstrap {
    /// The printed table: per class and overlap setting, one line per measure and difficulty.
    pub fn table(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "AP_R40 against the baseline, {} frames: results vs baseline, difference, {:.0}% interval over {} resamples of the frames (seed {}), share of resamples where the results lead",
            self.frames,
            self.confidence * 100.0,
            self.resamples,
            self.seed
        );
        for r in &self.rows {
            for d in Difficulty::ALL {
                let i = d.index();
                let _ = writeln!(
                    out,
                    "{} {:<4} @{:.2} {:<8} {:>6.2} vs {:>6.2}  {:+6.2}  [{:+6.2}, {:+6.2}]  ahead in {:>5.1}%",
                    r.class,
                    r.metric.as_str(),
                    r.min_overlap,
                    d.as_str(),
                    r.ap40[i],
                    r.baseline_ap40[i],
                    r.difference[i],
                    r.interval_low[i],
                    r.interval_high[i],
                    r.ahead[i] * 100.0
                );
            }
        }
        out
    }
}

/// One row of an ablation's interval table: a configuration, the training seed of its run
/// (`None`: the configuration's own) and its bootstrap against the baseline's run of that seed.
#[derive(Debug, Clone, Copy)]
pub struct RowDifference<'a> {
    pub name: &'a str,
    pub seed: Option<u64>,
    pub result: &'a PairedBootstrap,
}

/// An ablation's differences from its baseline for `class` and `metric` at the official
/// overlap: per row and difficulty the difference, its interval and the share of resamples
/// in which the row leads, as a markdown table.
pub fn difference_table(rows: &[RowDifference], class: ObjectClass, metric: Metric) -> String {
    let Some(first) = rows.first() else {
        return String::new();
    };
    let label = match metric {
        Metric::ThreeD => "3D",
        Metric::Bev => "BEV",
        _ => metric.as_str(),
    };
    let out = format!(
        "{class}, {label} AP_R40 minus the baseline's (same training seed): difference [{:.0}% interval over {} resamples of the {} val frames, seed {}] and the share of resamples where the row leads\n\n",
        first.result.confidence * 100.0,
        first.result.resamples,
        first.result.frames,
        first.result.seed
    );
    let header: Vec<String> = ["Configuration", "Seed", "Easy", "Mod.", "Hard"]
        .map(String::from)
        .to_vec();
    let cells: Vec<Vec<String>> = rows
        .iter()
        .filter_map(|r| {
            // The first row of this class and metric: the official overlap setting's.
            let d = r
                .result
                .rows
                .iter()
                .find(|x| x.class == class && x.metric == metric && x.setting == 0)?;
            let mut line = vec![
                r.name.to_string(),
                r.seed.map_or("-".into(), |s| s.to_string()),
            ];
            line.extend((0..3).map(|i| {
                format!(
                    "{:+.2} [{:+.2}, {:+.2}] {:.0}%",
                    d.difference[i],
                    d.interval_low[i],
                    d.interval_high[i],
                    d.ahead[i] * 100.0
                )
            }));
            Some(line)
        })
        .collect();
    out + &crate::ablation::markdown_table(&header, &cells)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::tests_support::{det, gt};
    use crate::protocol::OverlapSetting;

    fn car_cfg() -> EvalConfig {
        EvalConfig {
            classes: vec![ObjectClass::Car],
            settings: vec![OverlapSetting::STRICT],
        }
    }

    /// `n` frames of one easy car each; `hits[i]` says whether the detection in frame i lies
    /// on the car (else 5 m beside it, still on it in the image), with score `score`.
    fn frames(n: usize, hits: &[bool], score: f64) -> (Vec<FrameGt>, Vec<FrameDet>) {
        let bbox = [100.0, 100.0, 200.0, 180.0];
        let g = (0..n)
            .map(|i| FrameGt::new(format!("{i:06}"), vec![gt(ObjectClass::Car, bbox)]))
            .collect();
        let d = (0..n)
            .map(|i| {
                let mut o = det(ObjectClass::Car, bbox, score);
                if !hits[i] {
                    o.box3d.x += 5.0;
                }
                FrameDet::new(format!("{i:06}"), vec![o])
            })
            .collect();
        (g, d)
    }

    fn run(a_hits: &[bool], b_hits: &[bool], seed: u64) -> PairedBootstrap {
        let (g, a) = frames(a_hits.len(), a_hits, 0.9);
        let (_, b) = frames(b_hits.len(), b_hits, 0.9);
        let resampling = Resampling {
            resamples: 200,
            seed,
            confidence: 0.95,
        };
        paired_bootstrap(&g, &a, &b, &car_cfg(), resampling).unwrap()
    }

    fn row(p: &PairedBootstrap, metric: Metric) -> &DifferenceRow {
        p.rows.iter().find(|r| r.metric == metric).unwrap()
    }

    #[test]
    fn identical_results_differ_by_nothing_on_every_resample() {
        let hits = [true, false, true, true, false, true, true, true];
        let p = run(&hits, &hits, 3);
        // bbox, bev and 3d at the one setting.
        assert_eq!(p.rows.len(), 3);
        for r in &p.rows {
            assert_eq!(r.difference, [0.0; 3]);
            assert_eq!(r.interval_low, [0.0; 3]);
            assert_eq!(r.interval_high, [0.0; 3]);
            assert_eq!(r.ahead, [0.0; 3]);
        }
    }

    #[test]
    fn a_model_that_finds_every_car_leads_on_every_resample() {
        // 40 frames: the devkit's AP_R40 reaches its top only with 40 or more ground-truth
        // boxes (one threshold per recall sample a true positive reaches).
        let all = [true; 40];
        let half: Vec<bool> = (0..40).map(|i| i % 2 == 0).collect();
        let p = run(&all, &half, 1);
        let r = row(&p, Metric::ThreeD);
        assert!(r.difference[1] > 40.0, "{:?}", r.difference);
        // Every resample holds some of the baseline's 20 missed frames (none only with
        // probability 2^-40) and none of the results'.
        assert!(r.interval_low[1] > 0.0, "{:?}", r.interval_low);
        assert_eq!(r.ahead[1], 1.0, "{:?}", r.ahead);
        // The results' lead is symmetric: swapping the two negates the difference.
        let q = run(&half, &all, 1);
        let s = row(&q, Metric::ThreeD);
        assert_eq!(s.difference[1], -r.difference[1]);
        assert!((s.interval_high[1] + r.interval_low[1]).abs() < 1e-9);
    }

    #[test]
    fn one_differing_frame_in_many_gives_an_interval_around_zero() {
        // Both models miss the same frames, except one frame only the results find.
        let mut a = [true; 40];
        let mut b = [true; 40];
        for i in (0..40).step_by(4) {
            a[i] = false;
            b[i] = false;
        }
        a[0] = true;
        let p = run(&a, &b, 7);
        let r = row(&p, Metric::Bev);
        assert!(r.difference[1] > 0.0);
        // The frame is absent from about a third of the resamples ((39/40)^40): then the two
        // are level, so the interval reaches down to 0 and the results lead in about 2/3.
        assert_eq!(r.interval_low[1], 0.0, "{:?}", r.interval_low);
        assert!(r.ahead[1] > 0.5 && r.ahead[1] < 0.8, "{:?}", r.ahead);
    }

    #[test]
    fn a_row_both_settings_share_is_reported_once() {
        let (g, a) = frames(4, &[true; 4], 0.9);
        let cfg = EvalConfig {
            classes: vec![ObjectClass::Car],
            settings: vec![OverlapSetting::STRICT, OverlapSetting::LOOSE],
        };
        let resampling = Resampling {
            resamples: 4,
            seed: 0,
            confidence: 0.9,
        };
        let p = paired_bootstrap(&g, &a, &a, &cfg, resampling).unwrap();
        let rows: Vec<(Metric, f64)> = p.rows.iter().map(|r| (r.metric, r.min_overlap)).collect();
        assert_eq!(
            rows,
            [
                (Metric::Bbox, 0.7),
                (Metric::Bev, 0.7),
                (Metric::ThreeD, 0.7),
                (Metric::Bev, 0.5),
                (Metric::ThreeD, 0.5)
            ]
        );
    }

    #[test]
    fn the_seed_alone_decides_the_resamples() {
        let a = [
            true, false, true, true, false, true, false, true, true, true, false, true,
        ];
        let b = [
            true, true, false, true, false, false, true, true, false, true, true, true,
        ];
        assert_eq!(run(&a, &b, 11), run(&a, &b, 11));
        let (x, y) = (run(&a, &b, 11), run(&a, &b, 12));
        assert_eq!(
            row(&x, Metric::ThreeD).difference,
            row(&y, Metric::ThreeD).difference
        );
        assert_ne!(row(&x, Metric::ThreeD).ahead, row(&y, Metric::ThreeD).ahead);
    }

    #[test]
    fn too_few_resamples_or_a_bad_confidence_are_refused() {
        let (g, a) = frames(3, &[true; 3], 0.9);
        let mut resampling = Resampling {
            resamples: 1,
            seed: 0,
            confidence: 0.95,
        };
        let err = paired_bootstrap(&g, &a, &a, &car_cfg(), resampling).unwrap_err();
        assert!(err.to_string().contains("at least 2"), "{err}");
        resampling.resamples = 10;
        resampling.confidence = 1.0;
        let err = paired_bootstrap(&g, &a, &a, &car_cfg(), resampling).unwrap_err();
        assert!(err.to_string().contains("between 0 and 1"), "{err}");
    }

    #[test]
    fn the_ablation_table_has_a_line_per_row_with_its_interval() {
        let all = [true; 40];
        let half: Vec<bool> = (0..40).map(|i| i % 2 == 0).collect();
        let p = run(&half, &all, 1);
        let rows = [RowDifference {
            name: "half",
            seed: Some(2),
            result: &p,
        }];
        let table = difference_table(&rows, ObjectClass::Car, Metric::ThreeD);
        let d = row(&p, Metric::ThreeD);
        let cell = format!(
            "{:+.2} [{:+.2}, {:+.2}] 0%",
            d.difference[1], d.interval_low[1], d.interval_high[1]
        );
        assert!(table.contains("| half "), "{table}");
        assert!(table.contains(&cell), "{cell} not in {table}");
        assert!(
            table.contains("over 200 resamples of the 40 val frames, seed 1"),
            "{table}"
        );
        assert_eq!(
            table.lines().filter(|l| l.starts_with('|')).count(),
            3,
            "{table}"
        );
        assert!(difference_table(&[], ObjectClass::Car, Metric::Bev).is_empty());
    }

    #[test]
    fn quantiles_interpolate_between_order_statistics() {
        let v = [0.0, 1.0, 2.0, 3.0, 4.0];
        assert_eq!(quantile(&v, 0.0), 0.0);
        assert_eq!(quantile(&v, 1.0), 4.0);
        assert_eq!(quantile(&v, 0.5), 2.0);
        assert!((quantile(&v, 0.125) - 0.5).abs() < 1e-12);
    }
}
